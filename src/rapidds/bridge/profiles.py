"""Robot profiles: how a lab's robot driver names, zeroes and limits the world's joints, and
where its controller listens. The single owner of the mapping between a world's joint vector
and the driver's names and positions (``--robot PROFILE`` on every command that crosses the
border).

Profiles (:data:`PROFILES`):

- ``reference``: the world's own joint names (the painting world's MJCF names
  ``robot:panda0_joint1..7``), no offsets, the world's own limits (the painting arm: the Panda
  datasheet). What rapidds's reference nodes speak.
- ``franka-panda``: franka_ros / franka_ros2 names ``panda_joint1..7`` for a 7-joint Panda
  world. Offsets: the shipped MJCF's joint 6 is Franka's joint 6 minus pi/2 (the MJCF's range
  [-1.6573, 2.1127] is Franka's [-0.0873, 3.8223], its own commented-out line, shifted by
  -pi/2), so ``driver = world + offset`` with offset +pi/2 on joint 6, 0 elsewhere. Limits:
  the Panda (FER) datasheet, positions in Franka's convention.
- ``franka-fr3``: franka_ros2's ``fr3_joint1..7``, the same joint-6 offset, the FR3 datasheet:
  its position range, acceleration and jerk, and the velocity limits Franka states for the
  whole of a smaller "rectangular" box (lower than the Panda's; the FR3's own velocity limits
  depend on the position). The painting arm's mixing poses bend joint 4 to -2.90 rad, inside
  the FR3's range (-3.0421) but outside that box (-2.7478), where the arm is nearly still.

Limits are Franka's published control-interface tables (frankaemika/docs,
``control-parameters-joint-panda.csv``, ``control-parameters-joint-fr3.csv`` and
``control-parameters-joint-fr3-rectangular.csv``); docs/design-notes.md, "Robot profiles".

Controller topics follow ros2_control: the joint trajectory controller takes
``trajectory_msgs/msg/JointTrajectory`` on ``/<controller>/joint_trajectory``; its scaled
variant takes ``control_msgs/msg/SpeedScalingFactor`` on ``/<controller>/speed_scaling_input``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from pydantic import Field

from rapidds.errors import RapiddsError
from rapidds.motion.timing import JointLimits, TimedTrajectory, parameterize
from rapidds.settings import Settings
from rapidds.worlds.capabilities import capability

__all__ = ["DEFAULT_PROFILE", "PROFILES", "SPEED_SCALING_TYPE", "ProfileError", "RobotProfile",
           "profile_names", "robot_limits", "robot_profile", "task_rows"]

SPEED_SCALING_TYPE = "control_msgs/msg/SpeedScalingFactor"
"""The message ros2_control's scaled joint trajectory controller reads its scaling from."""
DEFAULT_PROFILE = "reference"

Floats = tuple[float, ...]


class ProfileError(RapiddsError):
    """An unknown profile, or one that does not fit the world or a joint state."""


class RobotProfile(Settings):
    """A driver's view of the world's robot joints (module docstring).

    joints: the driver's names of the world's joints, in the world's order (None: the world's
    own names). offsets: added to a world position to give the driver's (None: zeros).
    lower, upper, velocity, acceleration, jerk: the arm's limits in the driver's convention
    (None: the world's own, :func:`robot_limits`). fingers: driver joints a joint state may
    carry that the world does not plan (ignored). controller: the ros2_control controller."""

    label = "RobotProfile"
    name: str = Field(min_length=1)
    description: str = ""
    joints: tuple[str, ...] | None = None
    offsets: Floats | None = None
    lower: Floats | None = None
    upper: Floats | None = None
    velocity: Floats | None = None
    acceleration: Floats | None = None
    jerk: Floats | None = None
    fingers: tuple[str, ...] = ()
    controller: str = Field("joint_trajectory_controller", min_length=1)

    @property
    def trajectory_topic(self) -> str:
        """``/<controller>/joint_trajectory`` (``trajectory_msgs/msg/JointTrajectory``)."""
        return f"/{self.controller}/joint_trajectory"

    @property
    def speed_scaling_topic(self) -> str:
        """``/<controller>/speed_scaling_input`` (:data:`SPEED_SCALING_TYPE`)."""
        return f"/{self.controller}/speed_scaling_input"

    def joint_names(self, world: Any) -> tuple[str, ...]:
        """The driver's names of ``world``'s robot joints, in the world's order."""
        from rapidds.worlds.base import joint_names

        own = joint_names(world)
        if self.joints is None:
            return own
        if len(self.joints) != len(own):
            raise ProfileError(
                f"robot profile '{self.name}' maps {len(self.joints)} joints; world "
                f"{world.name}'s robot has {len(own)} ({', '.join(own)}): use --robot "
                f"{DEFAULT_PROFILE} or a profile for this robot")
        return self.joints

    def offset(self, world: Any) -> np.ndarray:
        """(J,) driver position minus world position."""
        n = len(self.joint_names(world))
        return np.zeros(n) if self.offsets is None else np.asarray(self.offsets, dtype=float)

    def to_driver(self, world: Any, positions: np.ndarray) -> tuple[tuple[str, ...], np.ndarray]:
        """World joint positions (..., J) -> (the driver's names, the driver's positions)."""
        names = self.joint_names(world)
        return names, np.asarray(positions, dtype=float) + self.offset(world)

    def from_driver(self, world: Any, names: Sequence[str],
                    positions: Sequence[float]) -> np.ndarray:
        """A driver's joint state (names, positions) -> the world's (J,) joint vector. Finger
        joints and other extra names are ignored; a missing joint is a :class:`ProfileError`
        naming what came and what this profile expects."""
        expected = self.joint_names(world)
        index = {n: i for i, n in enumerate(names)}
        missing = [n for n in expected if n not in index]
        if missing or len(positions) != len(names):
            raise ProfileError(
                f"joint state names {list(names)} do not carry robot profile '{self.name}''s "
                f"joints {list(expected)} (missing {missing or 'none'}; "
                f"{len(positions)} positions for {len(names)} names)")
        q = np.asarray(positions, dtype=float)[[index[n] for n in expected]]
        return q - self.offset(world)

    def limits(self, world: Any) -> JointLimits:
        """The arm's limits in the world's convention (positions shifted by the offsets)."""
        own = robot_limits(world)
        names = self.joint_names(world)
        fields = {f: getattr(self, f) for f in ("lower", "upper", "velocity", "acceleration",
                                                 "jerk")}
        given = {f: np.asarray(v, dtype=float) for f, v in fields.items() if v is not None}
        if len(given) < len(fields) and own is None:
            raise ProfileError(f"robot profile '{self.name}' leaves limits to the world and "
                               f"world {world.name} declares none")
        if any(len(v) != len(names) for v in given.values()):
            raise ProfileError(f"robot profile '{self.name}' has limits of the wrong length "
                               f"for {len(names)} joints")
        off = self.offset(world)
        for f in ("lower", "upper"):
            if f in given:
                given[f] = given[f] - off
        return JointLimits(**{f: given[f] if f in given else getattr(own, f) for f in fields})

    def timed(self, world: Any, task: str, path: np.ndarray) -> TimedTrajectory:
        """``path`` cut to ``task`` (:func:`task_rows`) and time-parameterized within this
        profile's limits (:func:`~rapidds.motion.timing.parameterize`); world convention."""
        limits = self.limits(world)
        rows = task_rows(world, task, path)
        out = (rows < limits.lower - 1e-9) | (rows > limits.upper + 1e-9)
        if out.any():
            k, j = (int(x[0]) for x in np.nonzero(out))
            raise ProfileError(
                f"robot task {task}'s path leaves robot profile '{self.name}''s range of "
                f"joint {j + 1} at row {k}: {rows[k, j] + self.offset(world)[j]:.4f} not in "
                f"[{limits.lower[j] + self.offset(world)[j]:.4f}, "
                f"{limits.upper[j] + self.offset(world)[j]:.4f}] (the driver's convention)")
        return parameterize(rows, world.dt, limits)

    def trajectory(self, world: Any, timed: TimedTrajectory, stamp_ns: int = 0,
                   frame_id: str = "world") -> Any:
        """The driver's ``trajectory_msgs/msg/JointTrajectory`` of a parameterized trajectory:
        its names, positions with the offsets, velocities and accelerations at every point;
        header stamp ``stamp_ns`` (0: "start on arrival" to a joint trajectory controller);
        ``frame_id``: the live link names the trajectory's task there."""
        from rapidds.bridge.ros2 import joint_trajectory

        names, q = self.to_driver(world, timed.positions)
        return joint_trajectory(names, q, world.dt, stamp_ns=stamp_ns, frame_id=frame_id,
                                times=timed.times,
                                velocities=timed.velocities,
                                accelerations=timed.accelerations)


def task_rows(world: Any, task: str, path: np.ndarray) -> np.ndarray:
    """The rows of a robot ``path`` that do ``task``: up to the row at which the world counts
    it complete (its ``completion_time``), at least two; all of them when it never is."""
    q = np.asarray(path, dtype=float)
    done = float(world.completion_time(task, q[None])[0])
    if done >= world.penalty:
        return q
    return q[:max(round(done / world.dt) + 1, 2)]


def robot_limits(world: Any) -> JointLimits | None:
    """The world's own robot limits (its ``robot_limits`` capability), or None."""
    own = capability(world, "robot_limits")
    return None if own is None else own.robot_limits


_FRANKA_OFFSETS: Floats = (0.0, 0.0, 0.0, 0.0, 0.0, math.pi / 2, 0.0)
# Panda (FER) joint limits, frankaemika/docs control-parameters-joint-panda.csv
_PANDA = {"lower": (-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973),
          "upper": (2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973),
          "velocity": (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61),
          "acceleration": (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0),
          "jerk": (7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0)}
# FR3 joint limits, frankaemika/docs control-parameters-joint-fr3.csv (positions,
# acceleration, jerk) and control-parameters-joint-fr3-rectangular.csv (velocities: the ones
# valid everywhere in that table's smaller box; the FR3's own velocity limits depend on the
# position and shrink near the range's ends)
_FR3 = {"lower": (-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159),
        "upper": (2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159),
        "velocity": (2.0, 1.0, 1.5, 1.25, 3.0, 1.5, 3.0),
        "acceleration": (10.0,) * 7,
        "jerk": (5000.0,) * 7}

PROFILES: dict[str, RobotProfile] = {p.name: p for p in (
    RobotProfile(name="reference", description="the world's own joint names and limits "
                 "(rapidds's reference nodes)"),
    RobotProfile(name="franka-panda", description="Franka Emika Panda on franka_ros / "
                 "franka_ros2 (panda_joint1..7)",
                 joints=tuple(f"panda_joint{k}" for k in range(1, 8)), offsets=_FRANKA_OFFSETS,
                 fingers=("panda_finger_joint1", "panda_finger_joint2"),
                 controller="panda_arm_controller", **_PANDA),
    RobotProfile(name="franka-fr3", description="Franka Research 3 on franka_ros2 "
                 "(fr3_joint1..7)",
                 joints=tuple(f"fr3_joint{k}" for k in range(1, 8)), offsets=_FRANKA_OFFSETS,
                 fingers=("fr3_finger_joint1", "fr3_finger_joint2"),
                 controller="fr3_arm_controller", **_FR3),
)}


def profile_names() -> tuple[str, ...]:
    return tuple(PROFILES)


def robot_profile(name: str) -> RobotProfile:
    """The profile called ``name``; a :class:`ProfileError` line naming the known ones."""
    try:
        return PROFILES[name]
    except KeyError:
        raise ProfileError(f"unknown robot profile {name!r}; one of "
                           f"{', '.join(PROFILES)}") from None
