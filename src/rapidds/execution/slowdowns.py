"""Predicted slowdowns: how long the speed and separation monitor will slow or hold a robot
motion beside the person's concurrent tasks, so that the planner can plan for it.

The monitor (:class:`~rapidds.execution.policies.SpeedSeparation`) moves the robot at the
largest rate r in [0, 1] with d >= S_p(r) (ISO/TS 15066 Eq. 1, :func:`protective_distance`).
A step of the motion that takes dt at full speed takes dt / r at rate r, so it loses
dt (1 / r - 1). The prediction runs that over the steered trajectory, step by step until the
motion is done, with

- d: the distance from each of the robot's body points to the person's path on the concurrent
  task as the learned grid belief has it. The belief holds s(x) = E[exp(-beta |x - path|)]
  (paper Eq. 7), so -ln s(x) / beta is a distance, by Jensen never larger than the expected
  one: the prediction errs on the side of a hold. It is the closest the person comes to x over
  the whole task, not where they are at that instant, so it predicts a hold wherever the robot
  passes the person's route; the learned correction (:mod:`rapidds.human.slowdowns`) scales
  that to what the monitor really does.
- v_h: the person's speed on that task (the population's typical fastest body-point speed);
- v_r: the fastest of the robot's body points at full speed (as the executor measures it).

A stop (r = 0) is counted as ``floor`` (r = 0.1: a step in the stop zone costs 9 dt more): the
person moves on and the robot resumes, which a path belief cannot time. Everything is
elementwise array arithmetic (no Python loop over trajectories), so it can run as tensor ops.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from rapidds.execution.policies import protective_distance
from rapidds.human.slowdowns import SlowdownBelief
from rapidds.human.spatial import SpatialModel
from rapidds.worlds.base import World
from rapidds.worlds.reactions import SafetyLimits

__all__ = ["HoldModel", "hold_rates", "human_speeds", "predicted_hold"]

FLOOR = 0.1


def hold_rates(limits: SafetyLimits, separation: np.ndarray, human_speed: np.ndarray,
               robot_speed: np.ndarray) -> np.ndarray:
    """The monitor's rate for arrays of (d, v_h, v_r): the largest r in [0, 1] with
    d >= S_p(r); S_p is affine in the robot's speed, so r = (d - S_p(0)) / (S_p(v_r) - S_p(0)).
    Equal to ``SpeedSeparation(limits).rate_at`` elementwise (tests/test_slowdowns.py checks)."""
    still = protective_distance(limits, human_speed, 0.0 * robot_speed)
    per_rate = protective_distance(limits, human_speed, robot_speed) - still
    room = separation - still
    safe = np.where(per_rate > 0.0, per_rate, 1.0)
    r = np.where(per_rate > 0.0, np.clip(room / safe, 0.0, 1.0), 1.0)
    return np.where(room < 0.0, 0.0, r)


def predicted_hold(limits: SafetyLimits, separation: np.ndarray, human_speed: np.ndarray,
                   robot_speed: np.ndarray, active: np.ndarray, dt: float,
                   floor: float = FLOOR) -> np.ndarray:
    """Seconds the monitor adds to each motion: (..., H) separations, speeds and the steps
    still moving (``active``) -> (...). Broadcasting arrays only."""
    r = np.maximum(hold_rates(limits, separation, human_speed, robot_speed), floor)
    return (dt * (1.0 / r - 1.0) * active).sum(axis=-1)


def human_speeds(world: World) -> dict[str, float]:
    """Per person's task, the population's median of the fastest body point's speed while
    moving (units / s), from the world's prior paths at its dt."""
    out = {}
    for task, paths in world.prior().paths.items():
        speeds = []
        for p in paths:
            arr = np.asarray(p, dtype=float)
            arr = arr[:, None] if arr.ndim == 2 else arr
            if len(arr) > 1:
                step = np.linalg.norm(np.diff(arr, axis=0), axis=-1).max(axis=-1) / world.dt
                speeds.append(step[step > 1e-9])
        flat = np.concatenate(speeds) if speeds else np.zeros(0)
        out[task] = float(np.median(flat)) if flat.size else 0.0
    return out


@dataclass
class HoldModel:
    """The predicted lost time of robot trajectories beside the person's tasks, from the path
    belief ``spatial``, corrected by ``belief`` (None: the prediction as it is)."""

    world: World
    spatial: SpatialModel
    limits: SafetyLimits
    speeds: Mapping[str, float]
    belief: SlowdownBelief | None = None

    def raw(self, task: str, concurrent: Iterable[str], xi: np.ndarray) -> dict[str, np.ndarray]:
        """Per concurrent person's task, the uncorrected lost time of trajectories xi (N, H, d)
        of robot task ``task`` -> (N,) seconds."""
        xi = np.asarray(xi, dtype=float)
        dt = self.world.dt
        pts = np.asarray(self.world.robot_points(xi), dtype=float)      # (N, H, P, d_ws)
        step = np.linalg.norm(np.diff(pts, axis=1), axis=-1).max(axis=-1) / dt
        v_r = np.concatenate([step, np.zeros((len(xi), 1))], axis=1)   # (N, H)
        done = np.asarray(self.world.completion_time(task, xi), dtype=float)  # (N,)
        active = np.arange(xi.shape[1])[None] * dt < done[:, None] - 1e-9
        beta = self.spatial.config.beta
        out = {}
        for i in dict.fromkeys(concurrent):
            s = np.asarray(self.spatial[i].point_cost(pts), dtype=float)   # (N, H, P)
            sep = (-np.log(np.maximum(s, 1e-300)) / beta).min(axis=-1)     # (N, H)
            out[i] = predicted_hold(self.limits, sep, np.asarray(self.speeds.get(i, 0.0)),
                                    v_r, active, dt)
        return out

    def hold(self, task: str, concurrent: Iterable[str], xi: np.ndarray) -> np.ndarray:
        """Predicted lost time beside C_j = ``concurrent``: the largest over its tasks of the
        corrected prediction (as the paper's spatial cost takes the largest S_i), (N,)."""
        per = self.raw(task, concurrent, xi)
        if not per:
            return np.zeros(np.asarray(xi).shape[0])
        b = self.belief
        return np.max(np.stack([p * (1.0 if b is None else b.factor(task, i))
                                for i, p in per.items()]), axis=0)

    def value_term(self) -> Callable[[str, Sequence[str], np.ndarray], np.ndarray]:
        """The term steering adds to a motion's value (seconds, like d_j)."""
        return self.hold
