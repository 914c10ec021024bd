"""Policies: what the robot does about what it sees while a cycle runs.

:class:`OpenLoop` is the paper's execution: the robot follows its plan whatever happens.
:class:`SpeedSeparation` is speed and separation monitoring after ISO/TS 15066:2016, clause
5.5.4 (the protective separation distance of its Eq. 1, with ISO 13855 for the person's
speed): the robot may only move at a rate r of its planned speed v_r while the smallest
distance d between any of its body points and any of the person's is at least

    S_p(r) = v_h (T_r + T_s) + r v_r T_r + r v_r T_s / 2 + C + Z_d + Z_r

with v_h the person's measured speed (the fastest of their body points over the last tick),
T_r the robot's reaction time, T_s its stopping time (a constant deceleration from r v_r, so
S_s = r v_r T_s / 2), C the intrusion distance and Z_d, Z_r the sensing and position
uncertainties (:class:`rapidds.worlds.reactions.SafetyLimits`). It takes the largest such
r in [0, 1]: full speed when clear, slower as the person nears, stopped inside S_p(0).
Re-planning the rest of the cycle is the third policy, in :mod:`.replan`.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from rapidds.worlds.reactions import SafetyLimits

__all__ = ["OpenLoop", "RobotPolicy", "SpeedSeparation", "protective_check",
           "protective_distance", "separation"]


def separation(a: np.ndarray, b: np.ndarray) -> float:
    """d: the smallest distance between any of the points ``a`` (n, k) and ``b`` (m, k)."""
    return float(np.linalg.norm(a[:, None] - b[None], axis=-1).min())


def protective_distance(limits: SafetyLimits, human_speed: float, robot_speed: float) -> float:
    """S_p of ISO/TS 15066 Eq. 1 for a robot moving at ``robot_speed`` (see the module)."""
    t_r, t_s = limits.reaction_time, limits.stopping_time
    return (human_speed * (t_r + t_s) + robot_speed * t_r + robot_speed * t_s / 2.0
            + limits.margin)


def protective_check(limits: SafetyLimits, watched: int,
                     moving: Iterable[tuple[float, float, float]]) -> dict[str, Any]:
    """A cycle's check against the protective distance: of ``watched`` instants, those at which
    the robot moved, given as (separation, person's speed, robot's speed), how many of them were
    inside S_p and the closest margin (separation - S_p)."""
    margins = [sep - protective_distance(limits, vh, vr) for sep, vh, vr in moving]
    return {"watched": watched, "moving": len(margins),
            "moving_inside": sum(m < -1e-9 for m in margins),
            "closest_margin": min(margins, default=None)}


class RobotPolicy(Protocol):
    """Decides the robot's rate (fraction of its planned speed) at one instant."""

    def rate(self, separation: float, human_speed: float, robot_speed: float) -> float: ...


class OpenLoop:
    """The paper: the plan runs as planned."""

    def rate(self, separation: float, human_speed: float, robot_speed: float) -> float:
        return 1.0


@dataclass(frozen=True)
class SpeedSeparation:
    """Speed and separation monitoring with the robot's ``limits``."""

    limits: SafetyLimits

    def rate(self, separation: float, human_speed: float, robot_speed: float) -> float:
        still = protective_distance(self.limits, human_speed, 0.0)
        if separation < still:
            return 0.0
        per_rate = protective_distance(self.limits, human_speed, robot_speed) - still
        if per_rate <= 0.0:
            return 1.0
        return min(1.0, (separation - still) / per_rate)
