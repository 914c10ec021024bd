"""Robot paths made trajectories an arm executes: jerk-limited time-parameterization (ruckig)
within the joint position, velocity, acceleration and jerk limits the arm declares.

A planned robot motion is a *path*: H rows, row k meant at k * dt (the diffusion policy's
output, what steering scores and motion memory keeps). Rows at 0.15 s differenced do not
respect an arm's acceleration limit, and positions alone make a joint trajectory controller
interpolate linearly (a velocity jump at every row). :func:`parameterize` gives the path a
timing the arm can follow: it passes through every row, starts and ends at rest, and each
segment between two rows is ruckig's time-optimal jerk-limited motion from one row's state to
the next, never shorter than the path's own ``dt`` (so a dwell stays a dwell and the arm is
never faster than planned, only slower where its limits require).

Waypoint velocities: at row i each joint gets the central difference of its neighbouring rows
(zero where the joint turns), capped at twice the smaller of its two row-to-row speeds and at
its velocity limit; where the segment after row i - 1 had to be slowed by its limits, row i's
velocity is scaled down by the same factor and the segment recomputed once. The cap keeps
every joint between its rows (measured on 24 painting demonstrations: no overshoot; uncapped
central differences overshoot by up to 0.011 rad, the smaller speed alone adds twice the
time: 0.29 s a motion on average against 0.15 s). Every waypoint has zero
acceleration. ruckig (community edition) is used state to state, which is all it offers
without its cloud API.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rapidds.errors import RapiddsError

__all__ = ["JointLimits", "TimedTrajectory", "TimingError", "limit_excess", "parameterize",
           "row_times"]

_EPS = 1e-9
_INSIDE = 1.0 - 1e-6  # ruckig plans this close to the limits: the arm's checks are strict
_CAP = 2.0  # waypoint speed <= this times the smaller neighbouring row speed (see below)


class TimingError(RapiddsError):
    """A path that cannot be time-parameterized (wrong shape, NaN, a limit ruckig refuses)."""


@dataclass(frozen=True, eq=False)
class JointLimits:
    """Per-joint limits in the world's convention: ``lower``/``upper`` (rad or m),
    ``velocity`` (/s), ``acceleration`` (/s^2), ``jerk`` (/s^3), each (J,) and symmetric
    for the derivatives (a datasheet's maxima)."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray

    def __post_init__(self) -> None:
        arrays = {f: np.asarray(getattr(self, f), dtype=float) for f in
                  ("lower", "upper", "velocity", "acceleration", "jerk")}
        shapes = {a.shape for a in arrays.values()}
        if len(shapes) != 1 or len(next(iter(shapes))) != 1:
            raise TimingError(f"joint limits must be 1-D of one length, got shapes {shapes}")
        for name in ("velocity", "acceleration", "jerk"):
            if not (np.isfinite(arrays[name]).all() and (arrays[name] > 0).all()):
                raise TimingError(f"joint {name} limits must be finite and > 0")
        if not (arrays["lower"] <= arrays["upper"]).all():
            raise TimingError("joint position limits need lower <= upper")
        for name, a in arrays.items():
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def dof(self) -> int:
        return int(self.velocity.shape[0])


@dataclass(frozen=True, eq=False)
class TimedTrajectory:
    """A parameterized path. ``times`` (N,) seconds from the start, ``positions``,
    ``velocities``, ``accelerations`` (N, J) sampled from ruckig's trajectory; ``row_times``
    (H,) the time each path row is reached (rows are among the samples)."""

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    row_times: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.times[-1])


def _path(path: np.ndarray, limits: JointLimits) -> np.ndarray:
    q = np.asarray(path, dtype=float)
    if q.ndim != 2 or q.shape[1] != limits.dof or len(q) < 1:
        raise TimingError(f"a path must be (H >= 1, {limits.dof}), got {q.shape}")
    if not np.isfinite(q).all():
        raise TimingError("a path with NaN or infinite positions")
    return q


def _waypoint_velocities(q: np.ndarray, dt: float, vmax: np.ndarray) -> np.ndarray:
    """(H, J): zero at the ends and where a joint turns; else the central difference, capped
    at twice the smaller neighbouring row-to-row speed (no segment overshoots a row)."""
    v = np.zeros_like(q)
    if len(q) > 2:
        d0, d1 = np.diff(q, axis=0)[:-1], np.diff(q, axis=0)[1:]
        central = (d0 + d1) / (2 * dt)
        cap = _CAP * np.minimum(np.abs(d0), np.abs(d1)) / dt
        v[1:-1] = np.where(d0 * d1 > 0, np.sign(central) * np.minimum(np.abs(central), cap), 0.0)
    return np.clip(v, -vmax * _INSIDE, vmax * _INSIDE)


def _segments(q: np.ndarray, dt: float, limits: JointLimits) -> list[Any]:
    """ruckig's trajectory from each row to the next (see the module docstring)."""
    import ruckig

    dof = limits.dof
    otg, inp = ruckig.Ruckig(dof), ruckig.InputParameter(dof)
    inp.max_velocity = (limits.velocity * _INSIDE).tolist()
    inp.max_acceleration = (limits.acceleration * _INSIDE).tolist()
    inp.max_jerk = (limits.jerk * _INSIDE).tolist()
    inp.minimum_duration = float(dt)
    zero = [0.0] * dof
    inp.current_velocity, inp.current_acceleration = zero, zero
    inp.current_position = q[0].tolist()
    inp.target_acceleration = zero
    vel = _waypoint_velocities(q, dt, limits.velocity)
    out = []
    for i in range(1, len(q)):
        inp.target_position = q[i].tolist()
        for _ in range(2):
            inp.target_velocity = vel[i].tolist()
            traj = ruckig.Trajectory(dof)
            result = otg.calculate(inp, traj)
            if result != ruckig.Result.Working:
                raise TimingError(f"ruckig refused the segment to row {i}: {result}")
            slow = dt / traj.duration
            if slow > 1 - 1e-6 or not vel[i].any():
                break
            vel[i] *= slow  # the arm is slower here than the path: arrive slower too
        out.append(traj)
        inp.current_position, inp.current_velocity = q[i].tolist(), vel[i].tolist()
        inp.current_acceleration = zero
    return out


def row_times(path: np.ndarray, dt: float, limits: JointLimits) -> np.ndarray:
    """(H,) seconds at which the parameterized trajectory reaches each row of ``path``."""
    q = _path(path, limits)
    durations = [s.duration for s in _segments(q, dt, limits)]
    return np.concatenate([[0.0], np.cumsum(durations)])


def parameterize(path: np.ndarray, dt: float, limits: JointLimits,
                 samples_per_row: int = 3) -> TimedTrajectory:
    """``path`` (H, J), rows meant at k * ``dt``, as a trajectory within ``limits`` (module
    docstring), sampled ``samples_per_row`` times per segment (rows included), so a
    controller interpolating between samples stays close to ruckig's motion."""
    q = _path(path, limits)
    if samples_per_row < 1:
        raise TimingError("samples_per_row must be >= 1")
    segs = _segments(q, dt, limits)
    starts = np.concatenate([[0.0], np.cumsum([s.duration for s in segs])])
    times, pos, vel, acc = [0.0], [q[0]], [np.zeros(limits.dof)], [np.zeros(limits.dof)]
    for seg, t0 in zip(segs, starts, strict=False):
        for j in range(1, samples_per_row + 1):
            t = seg.duration * j / samples_per_row
            p, v, a = seg.at_time(t)
            times.append(t0 + t)
            pos.append(np.asarray(p))
            vel.append(np.asarray(v))
            acc.append(np.asarray(a))
    positions = np.array(pos)
    positions[::samples_per_row] = q  # the rows exactly, not ruckig's float round trip
    return TimedTrajectory(np.array(times), positions, np.array(vel), np.array(acc), starts)


def limit_excess(times: np.ndarray, positions: np.ndarray, limits: JointLimits,
                 velocities: np.ndarray | None = None,
                 accelerations: np.ndarray | None = None) -> dict[str, float]:
    """How far a sampled trajectory goes past ``limits``, by differencing, as a reader of the
    messages would check it: name -> the largest ratio to its limit (<= 1 is within), for
    ``position`` (distance outside [lower, upper] over the range), ``velocity`` (position
    differences), ``acceleration`` (velocity differences, or second differences without
    them) and ``jerk`` (acceleration differences, when given)."""
    t = np.asarray(times, dtype=float)
    q = np.asarray(positions, dtype=float)
    h = np.diff(t)[:, None]
    if (h <= 0).any():
        raise TimingError("sample times must increase")
    out = {"position": 1.0 + float(np.max(np.maximum(limits.lower - q, q - limits.upper)
                                          / np.maximum(limits.upper - limits.lower, _EPS)))}
    v = np.diff(q, axis=0) / h
    out["velocity"] = float(np.max(np.abs(v) / limits.velocity, initial=0.0))
    if velocities is not None:
        a = np.diff(np.asarray(velocities, dtype=float), axis=0) / h
    else:
        a = np.diff(v, axis=0) / ((h[1:] + h[:-1]) / 2)
    out["acceleration"] = float(np.max(np.abs(a) / limits.acceleration, initial=0.0))
    if accelerations is not None:
        j = np.diff(np.asarray(accelerations, dtype=float), axis=0) / h
        out["jerk"] = float(np.max(np.abs(j) / limits.jerk, initial=0.0))
    return out
