"""Steered motions carried from one cycle to the next while their value function is unchanged.

Algorithm 1 empties the memory M of steered motions at the start of every cycle. The value a
motion request (j, C_j) is steered against, V(xi) = d_j(xi) + gamma max_{i in C_j} S_i(xi),
changes between cycles only through the spatial models S_i of the tasks in C_j (the world, the
policy and gamma are fixed for a run). So a plan steered in an earlier cycle is still a sample of
the very same steering problem as long as none of those models moved, and steering again would
only draw another one. :class:`CarriedMotions` answers such requests from the carried plans and
steers the rest; every plan is stamped with a fingerprint of the S_i it was steered against.

Without learning (levels none, temporal, oracle, exact) nothing moves, and after the first cycle
only overlap sets never met before are steered; with spatial learning, the requests that involve
a task the person did in the last cycle are steered again. The carried plans are part of the
stored state, so a resumed run plans exactly as an uninterrupted one.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rapidds.codec import decode_array, encode_array
from rapidds.errors import StateError
from rapidds.human.spatial import SpatialModel
from rapidds.motion.interface import MotionKey, MotionModel, MotionPlan
from rapidds.problem import Problem

__all__ = ["CarriedMotions", "decode_plans", "encode_plans", "spatial_stamps", "valid_plans"]

Stamped = tuple[MotionPlan, dict[str, str]]
"""A plan and the fingerprints of the spatial models of its concurrent tasks."""


def spatial_stamps(spatial: SpatialModel) -> dict[str, str]:
    """task -> fingerprint of what S_task evaluates (the posterior mean, or the MLP weights when
    the surrogate evaluates it)."""
    out = {}
    for task in spatial.tasks:
        model = spatial[task]
        h = hashlib.sha1(np.ascontiguousarray(model.mean).tobytes())
        if model.config.use_surrogate:
            sur = model.to_dict()["surrogate"]
            h.update(repr(sur and sur["state"]).encode())
        out[task] = h.hexdigest()[:16]
    return out


def _current(key: MotionKey, stamped: Stamped, stamps: Mapping[str, str]) -> bool:
    """Whether a carried plan was steered against the spatial models ``stamps`` fingerprint."""
    return all(stamped[1].get(t) == stamps.get(t) for t in key[1])


def valid_plans(carried: Mapping[MotionKey, Stamped],
                stamps: Mapping[str, str]) -> dict[MotionKey, MotionPlan]:
    """The carried plans that are still samples of their steering problem under the spatial
    models ``stamps`` fingerprint (what :class:`CarriedMotions` would answer a request with)."""
    return {k: got[0] for k, got in carried.items() if _current(k, got, stamps)}


class CarriedMotions:
    """A :class:`~rapidds.motion.interface.MotionModel` that reuses carried plans whose
    concurrent tasks' spatial models are unchanged and steers every other request with
    ``inner``. ``carried`` is updated in place with every plan steered here."""

    def __init__(self, inner: MotionModel, carried: dict[MotionKey, Stamped],
                 stamps: Mapping[str, str], presteer: bool | None = None):
        self.inner = inner
        self.carried = carried
        self.stamps = dict(stamps)
        self.reused = 0
        # The carried requests whose spatial models moved are steered again with the cycle's
        # first request, one batch for the cycle (the search asks for them in later
        # generations one or two at a time): by default when ``inner`` steers on a device,
        # where a steering call costs its denoising steps however few its rows; on the CPU a
        # call costs its rows, and the stored records keep their batches.
        self.presteer = (bool(getattr(inner, "batches_cycle", False)) if presteer is None
                         else presteer)
        self._stale = [k for k in carried if not self._valid(k)] if self.presteer else []

    def _valid(self, key: MotionKey) -> bool:
        got = self.carried.get(key)
        return got is not None and _current(key, got, self.stamps)

    def nominal_durations(self, problem: Problem) -> np.ndarray:
        return self.inner.nominal_durations(problem)

    def plan(self, requests: Sequence[MotionKey]) -> list[MotionPlan]:
        fresh = [k for k in requests if not self._valid(k)]
        self.reused += len(requests) - len(fresh)
        if fresh and self._stale:
            fresh += [k for k in self._stale if k not in fresh and not self._valid(k)]
            self._stale = []
        for key, plan in zip(fresh, self.inner.plan(fresh) if fresh else [], strict=True):
            self.carried[key] = (plan, {t: self.stamps[t] for t in key[1]})
        return [self.carried[k][0] for k in requests]


def encode_plans(carried: Mapping[MotionKey, Stamped]) -> list[dict[str, Any]]:
    """JSON-safe list; trajectories in the models' array codec (:mod:`rapidds.codec`)."""
    out = []
    for (task, concurrent), (plan, stamps) in carried.items():
        out.append({"task": task, "concurrent": sorted(concurrent), "duration": plan.duration,
                    "spatial": plan.spatial_cost, "stamps": stamps,
                    "trajectory": None if plan.trajectory is None else encode_array(
                        np.asarray(plan.trajectory, dtype=float))})
    return out


def decode_plans(items: Sequence[Mapping[str, Any]]) -> dict[MotionKey, Stamped]:
    """Inverse of :func:`encode_plans`; StateError on malformed entries."""
    out: dict[MotionKey, Stamped] = {}
    try:
        for d in items:
            key = (str(d["task"]), frozenset(str(t) for t in d["concurrent"]))
            traj = _trajectory(d["trajectory"], key[0])
            if traj is not None and (traj.ndim != 2 or not np.isfinite(traj).all()):
                raise ValueError(f"trajectory of {key[0]} is not a finite (H, d) array")
            plan = MotionPlan(key[0], key[1], float(d["duration"]), float(d["spatial"]), traj)
            out[key] = (plan, {str(k): str(v) for k, v in dict(d["stamps"]).items()})
    except (KeyError, TypeError, ValueError) as exc:
        raise StateError(f"stored motions are corrupt ({exc})") from None
    return out


def _trajectory(stored: Any, task: str) -> np.ndarray | None:
    """A carried trajectory as stored: encoded (:func:`rapidds.codec.encode_array`), or a list
    of lists as stores written before the codec was shared hold it."""
    if stored is None:
        return None
    if isinstance(stored, dict):
        return decode_array(stored, f"stored motions: trajectory of {task}")
    return np.asarray(stored, dtype=float)
