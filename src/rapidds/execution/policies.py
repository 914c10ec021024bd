"""Policies: what the robot does about what it sees while a cycle runs.

:class:`OpenLoop` is the paper's execution: the robot follows its plan whatever happens.
:class:`SpeedSeparation` is speed and separation monitoring after ISO/TS 15066:2016, clause
5.5.4 (the protective separation distance of its Eq. 1, with ISO 13855 for the person's
speed): the robot may only move at a rate r of its planned speed while the smallest distance d
between any of its body points and any of the person's is at least

    S_p(r) = v_h (T_r + T_s) + r v_r T_r + r v_r T_s / 2 + C + Z_d + Z_r

with v_h the person's speed *towards the robot* and v_r the robot's *towards the person* at
full rate (the standard's directed speeds, :func:`directed_speeds`, floored at 0: one who
moves away counts as standing, never as a credit), T_r the robot's reaction time, T_s its
stopping time (a constant deceleration from r v_r, so S_s = r v_r T_s / 2), C the intrusion
distance and Z_d, Z_r the sensing and position uncertainties
(:class:`rapidds.worlds.reactions.SafetyLimits`). It takes the largest such r in [0, 1]: full
speed when clear, slower as the person nears, stopped inside S_p(0). A policy sees one
:class:`Scene` per instant: both agents' body points and velocities. Re-planning the rest of
the cycle is the third policy, in :mod:`.replan`.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from rapidds.worlds.reactions import SafetyLimits

__all__ = ["OpenLoop", "RobotPolicy", "Scene", "SpeedSeparation", "directed_arrays",
           "directed_speeds", "monitor_rates", "protective_check", "protective_distance",
           "separation"]


def separation(a: np.ndarray, b: np.ndarray) -> float:
    """d: the smallest distance between any of the points ``a`` (n, k) and ``b`` (m, k)."""
    return float(np.linalg.norm(a[:, None] - b[None], axis=-1).min())


@dataclass(frozen=True)
class Scene:
    """One instant as a monitor sees it. human: the person's body points (K, d);
    human_velocity: theirs (K, d, units/s); robot: the robot's (P, d); robot_velocity: its
    points' velocities at full rate (P, d). A velocity is None where the monitor cannot know
    its direction: then the speed beside it (the fastest point's; the robot's at full rate)
    counts as towards the other."""

    human: np.ndarray
    human_velocity: np.ndarray | None
    robot: np.ndarray
    robot_velocity: np.ndarray | None
    robot_speed: float = 0.0
    human_speed: float = 0.0

    def backwards(self) -> Scene:
        """The robot going back along its path (a yield): its velocities reversed."""
        v = None if self.robot_velocity is None else -self.robot_velocity
        return replace(self, robot_velocity=v)


def directed_arrays(human: np.ndarray, human_velocity: np.ndarray, robot: np.ndarray,
                    robot_velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(d, v_h, v_r) of ISO/TS 15066 5.5.4 for a batch of instants: the person's body points
    (..., K, d) and velocities, the robot's (..., P, d) and velocities at full rate -> three
    (...) arrays. Each point's velocity component along the unit vector to its nearest point of
    the other agent, the fastest of them, floored at 0. The one computation behind the monitor
    (:func:`directed_speeds`, one instant) and the planner's predicted holds
    (:mod:`rapidds.execution.slowdowns`, every step of every candidate at once)."""
    diff = robot[..., None, :, :] - human[..., :, None, :]  # (..., K, P, d): person -> robot
    dist = np.linalg.norm(diff, axis=-1)  # (..., K, P)
    sep = dist.min(axis=(-2, -1))
    near_r = dist.argmin(axis=-1)[..., None, None]  # each person's point's nearest robot point
    to_r = (np.take_along_axis(diff, near_r, axis=-2)[..., 0, :]
            / np.maximum(np.take_along_axis(dist, near_r[..., 0], axis=-1), 1e-12))
    near_h = dist.argmin(axis=-2)[..., None, :, None]  # each robot point's nearest person's
    to_h = (-np.take_along_axis(diff, near_h, axis=-3)[..., 0, :, :]
            / np.maximum(np.take_along_axis(dist, near_h[..., 0], axis=-2)[..., 0, :, None],
                         1e-12))
    v_h = np.maximum(np.einsum("...kd,...kd->...k", human_velocity, to_r).max(axis=-1), 0.0)
    v_r = np.maximum(np.einsum("...pd,...pd->...p", robot_velocity, to_h).max(axis=-1), 0.0)
    return sep, v_h, v_r


def directed_speeds(scene: Scene) -> tuple[float, float, float]:
    """(d, v_h, v_r) of ISO/TS 15066 5.5.4 at one instant (:func:`directed_arrays`): the
    separation; the person's speed towards the robot (the fastest of their body points'
    velocity components towards the robot's nearest point); the robot's towards the person at
    full rate, likewise (where a direction is unknown, the speed the scene gives). Both floored
    at 0: a person walking away counts as standing (the standard allows the directed speed; a
    floor of 0 is the common and conservative choice). The fastest point's, not only the
    closest pair's: a hand may close in faster than the nearest point does."""
    h_vel = np.zeros_like(scene.human) if scene.human_velocity is None else scene.human_velocity
    r_vel = np.zeros_like(scene.robot) if scene.robot_velocity is None else scene.robot_velocity
    sep, v_h, v_r = directed_arrays(scene.human, h_vel, scene.robot, r_vel)
    return (float(sep), scene.human_speed if scene.human_velocity is None else float(v_h),
            scene.robot_speed if scene.robot_velocity is None else float(v_r))


def monitor_rates(limits: SafetyLimits, separation: np.ndarray, human_speed: np.ndarray,
                  robot_speed: np.ndarray) -> np.ndarray:
    """The monitor's rate for arrays of (d, v_h, v_r): the largest r in [0, 1] with
    d >= S_p(r); S_p is affine in the robot's speed, so r = (d - S_p(0)) / (S_p(v_r) - S_p(0)).
    :meth:`SpeedSeparation.rate_at` is this at one instant."""
    still = protective_distance(limits, human_speed, 0.0 * robot_speed)
    per_rate = protective_distance(limits, human_speed, robot_speed) - still
    room = separation - still
    safe = np.where(per_rate > 0.0, per_rate, 1.0)
    r = np.where(per_rate > 0.0, np.minimum(room / safe, 1.0), 1.0)
    return np.where(room < 0.0, 0.0, r)


def protective_distance(limits: SafetyLimits, human_speed: Any, robot_speed: Any) -> Any:
    """S_p of ISO/TS 15066 Eq. 1 for a robot moving at ``robot_speed`` (see the module); floats
    or arrays that broadcast."""
    t_r, t_s = limits.reaction_time, limits.stopping_time
    return (human_speed * (t_r + t_s) + robot_speed * t_r + robot_speed * t_s / 2.0
            + limits.margin)


def protective_check(limits: SafetyLimits, watched: int,
                     moving: Iterable[tuple[float, float, float]]) -> dict[str, Any]:
    """A cycle's check against the protective distance: of ``watched`` instants, those at which
    the robot moved, given as (separation, person's speed, robot's speed; directed, as the
    policy saw them), how many of them were inside S_p and the closest margin (separation -
    S_p)."""
    margins = [sep - protective_distance(limits, vh, vr) for sep, vh, vr in moving]
    return {"watched": watched, "moving": len(margins),
            "moving_inside": sum(m < -1e-9 for m in margins),
            "closest_margin": min(margins, default=None)}


class RobotPolicy(Protocol):
    """Decides the robot's rate (fraction of its planned speed) at one instant."""

    def rate(self, scene: Scene) -> float: ...


class OpenLoop:
    """The paper: the plan runs as planned."""

    def rate(self, scene: Scene) -> float:
        return 1.0


@dataclass(frozen=True)
class SpeedSeparation:
    """Speed and separation monitoring with the robot's ``limits``, on directed speeds."""

    limits: SafetyLimits

    def rate(self, scene: Scene) -> float:
        return self.rate_at(*directed_speeds(scene))

    def rate_at(self, separation: float, human_speed: float, robot_speed: float) -> float:
        """The largest r in [0, 1] with separation >= S_p(r), for the (directed) speeds."""
        return float(monitor_rates(self.limits, np.asarray(separation), np.asarray(human_speed),
                                   np.asarray(robot_speed)))
