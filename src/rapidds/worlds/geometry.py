"""Planar geometry that worlds share: wall rectangles, segment-wall hits, fetch-style completion.

Trajectories are arrays of shape (N, H, d): row k is the state at time k * dt, so the start pose
is row 0.
"""

from __future__ import annotations

import numpy as np

from rapidds.settings import Real, settings_dataclass

__all__ = ["Rect", "reach_then_return_time", "segments_hit_rects"]


@settings_dataclass("Rect")
class Rect:
    """An axis-aligned wall rectangle [xmin, xmax] x [ymin, ymax] in world units."""

    xmin: Real
    ymin: Real
    xmax: Real
    ymax: Real

    def __post_init__(self) -> None:
        if not (self.xmin < self.xmax and self.ymin < self.ymax):
            raise ValueError(f"needs xmin < xmax and ymin < ymax, got {self}")

    def as_array(self) -> np.ndarray:
        """(4,) [xmin, ymin, xmax, ymax]."""
        return np.array([self.xmin, self.ymin, self.xmax, self.ymax], dtype=float)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(...,) bool: which of the (..., 2) points lie inside or on the rectangle."""
        p = np.asarray(points, dtype=float)
        return (
            (p[..., 0] >= self.xmin)
            & (p[..., 0] <= self.xmax)
            & (p[..., 1] >= self.ymin)
            & (p[..., 1] <= self.ymax)
        )


def segments_hit_rects(
    traj: np.ndarray, rects: np.ndarray | tuple[Rect, ...], margin: float = 0.0
) -> np.ndarray:
    """Which polylines touch a wall: a segment between consecutive points that meets any
    rectangle (grown by ``margin`` on every side) counts, not only its sample points, so a fast
    trajectory cannot jump through a thin wall between two steps.

    traj: (N, T, 2) or (T, 2) points. rects: (R, 4) [xmin, ymin, xmax, ymax] or Rect objects.
    Returns (N,) bool, or a 0-d bool for a single (T, 2) polyline. Slab test (Liang-Barsky),
    vectorised over N x (T-1) x R.
    """
    p = np.asarray(traj, dtype=float)
    single = p.ndim == 2
    if single:
        p = p[None]
    if p.ndim != 3 or p.shape[-1] != 2:
        raise ValueError(f"traj must have shape (N, T, 2) or (T, 2), got {np.shape(traj)}")
    r = np.array([x.as_array() for x in rects]) if isinstance(rects, tuple) else np.asarray(rects)
    if r.size == 0:
        out = np.zeros(p.shape[0], dtype=bool)
        return out[0] if single else out
    r = r.reshape(-1, 4).astype(float) + np.array([-margin, -margin, margin, margin])
    if p.shape[1] == 1:  # a single point: a degenerate segment
        p = np.concatenate([p, p], axis=1)
    a = p[:, :-1, None, :]  # (N, S, 1, 2)
    d = (p[:, 1:] - p[:, :-1])[:, :, None, :]
    lo = r[None, None, :, :2]  # (1, 1, R, 2)
    hi = r[None, None, :, 2:]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - a) / d
        t2 = (hi - a) / d
    parallel = d == 0
    inside = (a >= lo) & (a <= hi)
    # A segment parallel to an axis overlaps that slab for all t or for none.
    t_enter = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    t_exit = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    enter = np.maximum(t_enter.max(axis=-1), 0.0)
    leave = np.minimum(t_exit.min(axis=-1), 1.0)
    hit = (enter <= leave).any(axis=(1, 2))
    return hit[0] if single else hit


def reach_then_return_time(
    traj: np.ndarray,
    goal: np.ndarray,
    home: np.ndarray,
    radius: float,
    dt: float,
    penalty: float,
) -> np.ndarray:
    """Completion time of a fetch: the first step k at which the trajectory is within ``radius``
    of ``home`` having been within ``radius`` of ``goal`` at some step <= k; returned as k * dt
    (row k is the state at time k * dt, so a trajectory back home at row k has finished at
    k * dt seconds). Trajectories that never do it get ``penalty`` (finite, so costs stay
    comparable and sortable).

    traj: (..., H, d); goal, home: (d,). Returns (...,) float64.
    """
    x = np.asarray(traj, dtype=float)
    near_goal = np.linalg.norm(x - np.asarray(goal, dtype=float), axis=-1) <= radius
    near_home = np.linalg.norm(x - np.asarray(home, dtype=float), axis=-1) <= radius
    done = np.logical_or.accumulate(near_goal, axis=-1) & near_home
    k = np.argmax(done, axis=-1)
    # Rounded so that e.g. 24 steps of 0.2 s read 4.8, not 4.800000000000001.
    return np.where(done.any(axis=-1), np.round(k * dt, 9), penalty).astype(float)
