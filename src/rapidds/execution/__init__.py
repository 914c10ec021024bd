"""Execution as its own layer: one cycle run by a clock (docs/design-notes.md "Reacting inside
the cycle").

:class:`CycleExecutor` advances time, takes what happens from *sources* (:class:`HumanSource`:
a simulated person, later the browser game, a study page or a ROS 2 link; :class:`RobotSource`:
the planned, steered trajectories) and lets *policies* act (:class:`OpenLoop`, the paper;
:class:`SpeedSeparation`, ISO/TS 15066 speed and separation monitoring; re-planning the rest of
the cycle, :class:`Replanning`). What it returns is the realised cycle as a
:class:`Deployment`, the shape the loop learns from and records. Which policies and re-planner
a run gets is its registered execution setting (:mod:`.registry`).

Names are imported on first use: the registry is read by ``rapidds --help`` (through
``RunConfig``), which must not pay for numpy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rapidds.lazy import submodule_attributes

if TYPE_CHECKING:
    from rapidds.execution.deployment import Deployment, realise
    from rapidds.execution.executor import CycleExecutor, CycleRules, Replanning
    from rapidds.execution.policies import (
        OpenLoop,
        RobotPolicy,
        Scene,
        SpeedSeparation,
        directed_speeds,
        protective_distance,
    )
    from rapidds.execution.registry import (
        ExecutionSetting,
        execution_names,
        execution_setting,
        register_execution,
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

_WHERE = {
    "Deployment": "deployment", "realise": "deployment",
    "CycleExecutor": "executor", "CycleRules": "executor", "Replanning": "executor",
    "OpenLoop": "policies", "RobotPolicy": "policies", "Scene": "policies",
    "SpeedSeparation": "policies", "directed_speeds": "policies",
    "protective_distance": "policies",
    "ExecutionSetting": "registry", "execution_names": "registry",
    "execution_setting": "registry", "register_execution": "registry",
    "MotionSupply": "replan",
    "HumanSource": "sources", "PlannedRobot": "sources", "RobotSource": "sources",
    "RobotView": "sources", "SimulatedHuman": "sources", "SteerableRobot": "sources",
}
__all__ = [
    "CycleExecutor", "CycleRules", "Deployment", "ExecutionSetting", "HumanSource",
    "MotionSupply", "OpenLoop", "PlannedRobot", "Replanning", "RobotPolicy", "RobotSource",
    "RobotView", "Scene", "SimulatedHuman", "SpeedSeparation", "SteerableRobot",
    "directed_speeds", "execution_names", "execution_setting", "protective_distance", "realise",
    "register_execution",
]

__getattr__ = submodule_attributes(__name__, _WHERE)
