"""Eq. 7 of the paper: the point cost of robot points against one observed human path,
s(x, xi_h) = max over the path of exp(-beta ||x_h - x||), exactly, in numpy, or with its
distances found on a device with numpy's operations in numpy's order (the population prior
and every observation of :class:`~rapidds.human.spatial.grid.SpatialCostModel` evaluate it at
all grid points)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike

from rapidds.human.spatial.config import _is_real

__all__ = ["check_path", "point_cost"]

# Elements of point_cost's (chunk x S) temporaries: 1 MiB of float64 each, to stay in cache;
# on a device, 32 MiB each (a GPU's few large kernels beat many small ones).
_POINT_COST_PAIRS = 1 << 17
_DEVICE_PAIRS = 1 << 22


def _check_points(a: ArrayLike, what: str, d: int | None = None) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{what} must be a non-empty (n, d) array, got shape {arr.shape}")
    if d is not None and arr.shape[1] != d:
        raise ValueError(f"{what} has {arr.shape[1]} coordinates per point, the model has {d}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{what} contains NaN or infinite coordinates")
    return arr


def check_path(a: ArrayLike, what: str, d: int) -> np.ndarray:
    """A validated human path, (T, d) (one body point) or (T, K, d) (K body points, each a
    polyline over the same T samples), as float64 in the same layout."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 3:
        if 0 in arr.shape:
            raise ValueError(f"{what} must be a non-empty (T, K, d) array, got shape {arr.shape}")
        if arr.shape[2] != d:
            raise ValueError(f"{what} has {arr.shape[2]} coordinates per point, the model has {d}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{what} contains NaN or infinite coordinates")
        return arr
    if arr.ndim != 2:
        raise ValueError(f"{what} must be a non-empty (T, d) or (T, K, d) array, got shape "
                         f"{arr.shape}")
    return _check_points(arr, what, d)


def point_cost(
    points: ArrayLike, human_traj: ArrayLike, beta: float, *, polyline: bool = True,
    device: str | torch.device | None = None,
) -> np.ndarray:
    """Eq. 7: s(x, xi_h) = max over the human path of exp(-beta ||x_h - x||), for every x.

    Args:
        points: (V, d) robot points x.
        human_traj: (T, d) human path xi_h, T >= 1 samples in time order; or (T, K, d), K body
            points (hands, elbows, ...) each followed over the same T samples: the cost is then
            the max over the K paths, i.e. set by the body point nearest to x.
        beta: distance decay, > 0.
        polyline: True takes each path as the piecewise-linear route through its samples (the
            person is between two samples between time steps); False takes the samples alone,
            as Eq. 7 is printed, which leaves dips between samples spaced wider than ~1/beta.
        device: find the nearest distances with tensor operations there (a GPU, where a
            run's policy is: there the host is what a cycle waits for) and copy them back once;
            the same operations in the same order, each exactly rounded in float64, so numpy's
            bits (tested with tensors on the CPU; not yet compared on a GPU). None: numpy on the
            host.

    Returns:
        (V,) float64 costs in (0, 1]. The exponential is monotone, so this is
        exp(-beta * distance to the nearest path point or segment), computed coordinate by
        coordinate on (chunk, S) arrays of about 1 MiB (S segments of all K paths together),
        which stay in cache: several times faster than (chunk, S, d) arrays and einsum.
    """
    if not _is_real(beta) or not math.isfinite(beta) or beta <= 0:
        raise ValueError(f"beta must be a finite number > 0, got {beta!r}")
    pts = _check_points(points, "points")
    traj = check_path(human_traj, "human_traj", pts.shape[1])
    paths = traj[None] if traj.ndim == 2 else traj.transpose(1, 0, 2)   # (K, T, d)
    if polyline and paths.shape[1] > 1:
        # The segments of every body point's path, and only those: no segment joins the end of
        # one body point's path to the start of the next.
        start = paths[:, :-1].reshape(-1, pts.shape[1])
        seg = np.diff(paths, axis=1).reshape(-1, pts.shape[1])  # (S, d)
        seg_len2 = np.einsum("sd,sd->s", seg, seg)
        inv = np.divide(1.0, seg_len2, out=np.zeros_like(seg_len2), where=seg_len2 > 0)
    else:
        start = paths.reshape(-1, pts.shape[1])
        seg, inv = np.zeros_like(start), np.zeros(len(start))
    start_t, seg_t = start.T.copy(), seg.T.copy()                       # (d, S)
    if device is None:
        nearest = _nearest(pts, start_t, seg_t, inv, _POINT_COST_PAIRS)
    else:  # the same steps on tensors, copied back once
        at = torch.device(device)
        nearest = _nearest(*(torch.as_tensor(a, device=at) for a in (pts, start_t, seg_t, inv)),
                           _DEVICE_PAIRS).cpu().numpy()
    return np.exp(-float(beta) * np.sqrt(nearest))


def _nearest(pts: Any, start_t: Any, seg_t: Any, inv: Any, pairs: int) -> Any:
    """Squared distance (V,) of each point to its nearest segment, arrays or tensors (one
    kernel per operation, none fused, so the bits are numpy's on any device), in chunks of
    about ``pairs`` (point, segment) pairs. Every (chunk, S) array is written in place into
    three buffers: a fresh temporary per operation took about a fifth longer on the host."""
    d, n_seg = start_t.shape
    n = len(pts)
    step = max(1, pairs // n_seg)
    if isinstance(pts, torch.Tensor):
        def new(shape: tuple[int, ...]) -> Any:
            return torch.empty(shape, dtype=pts.dtype, device=pts.device)
        sub, mul, clip = torch.sub, torch.mul, torch.clamp
    else:
        new, sub, mul, clip = np.empty, np.subtract, np.multiply, np.clip
    nearest = new((n,))
    rel_buf = new((d, min(step, n), n_seg))
    acc_buf, tmp_buf = new(rel_buf.shape[1:]), new(rel_buf.shape[1:])
    for k in range(0, n, step):
        c = min(step, n - k)
        rel, acc, tmp = rel_buf[:, :c], acc_buf[:c], tmp_buf[:c]
        for i, r in enumerate(rel):
            sub(pts[k:k + c, i, None], start_t[i], out=r)
        t = _coordinate_sum(rel, seg_t, acc, tmp)
        t *= inv
        clip(t, 0.0, 1.0, out=t)
        for r, g in zip(rel, seg_t, strict=True):
            r -= mul(t, g, out=tmp)
        sq = _coordinate_sum(rel, rel, acc, tmp)
        nearest[k:k + c] = sq.amin(dim=1) if isinstance(sq, torch.Tensor) else sq.min(axis=1)
    return nearest


def _coordinate_sum(a: Any, b: Any, out: Any, tmp: Any) -> Any:
    """sum_i a[i] * b[i] over the coordinates i, into ``out`` (``tmp`` a scratch array of its
    shape), added in the order NumPy's einsum adds three coordinates ((x + z) + y), so that
    costs are the bits the einsum form gave; other d in order. Arrays or tensors."""
    mul = torch.mul if isinstance(out, torch.Tensor) else np.multiply
    order = [0, 2, 1] if len(a) == 3 else range(len(a))
    first, *rest = order
    mul(a[first], b[first], out=out)
    for i in rest:
        out += mul(a[i], b[i], out=tmp)
    return out
