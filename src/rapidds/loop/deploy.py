"""Deploy a plan for one cycle: the realised timeline and costs of what the person actually did.

The human's actual durations and paths come from the teammate (simulated, recorded or live);
the robot's from its chosen motions. Precedence and waits are enforced as they really happen:
the realised timeline is the schedule simulated on the actual durations. Realised costs
(docs/design-notes.md item 15): makespan; spatial cost, the S of each robot trajectory against
the human paths that actually overlapped it in time; cost = makespan + gamma x spatial; and the
smallest time-synchronised distance between the robot's and the person's body points.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from rapidds.human.spatial import point_cost
from rapidds.motion.interface import MotionPlan
from rapidds.problem import Problem
from rapidds.schedule import Schedule, Timeline, compile_schedule
from rapidds.worlds.base import HumanExecution, World, body_points

__all__ = ["Deployment", "HumanExecution", "deploy", "separations"]


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


def _separations(
    world: World, tl: Timeline, human: Mapping[str, HumanExecution],
    robot_pts: Mapping[str, np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """(times (T,), smallest distance between the person's and the robot's body points at each
    time (T,)) over the realised cycle, every ``world.dt`` seconds."""
    idx = tl.problem.index
    start, finish = tl.start[0], tl.finish[0]
    dt = world.dt
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
    if not times.size:
        return times, np.zeros(0)
    gaps = np.linalg.norm(h_pos[:, :, None, :] - r_pos[:, None, :, :], axis=-1)
    return times, gaps.min(axis=(1, 2))


def separations(world: World, dep: Deployment) -> tuple[np.ndarray, np.ndarray]:
    """Where the robot was relative to the person through a deployed cycle: (times, smallest
    body-point distance at each time); what a "too close" signal at time t is tied to."""
    pts = {j: world.robot_points(p) for j, p in dep.robot.items()}
    return _separations(world, dep.timeline, dep.human, pts)


def deploy(
    world: World,
    problem: Problem,
    schedule: Schedule,
    motions: Mapping[str, MotionPlan],
    human: Mapping[str, HumanExecution],
    *,
    beta: float,
) -> Deployment:
    """The realised cycle of ``schedule``: ``motions`` holds the robot's plan per robot task,
    ``human`` what the person did for each of their tasks. Costs use ``problem.objective.gamma``.
    """
    compiled = compile_schedule(problem, schedule)
    if compiled is None:
        raise ValueError(f"cannot deploy a deadlocked schedule: {schedule}")
    missing = set(schedule.tasks("human")) - set(human)
    if missing:
        raise ValueError(f"no observation of human task(s) {sorted(missing)}")
    idx = problem.index
    durations = np.zeros((1, len(problem.tasks)))
    for task in schedule.tasks("human"):
        durations[0, idx[task]] = human[task].duration
    robot: dict[str, np.ndarray] = {}
    for task in schedule.tasks("robot"):
        plan = motions[task]
        durations[0, idx[task]] = plan.duration
        if plan.trajectory is not None:
            robot[task] = np.asarray(plan.trajectory, dtype=float)
    tl = compiled.simulate(durations)
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

    times, gaps = _separations(world, tl, human, robot_pts)
    min_sep = float(gaps.min()) if times.size else float("inf")
    return Deployment(
        timeline=tl,
        human={t: human[t] for t in schedule.tasks("human")},
        robot=robot,
        overlaps=overlaps,
        spatial_by_task=spatial_by_task,
        makespan=makespan,
        spatial=spatial,
        cost=makespan + problem.objective.gamma * spatial,
        min_separation=min_sep,
    )
