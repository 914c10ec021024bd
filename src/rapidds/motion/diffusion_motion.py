"""The scheduler's motion interface backed by the diffusion policy and SVDD-PM steering.

Each request (robot task j, concurrent human tasks C_j) is answered by steering
``particles`` samples toward low V(xi) = d_j(xi) + gamma * max_{i in C_j} S_i(xi) and keeping the
best. All requests of one call share one steering batch (the GA asks once per generation), so the
network sees requests x particles x candidates rows per pass.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Protocol, cast

import numpy as np
import torch
from pydantic import Field

from rapidds.motion.interface import MotionKey, MotionPlan
from rapidds.motion.policy import DiffusionPolicy
from rapidds.motion.steering import (
    SteerRequest,
    TensorValue,
    ValueFn,
    particle_temperatures,
    steer,
)
from rapidds.problem import Problem
from rapidds.settings import Int, Real, Settings

SpatialCost = Callable[[Iterable[str], np.ndarray], np.ndarray]
"""(task_ids, xi (N, H, d)) -> (N,): max over the tasks of S_i; 0 for no tasks."""
CompletionTime = Callable[[str, np.ndarray], np.ndarray]
"""(task, xi (N, H, d)) -> (N,) seconds until the trajectory completes the task."""
HoldTime = Callable[[str, Iterable[str], np.ndarray], np.ndarray]
"""(task, C_j, xi (N, H, d)) -> (N,) seconds the safety monitor is predicted to add."""
DeviceHold = Callable[[Sequence[MotionKey], int, torch.Tensor, torch.Tensor, torch.Tensor],
                     torch.Tensor]
""":data:`HoldTime` of a whole steering batch as tensor operations: (its requests, rows per
request, xi (N, H, d), their workspace points (N, H, P, w), their completion times (N,)) ->
(N,), 0 for a request beside no person's task, on the tensors' device."""


class DeviceTerms(Protocol):
    """The value's terms as tensor operations on one device, the forward kinematics shared by
    both: what lets a whole steering batch be scored where the policy runs."""

    def points(self, xi: torch.Tensor) -> torch.Tensor:
        """(N, H, d) trajectories -> (N, H, P, w) workspace points."""
        ...

    def completion_times(self, tasks: Sequence[str], xi: torch.Tensor, points: torch.Tensor
                         ) -> torch.Tensor:
        """(N,) seconds of (N, H, d) trajectories, given their points, the rows in
        ``len(tasks)`` equal blocks, block k doing ``tasks[k]``: a whole steering batch in one
        pass, as each operation is a kernel the host launches."""
        ...

    def spatial_cost(self, tasks: Iterable[str], points: torch.Tensor) -> torch.Tensor:
        """(N,) max over ``tasks`` of S_i for the points (N, H, P, w) of N trajectories."""
        ...


DeviceTermsFactory = Callable[[torch.device], DeviceTerms]
"""The :class:`DeviceTerms` on a device (None where a world has no tensor terms)."""


class HostTerms(Protocol):
    """:class:`DeviceTerms` on numpy arrays, the host's value (the stored records' bits): the
    workspace points computed once per denoising step for every request's candidates, the
    completion time once per task."""

    def points(self, xi: np.ndarray) -> np.ndarray: ...

    def completion_time(self, task: str, xi: np.ndarray, points: np.ndarray) -> np.ndarray: ...

    def spatial_cost(self, tasks: Iterable[str], points: np.ndarray) -> np.ndarray: ...


class SteeringConfig(Settings):
    """How robot motions are sampled for the scheduler.

    particles: B, steered samples per request; the best one is kept.
    candidates: M, draws from the reverse kernel per particle and step (1 = unsteered).
    alpha: 0 keeps the best candidate per step (the SVDD authors' choice); > 0 samples from
        softmax(-V / alpha) for every particle.
    soft_share: with alpha = 0, the share of each request's particles that are drawn with a
        temperature instead (:func:`~rapidds.motion.steering.particle_temperatures`; 0 = the
        authors' greedy SVDD-PM for all). Greedy particles refine within a motion mode,
        tempered ones keep the modes the noisiest steps would drop; the best by final V is kept
        (docs/design-notes.md, "Steering").
    seed: base seed; call k of a DiffusionMotion uses seed + k, so a deterministic scheduler
        gives deterministic motions.
    steps: reverse diffusion steps S per sample; None uses the policy's
        ``num_inference_steps``. A request costs particles * (1 + candidates * (S - 1))
        network rows, so halving S halves the cost (docs/benchmarks.md, "Motion", has V per S).
    """

    label: ClassVar[str] = "SteeringConfig"

    particles: Annotated[Int, Field(ge=1)] = 4
    candidates: Annotated[Int, Field(ge=1)] = 8
    alpha: Annotated[Real, Field(ge=0)] = 0.0
    soft_share: Annotated[Real, Field(ge=0, le=1)] = 0.5
    seed: Int = 0
    steps: Annotated[Int, Field(ge=1)] | None = None

    def temperatures(self) -> np.ndarray:
        """(particles,) SVDD temperature of each particle of a request."""
        if self.alpha > 0:
            return np.full(self.particles, self.alpha)
        return particle_temperatures(self.particles, self.soft_share)


@dataclass(frozen=True)
class ValueTerms:
    """What a world adds to :class:`DiffusionMotion`'s value beyond the paper's terms.

    duration: the chosen trajectory's d_j^r (the arm's time-parameterized time; None: the
    completion time of its path); hold: the time the safety monitor would hold it (None: the
    paper's V); device_terms: the world's value as tensor operations on the policy's device;
    device_hold: ``hold`` as tensor operations there (None: a value with a hold term is scored
    on the host); on_device: score there (None: :attr:`DiffusionMotion.default_on_device`);
    host_terms: the host's value from points shared by its terms (None: ``completion_time``
    and ``spatial_cost`` each per request).
    """

    duration: Callable[[str, np.ndarray], float] | None = None
    hold: HoldTime | None = None
    device_hold: DeviceHold | None = None
    device_terms: DeviceTermsFactory | None = None
    on_device: bool | None = None
    host_terms: HostTerms | None = None


class DiffusionMotion:
    """:class:`~rapidds.motion.interface.MotionModel` sampling steered trajectories.

    ``on_device``: score candidates with the world's tensor terms where the policy runs and
    steer a cycle's requests in one batch (None: :attr:`default_on_device`, which None leaves
    to the policy's device: on unless it is the CPU)."""

    default_on_device: ClassVar[bool | None] = None
    """Process-wide default of ``on_device`` (benchmarks set it to measure the device path on
    the CPU: benchmarks/bench_batched_quality.py)."""

    def __init__(
        self,
        policy: DiffusionPolicy,
        completion_time: CompletionTime,
        spatial_cost: SpatialCost,
        gamma: float,
        config: SteeringConfig | None = None,
        nominal: Callable[[Problem], np.ndarray] | None = None,
        terms: ValueTerms = ValueTerms(),
    ):
        self.policy = policy
        self.completion_time = completion_time
        self.spatial_cost = spatial_cost
        self.gamma = float(gamma)
        self.config = config or SteeringConfig()
        self._nominal = nominal
        # the chosen trajectory's d_j^r: the arm's time-parameterized time (the world's
        # robot_duration) where it has one; steering scores the path with completion_time
        self._duration = terms.duration
        # planning for the safety monitor: V gains the time it would take (None: the paper's V)
        self.hold = terms.hold
        self.device_hold = terms.device_hold
        # the value on the policy's device (no host copy per denoising step): by default where
        # the policy is not on the CPU, whose numpy value keeps the stored records' bits
        self.device_terms = terms.device_terms
        self.host_terms = terms.host_terms
        self.on_device = self.default_on_device if terms.on_device is None else terms.on_device
        self.calls = 0
        self.rows = 0

    def nominal_durations(self, problem: Problem) -> np.ndarray:
        if self._nominal is not None:
            return self._nominal(problem)
        return np.array(
            [np.nan if t.robot_duration is None else t.robot_duration for t in problem.tasks]
        )

    def _values(self, keys: Sequence[MotionKey], xi: np.ndarray, b: int) -> np.ndarray:
        """V for rows of ``xi`` (N, H, d), particle-major: N is len(keys) * b (final scores) or
        that times M (candidates). Rows of one request are contiguous."""
        per_key = xi.shape[0] // len(keys)
        if self.host_terms is not None:
            v = self._term_values(self.host_terms, keys, xi)
        else:
            v = np.empty(xi.shape[0])
            for k, (task, concurrent) in enumerate(keys):
                sl = slice(k * per_key, (k + 1) * per_key)
                v[sl] = self.completion_time(task, xi[sl])
                if concurrent and self.gamma > 0:
                    v[sl] += self.gamma * self.spatial_cost(concurrent, xi[sl])
        if self.hold is not None:
            for k, (task, concurrent) in enumerate(keys):
                if concurrent:
                    sl = slice(k * per_key, (k + 1) * per_key)
                    v[sl] += self.hold(task, concurrent, xi[sl])
        return v

    def _term_values(self, terms: DeviceTerms | HostTerms, keys: Sequence[MotionKey],
                     xi: Any, hold: DeviceHold | None = None) -> Any:
        """The value from ``terms``: the workspace points of every request's rows in one pass,
        then the completion time (tensors: of the whole batch at once; arrays: once per task)
        and the spatial cost once per concurrent set, over the rows of all requests that
        share it; ``hold`` (tensors) for the whole batch, from the same points and completion
        times. Each term is row by row, so grouping changes no value; it saves a call's fixed
        cost per request, tens of kernel launches on a GPU and the forward kinematics'
        per-call overhead on the host."""
        pts = terms.points(xi)
        per_key = xi.shape[0] // len(keys)
        if isinstance(xi, torch.Tensor):
            done = v = cast(DeviceTerms, terms).completion_times([task for task, _ in keys],
                                                                 xi, pts)
        else:
            host = cast(HostTerms, terms)
            done = v = _grouped(keys, per_key, lambda key: key[0], lambda task, rows: (
                host.completion_time(task, _take(xi, rows), _take(pts, rows))))
        if self.gamma > 0 and any(concurrent for _, concurrent in keys):
            v = v + _grouped(keys, per_key, lambda key: frozenset(key[1]), lambda conc, rows: (
                self.gamma * terms.spatial_cost(conc, _take(pts, rows)) if conc else None))
        if hold is not None and any(concurrent for _, concurrent in keys):
            v = v + hold(keys, per_key, xi, pts, done)
        return v

    @property
    def batches_cycle(self) -> bool:
        """Whether steering runs on a device (``on_device``, by default: the policy is not on
        the CPU), where one batch per cycle pays: see :class:`~rapidds.loop.carry.
        CarriedMotions`."""
        return self.on_device if self.on_device is not None else self.policy.device.type != "cpu"

    def value(self, requests: Sequence[MotionKey]) -> ValueFn | TensorValue:
        """V of a steering batch of ``requests``: on the policy's device when the world has
        tensor terms and :attr:`batches_cycle`, and a hold term, if any, comes as tensor
        operations too (``device_hold``); else the numpy value on the host."""
        b = self.config.particles
        hold = self.device_hold if self.hold is not None else None
        if (self.batches_cycle and self.device_terms is not None
                and (self.hold is None or hold is not None)):
            terms = self.device_terms(self.policy.device)
            return TensorValue(lambda xi: self._term_values(terms, requests, xi, hold))
        return lambda xi: self._values(requests, xi, b)

    def plan(self, requests: Sequence[MotionKey]) -> list[MotionPlan]:
        if not requests:
            return []
        cfg = self.config
        b = cfg.particles
        tasks = [task for task, _ in requests for _ in range(b)]
        result = steer(
            self.policy,
            SteerRequest(tasks, len(tasks)),
            self.value(requests),
            num_candidates=cfg.candidates,
            alpha=np.tile(cfg.temperatures(), len(requests)),
            generator=cfg.seed + self.calls,
            num_steps=cfg.steps,
        )
        self.calls += 1
        self.rows += len(tasks) * cfg.candidates
        plans = []
        for k, (task, concurrent) in enumerate(requests):
            vals = result.values[k * b : (k + 1) * b]
            best = k * b + int(np.argmin(vals))
            traj = result.trajectories[best]
            duration = (float(self.completion_time(task, traj[None])[0])
                        if self._duration is None else float(self._duration(task, traj)))
            spatial = float(self.spatial_cost(concurrent, traj[None])[0]) if concurrent else 0.0
            hold = (float(self.hold(task, concurrent, traj[None])[0])
                    if concurrent and self.hold is not None else 0.0)
            plans.append(MotionPlan(task, concurrent, duration, spatial, traj, hold))
        return plans


_Rows = slice | list[slice]


def _take(x: Any, rows: _Rows) -> Any:
    if isinstance(rows, slice):
        return x[rows]
    parts = [x[r] for r in rows]
    return torch.cat(parts) if isinstance(x, torch.Tensor) else np.concatenate(parts)


def _grouped(keys: Sequence[MotionKey], per_key: int, group: Callable[[MotionKey], Any],
             term: Callable[[Any, _Rows], Any]) -> Any:
    """A row-wise term (a tensor or an array) of every request's ``per_key`` rows (request
    k's are rows k * per_key on), evaluated once per ``group`` of requests over all their rows
    together, back in the requests' order; a group whose term is None adds 0."""
    members: dict[Any, list[int]] = {}
    for k, key in enumerate(keys):
        members.setdefault(group(key), []).append(k)
    parts: list[Any] = [None] * len(keys)
    like: Any = None
    for name, ks in members.items():
        rows = [slice(k * per_key, (k + 1) * per_key) for k in ks]
        out = term(name, rows[0] if len(rows) == 1 else rows)
        if out is None:
            continue
        chunks = (out.split(per_key) if isinstance(out, torch.Tensor)
                  else np.split(out, len(ks)))
        for k, chunk in zip(ks, chunks, strict=True):
            parts[k] = like = chunk
    if like is None:
        raise ValueError("no group of requests has a value term")
    if isinstance(like, torch.Tensor):
        return torch.cat([torch.zeros_like(like) if p is None else p for p in parts])
    return np.concatenate([np.zeros_like(like) if p is None else p for p in parts])
