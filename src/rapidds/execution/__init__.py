"""Execution as its own layer: one cycle run by a clock (docs/design-notes.md "Reacting inside
the cycle").

:class:`CycleExecutor` advances time, takes what happens from *sources* (:class:`HumanSource`:
a simulated person, later the browser game, a study page or a ROS 2 link; :class:`RobotSource`:
the planned, steered trajectories) and lets *policies* act (:class:`OpenLoop`, the paper;
:class:`SpeedSeparation`, ISO/TS 15066 speed and separation monitoring; re-planning the rest of
the cycle, :class:`Replanning`). What it returns is the realised cycle as a
:class:`Deployment`, the shape the loop learns from and records.
"""

from rapidds.execution.deployment import Deployment, realise
from rapidds.execution.executor import CycleExecutor, Replanning
from rapidds.execution.policies import (
    OpenLoop,
    RobotPolicy,
    Scene,
    SpeedSeparation,
    directed_speeds,
    protective_distance,
)
from rapidds.execution.replan import MotionSupply
from rapidds.execution.sources import (
    HumanSource,
    PlannedRobot,
    RobotSource,
    RobotView,
    SimulatedHuman,
    SteerableRobot,
)

__all__ = [
    "CycleExecutor",
    "Deployment",
    "HumanSource",
    "MotionSupply",
    "OpenLoop",
    "PlannedRobot",
    "Replanning",
    "RobotPolicy",
    "RobotSource",
    "RobotView",
    "Scene",
    "SimulatedHuman",
    "SpeedSeparation",
    "SteerableRobot",
    "directed_speeds",
    "protective_distance",
    "realise",
]
