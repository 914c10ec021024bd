"""SVDD-PM: derivative-free steering of the diffusion policy toward low values V (Li et al. 2024).

The paper's value V(xi) = d(xi) + gamma * max_i S_i(xi) mixes a completion index (a step
function of the trajectory, no gradient) with learned spatial costs, so gradient guidance does
not apply. SVDD-PM instead uses the model's own stochastic reverse kernel as a proposal: at
every reverse step each particle draws M candidates x_{t-1}, each candidate is scored by V of
its Tweedie estimate x0_hat, and one candidate survives. Because the survivor's noise
prediction (needed for x0_hat) is exactly the one the next step needs, a step costs M network
passes, all particles' candidates going through the network as one batch of B * M.

Any callable (N, H, d) -> (N,) in world units can serve as value; lower is better. A numpy one
sees every step's candidates on the host; a :class:`TensorValue` is scored where the policy
runs, so on a GPU the denoising loop never waits for the host. :func:`value_function` builds
the paper's V (a TensorValue when its spatial costs are) from spatial cost callables.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from diffusers import DDIMScheduler

from rapidds.errors import CheckpointError
from rapidds.motion.cuda_graphs import Replayed
from rapidds.motion.policy import DiffusionPolicy, GeneratorLike, as_generator

ValueFn = Callable[[np.ndarray], np.ndarray]
"""A value on the host: (N, H, d) float64 world-unit trajectories -> (N,) values."""
TensorValueFn = Callable[[Any], Any]
"""A value on the policy's device: (N, H, d) float64 world-unit tensor -> (N,) tensor."""


class TensorValue:
    """Marks a value computed with tensor operations on the policy's device (mark one with
    :func:`tensor_value`). The steering then never leaves the device inside its denoising loop:
    no copy to the host, no synchronisation. Terms add as tensors, so another term (a predicted
    slowdown, say) joins as ``tensor_value(lambda xi: v(xi) + w * slowdown(xi))``.
    A plain :data:`ValueFn` still works: its candidates are copied to the host once per step.
    """

    def __init__(self, fn: TensorValueFn):
        self.fn = fn

    def __call__(self, trajectories: Any) -> Any:
        return self.fn(trajectories)


def tensor_value(fn: TensorValueFn) -> TensorValue:
    """``fn`` (a tensor function of world-unit trajectories) marked for on-device steering."""
    return fn if isinstance(fn, TensorValue) else TensorValue(fn)


@dataclass
class SteerStats:
    """Cost accounting of one :func:`steer` call.

    network_passes: network evaluations per particle (rows sent through the network / B):
        1 for x_T, then M for the candidates of every step but the last, whose candidates
        are final samples and need no x0 estimate: 1 + M * (S - 1) for S steps.
    rows_per_call: batch size of every network call (B first, then B * M).
    value_calls, value_rows: calls of the value function and trajectories it scored.
    kept_value: per step, the mean over particles of V of the kept candidate.
    """

    n_particles: int
    num_candidates: int
    num_steps: int
    network_passes: int = 0
    rows_per_call: list[int] = field(default_factory=list)
    value_calls: int = 0
    value_rows: int = 0
    kept_value: list[float] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def forward_calls(self) -> int:
        return len(self.rows_per_call)


@dataclass
class SteerResult:
    """trajectories (B, H, d) float64 world units; values (B,) V of each final trajectory."""

    trajectories: np.ndarray
    values: np.ndarray
    stats: SteerStats

    def best(self) -> tuple[np.ndarray, float]:
        """The particle with the lowest value: ((H, d) trajectory, V)."""
        k = int(np.argmin(self.values))
        return self.trajectories[k], float(self.values[k])


_NON_FINITE = ("policy produced non-finite trajectories; the checkpoint is corrupt or "
               "diverged")


def require_finite(trajectories: np.ndarray) -> np.ndarray:
    """``trajectories`` as they are when every coordinate is finite, else CheckpointError. A
    network whose samples hold NaN or inf has corrupt or diverged weights; scored anyway, a NaN
    path would count as done at once (completion index 0) and be preferred."""
    if not np.isfinite(trajectories).all():
        raise CheckpointError(_NON_FINITE)
    return trajectories


class _Scorer:
    """V of normalised candidates (N, H, d) -> (N,) float64 on their device; NaN counts as +inf
    (never preferred). Every candidate, final samples included, passes here: non-finite
    trajectories stop the steering, at once for a host value, after the loop for a
    :class:`TensorValue` (checking at once would synchronise the device every step)."""

    def __init__(self, policy: DiffusionPolicy, value_fn: ValueFn | TensorValue):
        self.policy, self.value_fn = policy, value_fn
        self.on_device = isinstance(value_fn, TensorValue)
        self.finite: torch.Tensor | None = None  # all candidates finite so far (device path)
        # on a GPU, with the policy's cuda_graphs, the value's later calls of this steering
        # (one per step, all of one shape, its tables unchanged) replay a captured first
        self.replayed = (Replayed(value_fn) if self.on_device and policy.cuda_graphs
                         and policy.device.type == "cuda"
                         and "value" not in policy.graph_notes else None)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        n = x.shape[0]
        if self.on_device:
            world = self.policy.normalizer.unnormalize(x.detach().to(torch.float64))
            ok = torch.isfinite(world).all()
            self.finite = ok if self.finite is None else self.finite & ok
            out = (self.value_fn if self.replayed is None else self.replayed)(world)
            if not isinstance(out, torch.Tensor):
                raise TypeError("a tensor_value must return a tensor")
            out = out.to(torch.float64)
        else:
            host = np.asarray(self.value_fn(require_finite(self.policy.to_world(x))),
                              dtype=np.float64)
            out = torch.from_numpy(host).to(x.device)
        if out.shape != (n,):
            raise ValueError(f"value_fn must return shape ({n},) for {n} trajectories, got "
                             f"{tuple(out.shape)}")
        return torch.where(torch.isnan(out), torch.inf, out)

    def check(self) -> None:
        """Raise for non-finite candidates seen on the device path (one synchronisation)."""
        if self.replayed is not None and self.replayed.note:
            self.policy.graph_notes["value"] = self.replayed.note
        if self.finite is not None and not bool(self.finite):
            raise CheckpointError(_NON_FINITE)


def _select(values: torch.Tensor, alpha: torch.Tensor, soft: torch.Tensor | None,
            generator: torch.Generator | None) -> torch.Tensor:
    """Index of the kept candidate per particle from values (B, M), on their device: argmin
    where the particle's alpha (B,) is 0, else a draw from softmax(-V / alpha) for the rows
    ``soft`` (indices of the particles with alpha > 0, None for none)."""
    pick = values.argmin(dim=1)  # all-inf rows pick candidate 0
    if soft is not None:
        logits = -values[soft] / alpha[soft, None]
        # Rows where every candidate is infinitely bad: choose uniformly.
        logits = torch.where(torch.isfinite(logits).any(dim=1, keepdim=True), logits, 0.0)
        probs = torch.exp(logits - logits.amax(dim=1, keepdim=True))
        where = generator.device if generator is not None else probs.device
        drawn = torch.multinomial(probs.to(where), 1, generator=generator).squeeze(1)
        pick[soft] = drawn.to(pick.device)
    return pick


def particle_temperatures(n_particles: int, soft_share: float) -> np.ndarray:
    """Per-particle SVDD temperatures: the first particles greedy (alpha = 0), the last
    ``round(soft_share * n)`` (at most n - 1) drawn from softmax(-V / alpha), alpha spread from
    1.0 down to 0.5 (in V's units, seconds for the paper's V).

    Why a mixture: greedy selection commits to a motion mode at the first, noisiest steps, where
    the value of every blurred estimate x0_hat is dominated by whichever term is informative
    there (the spatial cost; the completion time is the same penalty for every estimate that
    does not yet complete the task), so it can settle on a mode whose final V is worse. Tempered
    particles keep both modes alive; the caller keeps the particle with the lowest final V, so
    greedy refinement within a mode and the choice between modes both count.
    """
    n_soft = min(n_particles - 1, round(soft_share * n_particles)) if n_particles > 1 else 0
    alpha = np.zeros(n_particles)
    if n_soft > 0:
        alpha[n_particles - n_soft:] = np.linspace(1.0, 0.5, n_soft)
    return alpha


def _check_steer_args(policy: DiffusionPolicy, b: int, m: int,
                      alpha: float | Sequence[float] | np.ndarray) -> np.ndarray:
    """The per-particle temperatures (B,), or ValueError for unusable arguments."""
    if isinstance(b, bool) or not isinstance(b, int) or b < 1:
        raise ValueError(f"n_particles must be a positive integer, got {b!r}")
    if isinstance(m, bool) or not isinstance(m, int) or m < 1:
        raise ValueError(f"num_candidates must be a positive integer, got {m!r}")
    alphas = np.asarray(alpha, dtype=np.float64).reshape(-1)
    if alphas.size == 1:
        alphas = np.full(b, alphas[0])
    if alphas.shape != (b,) or not (np.isfinite(alphas).all() and (alphas >= 0).all()):
        raise ValueError(f"alpha must be finite numbers >= 0, one or one per particle "
                         f"({b}), got {alpha}")
    if (m > 1 and isinstance(policy.noise_scheduler, DDIMScheduler)
            and policy.config.ddim_eta == 0):
        raise ValueError("SVDD steering needs a stochastic reverse kernel: this policy samples "
                         "with deterministic DDIM (ddim_eta = 0); use ddim_eta > 0 or DDPM")
    return alphas


@dataclass(frozen=True)
class SteerRequest:
    """What :func:`steer` samples: ``n_particles`` trajectories of ``task`` (one task name or
    one per particle), from ``start`` ((d,) or (B, d)) for start-conditioned policies."""

    task: str | Sequence[str]
    n_particles: int
    start: np.ndarray | None = None


@torch.inference_mode()
def steer(policy: DiffusionPolicy, request: SteerRequest, value_fn: ValueFn | TensorValue, *,
          num_candidates: int = 8, alpha: float | Sequence[float] | np.ndarray = 0.0,
          generator: GeneratorLike = None, num_steps: int | None = None) -> SteerResult:
    """Sample ``request.n_particles`` trajectories steered toward low ``value_fn`` with SVDD-PM.

    value_fn: (N, H, d) world-unit trajectories -> (N,) values, lower is better: a numpy
    function, or a :class:`TensorValue` computed on the policy's device.
    num_candidates: M >= 1 draws from the reverse kernel per particle and step (M = 1 is plain
    sampling: same seed, same trajectories as :meth:`DiffusionPolicy.sample`).
    alpha: 0 keeps the best candidate (the SVDD authors' choice); alpha > 0 draws from
    softmax(-V / alpha), V in value_fn's units; one value for all particles or one per
    particle (see :func:`particle_temperatures`). generator: a seed (a generator on the
    policy's device) or a generator. num_steps: reverse steps S (default: the policy's
    ``num_inference_steps``); a step costs M network passes, so fewer steps are cheaper.

    Every request's candidates go through the network as one batch per step, and the loop
    keeps values, selection and indices on the policy's device: with a :class:`TensorValue`
    nothing returns to the host until the end.
    """
    task, b, m, start = request.task, request.n_particles, num_candidates, request.start
    alphas = _check_steer_args(policy, b, m, alpha)
    t0 = time.perf_counter()
    dev = policy.device
    gen = as_generator(generator, dev)
    policy.model.eval()
    cond = policy.condition(task, b, start)                    # (B, c)
    cond_rep = cond.repeat_interleave(m, dim=0)                # (B*M, c), particle-major
    timesteps = policy.timesteps(num_steps)
    stats = SteerStats(b, m, len(timesteps))
    score = _Scorer(policy, value_fn)
    alpha_t = torch.as_tensor(alphas, device=dev)
    soft = (torch.as_tensor(np.flatnonzero(alphas > 0), device=dev) if (alphas > 0).any()
            else None)

    def network(x: torch.Tensor, t: int, c: torch.Tensor) -> torch.Tensor:
        stats.rows_per_call.append(int(x.shape[0]))
        return policy.predict_noise(x, t, c)

    x = policy.initial_noise(b, gen)                           # x_T, (B, H, d)
    eps = network(x, timesteps[0], cond)
    rows = torch.arange(b, device=dev) * m
    kept: list[torch.Tensor] = []
    for i, t in enumerate(timesteps):
        # M independent draws of x_{t-1} per particle from the model's own kernel.
        cand = policy.reverse_step(eps.repeat_interleave(m, dim=0), t,
                                   x.repeat_interleave(m, dim=0), gen)
        if i + 1 < len(timesteps):
            t_next = timesteps[i + 1]
            cand_eps = network(cand, t_next, cond_rep)         # the M passes of this step
            x0_hat = policy.predict_x0(cand, cand_eps, t_next)
        else:
            cand_eps, x0_hat = None, cand                      # final samples: score directly
        v = score(x0_hat).reshape(b, m)
        stats.value_calls += 1
        stats.value_rows += b * m
        keep = rows + _select(v, alpha_t, soft, gen)
        x = cand[keep]
        if cand_eps is not None:
            eps = cand_eps[keep]                               # reused: no extra pass
        kept.append(v.reshape(-1)[keep])
    score.check()
    kept_host = torch.stack(kept).cpu().numpy()                # (S, B): one copy at the end
    stats.kept_value = [float(np.mean(k)) for k in kept_host]
    stats.network_passes = sum(stats.rows_per_call) // b
    stats.seconds = time.perf_counter() - t0
    return SteerResult(policy.to_world(x), kept_host[-1].copy(), stats)


# -- the paper's value function ---------------------------------------------------------------
# Each works on a float64 numpy array (the host) and on a tensor (any device, tensor out), so a
# value built from them steers on the policy's device (:class:`TensorValue`).
Trajectories = np.ndarray | torch.Tensor


def completion_index(trajectories: Trajectories, tol: float) -> Trajectories:
    """(N, H, d) -> (N,) int: first index from which the trajectory stays within ``tol`` of its
    final point, i.e. where the motion is done (demonstrations are padded with their last
    point). 0 for a trajectory that never moves. A tensor in, a tensor out (same device)."""
    if not tol > 0:
        raise ValueError(f"tol must be > 0, got {tol}")
    if isinstance(trajectories, torch.Tensor):
        t = trajectories.to(torch.float64)
        if t.ndim != 3:
            raise ValueError(f"expected (N, H, d) trajectories, got shape {tuple(t.shape)}")
        far_t = torch.linalg.vector_norm(t - t[:, -1:], dim=-1) > tol      # (N, H)
        last = t.shape[1] - 1 - torch.argmax(far_t.flip(1).to(torch.int8), dim=1)
        return torch.where(far_t.any(dim=1), last + 1, 0)
    traj = np.asarray(trajectories, dtype=np.float64)
    if traj.ndim != 3:
        raise ValueError(f"expected (N, H, d) trajectories, got shape {traj.shape}")
    far = np.linalg.norm(traj - traj[:, -1:], axis=-1) > tol       # (N, H)
    h = traj.shape[1]
    last_far = h - 1 - np.argmax(far[:, ::-1], axis=1)
    return np.where(far.any(axis=1), last_far + 1, 0)


def proximity_cost(points: np.ndarray, beta: float) -> TensorValue:
    """S(xi) = max over the trajectory and over ``points`` (P, d) of exp(-beta ||x - p||):
    the paper's per-person spatial cost (Eq. 8) for someone standing at the given points.
    Takes a numpy array or a tensor (then computed on its device)."""
    pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
    if not beta > 0:
        raise ValueError(f"beta must be > 0, got {beta}")
    on: dict[torch.device, torch.Tensor] = {}  # the points, copied once per device

    def cost(trajectories: Trajectories) -> Trajectories:
        if trajectories.shape[-1] != pts.shape[1]:
            raise ValueError(f"cost points have d={pts.shape[1]}, trajectories "
                             f"d={trajectories.shape[-1]}")
        if isinstance(trajectories, torch.Tensor):
            t = trajectories.to(torch.float64)
            p = on.setdefault(t.device, torch.as_tensor(pts, device=t.device))
            dist_t = torch.linalg.vector_norm(t[:, :, None, :] - p[None, None], dim=-1)
            return torch.exp(-beta * dist_t.amin(dim=(1, 2)))
        traj = np.asarray(trajectories, dtype=np.float64)
        dist = np.linalg.norm(traj[:, :, None, :] - pts[None, None], axis=-1)  # (N, H, P)
        return np.exp(-beta * dist.min(axis=(1, 2)))

    return TensorValue(cost)


def value_function(spatial_costs: Sequence[ValueFn | TensorValue], gamma: float, *, tol: float,
                   dt: float = 1.0, hold: ValueFn | TensorValue | None = None
                   ) -> ValueFn | TensorValue:
    """The paper's V(xi) = d(xi) + gamma * max_i S_i(xi), batched (N, H, d) -> (N,).

    d(xi) = completion_index * dt (seconds when dt is the time per trajectory point);
    spatial_costs: S_i of the concurrent human tasks C_j (empty: completion time only);
    hold: the seconds a safety monitor would add to each motion (None: the paper's V), so
    that V is the time the motion takes under the monitor (:mod:`rapidds.execution.slowdowns`).
    When every term is a :class:`TensorValue` (as :func:`proximity_cost`'s are), so is V: it
    takes numpy arrays and tensors, and :func:`steer` keeps it on the policy's device.
    """
    costs = list(spatial_costs)
    if not (math.isfinite(gamma) and gamma >= 0):
        raise ValueError(f"gamma must be a finite number >= 0, got {gamma}")

    def value(trajectories: Trajectories) -> Trajectories:
        if isinstance(trajectories, torch.Tensor):
            vt = completion_index(trajectories, tol).to(torch.float64) * dt
            if costs and gamma > 0:
                st = torch.stack([c(trajectories).to(torch.float64) for c in costs])
                vt = vt + gamma * st.amax(dim=0)
            if hold is not None:
                vt = vt + hold(trajectories).to(torch.float64)
            return vt
        v = completion_index(trajectories, tol).astype(np.float64) * dt
        if costs and gamma > 0:
            s = np.stack([np.asarray(c(trajectories), dtype=np.float64) for c in costs])
            v = v + gamma * s.max(axis=0)
        if hold is not None:
            v = v + np.asarray(hold(trajectories), dtype=np.float64)
        return v

    terms = [*costs, *([] if hold is None else [hold])]
    return TensorValue(value) if all(isinstance(c, TensorValue) for c in terms) else value
