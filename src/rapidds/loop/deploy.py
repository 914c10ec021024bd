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

import numpy as np

from rapidds.execution.deployment import Deployment, realise, separations
from rapidds.motion.interface import MotionPlan
from rapidds.problem import Problem
from rapidds.schedule import Schedule, compile_schedule
from rapidds.worlds.base import HumanExecution, World

__all__ = ["Deployment", "HumanExecution", "deploy", "realise", "separations"]



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
    return realise(world, problem, compiled.simulate(durations),
                   {t: human[t] for t in schedule.tasks("human")}, robot, beta=beta)
