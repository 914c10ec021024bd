"""A new execution policy from outside the package (issue 32): registered here, named in a run's
settings, run for a cycle, and watched by the live cell's monitor, with no edit to rapidds.

The policy: the robot creeps at a third of its speed while the person comes towards it faster
than a stroll, and keeps its plan's order (a monitor, no re-planning). It reads the scene's
velocities, so it tells a person who approaches from one who walks away.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from conftest import SMALL_SEARCH as SMALL

from rapidds.bridge.reactive import SpeedMonitor
from rapidds.execution import RobotPolicy, Scene, directed_speeds, register_execution
from rapidds.execution.registry import ExecutionSetting
from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.worlds.reactions import SafetyLimits

SEEN: list[Scene] = []


@dataclass(frozen=True)
class Creep:
    """A third of the planned speed while the person approaches faster than ``stroll``."""

    stroll: float

    def rate(self, scene: Scene) -> float:
        SEEN.append(scene)
        _, towards, _ = directed_speeds(scene)
        return 1.0 / 3.0 if towards > self.stroll else 1.0


@register_execution
class Creeping(ExecutionSetting):
    """The robot creeps while the person approaches (``stroll``: units/s)."""

    monitor: ClassVar[bool] = True
    kind: Literal["creeping"] = "creeping"
    stroll: float = 0.05

    def policy(self, limits: SafetyLimits) -> RobotPolicy:
        return Creep(self.stroll)


def test_an_execution_registered_outside_runs_a_cycle(fetch_policy) -> None:
    SEEN.clear()
    cfg = RunConfig(human="fast-middle", cycles=1, seed=3, execution="creeping",
                    slowdowns="off", **SMALL)
    assert cfg.model_dump()["execution"] == "creeping" and "-creeping" in cfg.run_id
    run = AdaptiveRun(cfg, fetch_policy)
    plan = run.plan()
    dep = run.execute(plan)
    run.learn(plan, dep)
    rec = run.record(plan, dep)
    assert SEEN and all(s.human_velocity is not None for s in SEEN)  # it watched, with speeds
    crept = [p for p in dep.pauses if p["reason"] == "protective distance (slow)"]
    assert crept and all(p["agent"] == "robot" for p in crept)
    idx = run.problem.index
    for task in plan.best.schedule.tasks("robot"):  # slowed: longer than its motion, at most 3x
        took = dep.timeline.finish[0, idx[task]] - dep.timeline.start[0, idx[task]]
        assert plan.best.motions[task].duration - 1e-9 <= took
        assert took <= 3 * plan.best.motions[task].duration + 1e-9
    assert sum(p["end"] - p["start"] for p in crept) > 0
    in_cycle = rec.execution.in_cycle  # the record says what happened inside the cycle
    assert in_cycle is not None and in_cycle.pauses == tuple(dep.pauses)
    assert in_cycle.yields is not None  # a monitor may hold the robot: its yields are kept


def test_the_live_monitor_runs_the_registered_policy(fetch_policy) -> None:
    run = AdaptiveRun(RunConfig(human="fast-middle", cycles=1, execution="creeping",
                                slowdowns="off", **SMALL), fetch_policy)
    monitor = SpeedMonitor(run.world, {"t": 0.5}, execution=run.config.execution)
    assert isinstance(monitor.policy_now(0.0), Creep)
    robot = np.asarray(run.world.robot_rest(), float)
    monitor.joint_state(robot, 0.9)
    monitor.joint_state(robot, 1.0)
    points = run.world.robot_points(robot[None])[0]
    near = points[:1] + 0.5
    toward = np.broadcast_to(-np.sign(near - points[:1]) * 0.5, near.shape)
    assert monitor.tick(1.0, (near, 0.5, 1.0), "t", toward.copy()) == 1.0 / 3.0
    assert monitor.tick(1.05, (near, 0.5, 1.05), "t", -toward) == 1.0
