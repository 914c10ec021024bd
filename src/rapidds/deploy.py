"""Deploy a plan for one cycle: execute it in time with the teammate's actual behaviour.

The human's actual durations and paths come from the teammate (simulated or recorded); the
robot's from its chosen motions. Precedence and waits are enforced as they really happen: the
realised timeline is the schedule simulated on the actual durations. The realised costs are those
of DESIGN.md section 6.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from rapidds.human.spatial import point_cost
from rapidds.motion.interface import MotionPlan
from rapidds.problem import Problem
from rapidds.schedule import Schedule, Timeline, compile_schedule

Perform = Callable[[str, np.random.Generator], tuple[float, np.ndarray]]


@dataclass(frozen=True)
class HumanExecution:
    """What the person did for one task: its duration (s) and path (T, d) sampled at ``dt``."""

    task: str
    duration: float
    trajectory: np.ndarray


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
    home: np.ndarray,
    segments: list[tuple[float, float, np.ndarray]],
    times: np.ndarray,
    dt: float,
) -> np.ndarray:
    """Position at each time (T, d): at home when idle, along a task's path while it runs.

    segments: (start, finish, path (L, d)) with the path's k-th point at start + k*dt; past the
    end of a path the agent stays at its last point until the task finishes.
    """
    pos = np.broadcast_to(home, (times.size, home.size)).copy()
    for s, f, path in segments:
        active = (times >= s) & (times <= f)
        k = np.clip(np.round((times[active] - s) / dt).astype(int), 0, len(path) - 1)
        pos[active] = path[k]
    return pos


def deploy(
    problem: Problem,
    schedule: Schedule,
    motions: Mapping[str, MotionPlan],
    perform: Perform,
    *,
    human_home: np.ndarray,
    robot_home: np.ndarray,
    dt: float,
    beta: float,
    gamma: float,
    rng: np.random.Generator,
) -> Deployment:
    """Execute ``schedule`` once. ``motions`` holds the robot's plan per robot task;
    ``perform(task, rng)`` returns the person's actual (duration, path) for a task."""
    compiled = compile_schedule(problem, schedule)
    if compiled is None:
        raise ValueError(f"cannot deploy a deadlocked schedule: {schedule}")
    idx = problem.index
    durations = np.zeros((1, len(problem.tasks)))
    human: dict[str, HumanExecution] = {}
    for task in schedule.tasks("human"):
        d, path = perform(task, rng)
        human[task] = HumanExecution(task, float(d), np.asarray(path, dtype=float))
        durations[0, idx[task]] = d
    robot = {}
    for task in schedule.tasks("robot"):
        plan = motions[task]
        durations[0, idx[task]] = plan.duration
        if plan.trajectory is not None:
            robot[task] = np.asarray(plan.trajectory, dtype=float)
    tl = compiled.simulate(durations)
    overlaps = tl.overlaps()
    start, finish = tl.start[0], tl.finish[0]

    spatial_by_task = {}
    for j, concurrent in overlaps.items():
        if j not in robot or not concurrent:
            spatial_by_task[j] = 0.0
            continue
        spatial_by_task[j] = max(
            float(point_cost(robot[j], human[i].trajectory, beta).max()) for i in concurrent
        )
    makespan = float(tl.makespan[0])
    spatial = float(sum(spatial_by_task.values()))

    times = np.arange(0.0, makespan + dt, dt)
    h_pos = _positions(
        np.asarray(human_home, float),
        [(start[idx[i]], finish[idx[i]], e.trajectory) for i, e in human.items()],
        times, dt,
    )
    r_pos = _positions(
        np.asarray(robot_home, float),
        [(start[idx[j]], finish[idx[j]], p) for j, p in robot.items()],
        times, dt,
    )
    min_sep = float(np.linalg.norm(h_pos - r_pos, axis=1).min()) if times.size else np.inf
    return Deployment(
        timeline=tl,
        human=human,
        robot=robot,
        overlaps=overlaps,
        spatial_by_task=spatial_by_task,
        makespan=makespan,
        spatial=spatial,
        cost=makespan + gamma * spatial,
        min_separation=min_sep,
    )
