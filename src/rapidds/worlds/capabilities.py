"""A world's optional capabilities, declared by name in its spec and asked for by name.

A world does the contract of :class:`~rapidds.worlds.base.World`; anything beyond it (a physics
model, a floor a person can walk in the browser, a tracker mapping, ...) is a capability: its
name is in ``world.spec.capabilities`` and its members are on the world. Code that needs one
calls :func:`capability` (the world, typed as what the capability promises, or None), never
``getattr``/``isinstance`` on the world: so what a world can do is listed in one place
(``rapidds worlds``) and a new world gains a feature by declaring it, not by being some class.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, get_args, overload

import numpy as np

from rapidds.problem import Agent
from rapidds.worlds.base import Capability, SimulatedTeammate, World

if TYPE_CHECKING:
    import mujoco

    from rapidds.motion.timing import JointLimits
    from rapidds.worlds.geometry import Rect
    from rapidds.worlds.reactions import ReactionPopulation, SafetyLimits

__all__ = ["CAPABILITIES", "BrowserPlay", "capabilities", "capability", "check_capabilities",
           "lacks", "robot_duration"]


class BrowserPlay(World, Protocol):
    """A floor a person walks in the browser game (``rapidds play``, the study's game rounds): a
    2-D workspace with walls, each agent's home and one object per task to bring home."""

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]: ...

    @property
    def reach_radius(self) -> float: ...

    def home(self, agent: Agent) -> np.ndarray: ...

    def object_position(self, task: str) -> np.ndarray: ...

    def obstacles(self) -> tuple[Rect, ...]: ...


class Physics(World, Protocol):
    """A MuJoCo model of the cell for the reference robot of a live cell (``rapidds sim-robot``)
    and where to put the person's body points in it."""

    def physics_model(self) -> mujoco.MjModel: ...

    def place_person(self, model: mujoco.MjModel, data: mujoco.MjData,
                     points: np.ndarray) -> None: ...


class Participants(World, Protocol):
    """Draws a simulated study participant primed as ``levels`` (the design's priming factors)."""

    def participant(self, name: str, levels: Mapping[str, str],
                    rng: np.random.Generator) -> SimulatedTeammate: ...


class Priming(World, Protocol):
    """A user study's priming factors, whose factorial names the simulated teammates."""

    @property
    def priming_factors(self) -> Mapping[str, tuple[str, ...]]: ...


class Reactions(World, Protocol):
    """How its people react to the robot and how its robot stops (rapidds.worlds.reactions)."""

    @property
    def reaction_population(self) -> ReactionPopulation: ...

    @property
    def safety_limits(self) -> SafetyLimits: ...


class RobotLimits(World, Protocol):
    """The robot's joint limits, what its trajectories are timed within when they leave."""

    @property
    def robot_limits(self) -> JointLimits: ...


class RobotTiming(World, Protocol):
    """The planner's d_j^r of one (H, d) trajectory when it is not ``completion_time``: the
    time-parameterized duration (the painting arm)."""

    def robot_duration(self, task: str, traj: np.ndarray) -> float: ...


class EndEffectorIK(World, Protocol):
    """Joints (T, d) putting the robot's tool at positions (T, 3) in its base frame (CSV
    demonstrations, rapidds.bridge.poses)."""

    def end_effector_ik(self, positions: np.ndarray) -> np.ndarray: ...


class TrackingMapping(World, Protocol):
    """A YAML file mapping a tracker's frames to the body points (rapidds.bridge.recorded)."""

    @property
    def tracking_mapping(self) -> Path: ...


class TensorValues(World, Protocol):
    """The steering value's terms as tensor operations on a device (robot ``points(xi)`` and
    ``completion_times(tasks, xi, points)`` of a batch in one block of rows per task), so a
    cycle's candidates are scored there without the host (issue 36)."""

    def tensor_terms(self, device: Any) -> Any: ...


class PointValues(World, Protocol):
    """The completion time from the robot's workspace points already computed (its
    ``robot_points``), so steering computes them once per denoising step for every request's
    candidates and shares them with the spatial cost (an arm's forward kinematics)."""

    def completion_time_from_points(self, task: str, traj: np.ndarray,
                                    points: np.ndarray) -> np.ndarray: ...


CAPABILITIES: dict[Capability, tuple[type, str]] = {
    "browser_play": (BrowserPlay, "a person plays it in the browser game"),
    "physics": (Physics, "a MuJoCo model for the reference robot, sim-robot"),
    "participants": (Participants, "draws simulated study participants by priming levels"),
    "priming": (Priming, "names a user study's priming factors"),
    "reactions": (Reactions, "states how its people react and how its robot stops"),
    "robot_limits": (RobotLimits, "states the robot's joint limits"),
    "robot_timing": (RobotTiming, "times robot tasks by the parameterized trajectory"),
    "end_effector_ik": (EndEffectorIK, "inverse kinematics for end-effector demonstrations"),
    "tracking_mapping": (TrackingMapping, "ships a tracker mapping of its body points"),
    "tensor_values": (TensorValues, "scores steering candidates as tensor operations on a device"),
    "point_values": (PointValues, "its completion time takes the robot points steering shares"),
}
"""Capability -> (the protocol a declaring world fulfils, one line for ``rapidds worlds``)."""

_NAMES: tuple[str, ...] = get_args(Capability)
_OWN = frozenset(dir(World))  # protocol members: a capability's own are the rest


def capabilities(world: Any) -> tuple[Capability, ...]:
    """The capabilities ``world`` declares, in its spec's order (none for an object with no
    spec, e.g. a test's stand-in)."""
    spec = getattr(world, "spec", None)
    return () if spec is None else tuple(spec.capabilities)


def _members(name: Capability) -> tuple[str, ...]:
    proto = CAPABILITIES[name][0]
    return tuple(m for m in proto.__dict__ if not m.startswith("_") and m not in _OWN)


@overload
def capability(world: Any, name: Literal["browser_play"]) -> BrowserPlay | None: ...
@overload
def capability(world: Any, name: Literal["physics"]) -> Physics | None: ...
@overload
def capability(world: Any, name: Literal["participants"]) -> Participants | None: ...
@overload
def capability(world: Any, name: Literal["priming"]) -> Priming | None: ...
@overload
def capability(world: Any, name: Literal["reactions"]) -> Reactions | None: ...
@overload
def capability(world: Any, name: Literal["robot_limits"]) -> RobotLimits | None: ...
@overload
def capability(world: Any, name: Literal["robot_timing"]) -> RobotTiming | None: ...
@overload
def capability(world: Any, name: Literal["end_effector_ik"]) -> EndEffectorIK | None: ...
@overload
def capability(world: Any, name: Literal["tracking_mapping"]) -> TrackingMapping | None: ...
@overload
def capability(world: Any, name: Literal["tensor_values"]) -> TensorValues | None: ...
@overload
def capability(world: Any, name: Literal["point_values"]) -> PointValues | None: ...
def capability(world: Any, name: str) -> Any:
    """``world`` as the capability ``name`` promises, if it declares it; else None. The one
    place that asks what a world can do beyond the contract."""
    if name not in _NAMES:
        raise ValueError(f"unknown world capability {name!r}; one of {', '.join(_NAMES)}")
    return world if name in capabilities(world) else None


def check_capabilities(world: Any) -> None:
    """ValueError (one line) when ``world`` declares a capability whose members it lacks;
    looked up on its class and its own fields, not evaluated (a property may load MuJoCo)."""
    own = getattr(world, "__dict__", {})
    for name in capabilities(world):
        missing = [m for m in _members(name) if not hasattr(type(world), m) and m not in own]
        if missing:
            raise ValueError(f"world '{world.name}' declares {name} but has no "
                             f"{', '.join(missing)}")


def robot_duration(world: Any) -> Callable[[str, np.ndarray], float] | None:
    """The planner's d_j^r of one trajectory when the world declares ``robot_timing`` (None:
    ``completion_time`` is the duration), for the motion model's ``duration``."""
    timed = capability(world, "robot_timing")
    return None if timed is None else timed.robot_duration


def lacks(world: Any, name: Capability) -> str:
    """The one line that refuses ``world`` for want of capability ``name``."""
    return (f"world {world.name} does not declare the {name} capability "
            f"({CAPABILITIES[name][1]})")
