"""What happened in one cycle, scored: the :class:`Deployment` every execution returns.

The realised costs (docs/design-notes.md item 15): makespan; spatial cost, the S of each robot
trajectory against the human paths that actually overlapped it in time; cost = makespan +
gamma x spatial; and the smallest time-synchronised distance between the robot's and the
person's body points. The open-loop replay (:func:`rapidds.loop.deploy.deploy`) and the
clock-driven executor (:mod:`rapidds.execution.executor`) both score a cycle here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from rapidds.human.spatial import point_cost
from rapidds.problem import Problem
from rapidds.schedule import Schedule, Timeline
from rapidds.worlds.base import HumanExecution, World, body_points

__all__ = ["Deployment", "Reactions", "cycle_positions", "min_separation", "realise",
           "separations"]


@dataclass(frozen=True)
class Deployment:
    """A deployed cycle: the realised timeline, observations and realised costs."""

    timeline: Timeline
    human: dict[str, HumanExecution]
    robot: dict[str, np.ndarray]
    overlaps: dict[str, frozenset[str]]
    spatial_by_task: dict[str, float]
    makespan: float
    spatial: float
    cost: float
    min_separation: float
    pauses: tuple[dict[str, Any], ...] = ()  # reactive execution: who paused, when, why
    replans: tuple[dict[str, Any], ...] = ()  # reactive execution: re-plans inside the cycle
    # instants the executor watched with the robot on a task, those at which it moved while a
    # person was inside the protective distance, and the smallest (separation - S_p) moving
    protective: dict[str, Any] | None = None
    # reactive execution: the robot's yields to a person who waited for it (execution.yielding)
    yields: tuple[dict[str, Any], ...] = ()


@dataclass(frozen=True)
class Reactions:
    """What a reactive layer outside the executor did in a cycle (a live cell's monitor): the
    robot's pauses, its re-plans, and the protective-distance check, as a Deployment keeps them;
    ``schedule``: the order the cell ran where its re-plans changed the plan's (None: the
    plan's), which the cycle is realised with."""

    pauses: tuple[dict[str, Any], ...] = ()
    replans: tuple[dict[str, Any], ...] = ()
    protective: dict[str, Any] | None = None
    schedule: Schedule | None = None


def _positions(
    rest: np.ndarray,
    segments: list[tuple[float, float, np.ndarray]],
    times: np.ndarray,
    dt: float,
) -> np.ndarray:
    """Body points at each time (T, K, d_ws): at rest when idle, along a task's path while it
    runs. segments: (start, finish, path (L, K, d_ws)) with the path's k-th row at start + k*dt;
    past the end of a path the agent stays at its last row until the task finishes."""
    pos = np.broadcast_to(rest, (times.size, *rest.shape)).copy()
    for s, f, path in segments:
        active = (times >= s) & (times <= f)
        k = np.clip(np.round((times[active] - s) / dt).astype(int), 0, len(path) - 1)
        pos[active] = path[k]
    return pos


def _spatial(robot_pts: np.ndarray, human_path: np.ndarray, beta: float) -> float:
    """S of one robot trajectory's workspace points (H, P, d_ws) against one human path: the
    closest approach of any robot point to any body point's polyline (Eq. 7, max over xi)."""
    pts = robot_pts.reshape(-1, robot_pts.shape[-1])
    body = body_points(human_path)
    return max(float(point_cost(pts, body[:, k], beta).max()) for k in range(body.shape[1]))


def realise(
    world: World,
    problem: Problem,
    tl: Timeline,
    human: Mapping[str, HumanExecution],
    robot: Mapping[str, np.ndarray],
    *,
    beta: float,
) -> Deployment:
    """The realised costs of a cycle whose timeline ``tl`` (K = 1) is known: ``human`` what the
    person did for each task of ``tl.schedule``'s human, ``robot`` the trajectory (H, d) the
    robot followed for each of its tasks, row k at k * dt after the task started. Shared by the
    open-loop replay (:func:`rapidds.loop.deploy.deploy`) and the clock-driven executor, so both
    score a cycle the same way."""
    overlaps = tl.overlaps()
    robot_pts = {j: world.robot_points(p) for j, p in robot.items()}  # (H, P, d_ws)

    spatial_by_task = {}
    for j, concurrent in overlaps.items():
        if j not in robot or not concurrent:
            spatial_by_task[j] = 0.0
            continue
        spatial_by_task[j] = max(_spatial(robot_pts[j], human[i].trajectory, beta)
                                 for i in concurrent)
    makespan = float(tl.makespan[0])
    spatial = float(sum(spatial_by_task.values()))
    min_sep = min_separation(world, tl, human, robot_pts)
    return Deployment(
        timeline=tl,
        human=dict(human),
        robot=dict(robot),
        overlaps=overlaps,
        spatial_by_task=spatial_by_task,
        makespan=makespan,
        spatial=spatial,
        cost=makespan + problem.objective.gamma * spatial,
        min_separation=min_sep,
    )


def cycle_positions(
    world: World, tl: Timeline, human: Mapping[str, HumanExecution],
    robot_pts: Mapping[str, np.ndarray],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times (T,), person's body points (T, K, d_ws), robot's (T, P, d_ws)) every dt from 0 to
    the makespan: where both were while the cycle ran (at rest when idle)."""
    idx, dt = tl.problem.index, world.dt
    start, finish = tl.start[0], tl.finish[0]
    times = np.arange(0.0, float(tl.makespan[0]) + dt, dt)
    h_pos = _positions(
        np.asarray(world.human_rest(), float),
        [(start[idx[i]], finish[idx[i]], body_points(human[i].trajectory))
         for i in tl.schedule.tasks("human")],
        times, dt,
    )
    r_pos = _positions(
        world.robot_points(np.asarray(world.robot_rest(), float)[None])[0],
        [(start[idx[j]], finish[idx[j]], p) for j, p in robot_pts.items()],
        times, dt,
    )
    return times, h_pos, r_pos


def _gaps(h_pos: np.ndarray, r_pos: np.ndarray) -> np.ndarray:
    """(T,) smallest distance between any of the person's and the robot's points at each time."""
    return np.linalg.norm(h_pos[:, :, None, :] - r_pos[:, None, :, :], axis=-1).min(axis=(1, 2))


def min_separation(world: World, tl: Timeline, human: Mapping[str, HumanExecution],
                   robot_pts: Mapping[str, np.ndarray]) -> float:
    """The smallest time-synchronised distance between the robot's and the person's points."""
    times, h_pos, r_pos = cycle_positions(world, tl, human, robot_pts)
    if not times.size:
        return float("inf")
    return float(_gaps(h_pos, r_pos).min())


def separations(world: World, dep: Deployment) -> tuple[np.ndarray, np.ndarray]:
    """Where the robot was relative to the person through a deployed cycle: (times, smallest
    body-point distance at each time); what a "too close" signal at time t is tied to."""
    pts = {j: world.robot_points(p) for j, p in dep.robot.items()}
    times, h_pos, r_pos = cycle_positions(world, dep.timeline, dep.human, pts)
    if not times.size:
        return times, np.zeros(0)
    return times, _gaps(h_pos, r_pos)
