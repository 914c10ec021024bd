"""SVDD-PM: derivative-free steering of the diffusion policy toward low values V (Li et al. 2024).

The paper's value V(xi) = d(xi) + gamma * max_i S_i(xi) mixes a completion index (a step
function of the trajectory, no gradient) with learned spatial costs, so gradient guidance does
not apply. SVDD-PM instead uses the model's own stochastic reverse kernel as a proposal: at
every reverse step each particle draws M candidates x_{t-1}, each candidate is scored by V of
its Tweedie estimate x0_hat, and one candidate survives. Because the survivor's noise
prediction (needed for x0_hat) is exactly the one the next step needs, a step costs M network
passes, all particles' candidates going through the network as one batch of B * M.

Any callable (N, H, d) -> (N,) in world units can serve as value; lower is better.
:func:`value_function` builds the paper's V from spatial cost callables.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
from diffusers import DDIMScheduler

from rapidds.errors import CheckpointError
from rapidds.motion.policy import DiffusionPolicy, GeneratorLike, as_generator

ValueFn = Callable[[np.ndarray], np.ndarray]


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


def require_finite(trajectories: np.ndarray) -> np.ndarray:
    """``trajectories`` as they are when every coordinate is finite, else CheckpointError. A
    network whose samples hold NaN or inf has corrupt or diverged weights; scored anyway, a NaN
    path would count as done at once (completion index 0) and be preferred."""
    if not np.isfinite(trajectories).all():
        raise CheckpointError("policy produced non-finite trajectories; the checkpoint is "
                              "corrupt or diverged")
    return trajectories


def _score(value_fn: ValueFn, trajectories: np.ndarray) -> np.ndarray:
    """V for (N, H, d) -> (N,) float64; NaN counts as +inf (never preferred). Every candidate,
    final samples included, passes here: non-finite trajectories stop the steering."""
    n = require_finite(trajectories).shape[0]
    out = np.asarray(value_fn(trajectories), dtype=np.float64)
    if out.shape != (n,):
        raise ValueError(f"value_fn must return shape ({n},) for {n} trajectories, got "
                         f"{out.shape}")
    return np.where(np.isnan(out), np.inf, out)


def _select(values: np.ndarray, alpha: np.ndarray, generator: torch.Generator | None
            ) -> np.ndarray:
    """Index of the kept candidate per particle from values (B, M): argmin where the particle's
    alpha (B,) is 0, else a draw from softmax(-V / alpha)."""
    pick = np.argmin(values, axis=1)  # all-inf rows pick candidate 0
    soft = alpha > 0
    if soft.any():
        logits = -values[soft] / alpha[soft, None]
        finite = np.isfinite(logits)
        # Rows where every candidate is infinitely bad: choose uniformly.
        logits = np.where(finite.any(axis=1, keepdims=True), logits, 0.0)
        logits = logits - logits.max(axis=1, keepdims=True)
        probs = torch.as_tensor(np.exp(logits), dtype=torch.float64)
        pick[soft] = torch.multinomial(probs, 1, generator=generator).squeeze(1).numpy()
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


@torch.inference_mode()
def steer(policy: DiffusionPolicy, task: str | Sequence[str], n_particles: int,
          value_fn: ValueFn, *, num_candidates: int = 8,
          alpha: float | Sequence[float] | np.ndarray = 0.0,
          start: np.ndarray | None = None, generator: GeneratorLike = None,
          num_steps: int | None = None) -> SteerResult:
    """Sample ``n_particles`` trajectories steered toward low ``value_fn`` with SVDD-PM.

    task: one task name or one per particle; start: (d,) or (B, d) for start-conditioned
    policies. value_fn: (N, H, d) world-unit trajectories -> (N,) values, lower is better.
    num_candidates: M >= 1 draws from the reverse kernel per particle and step (M = 1 is plain
    sampling: same seed, same trajectories as :meth:`DiffusionPolicy.sample`).
    alpha: 0 keeps the best candidate (the SVDD authors' choice); alpha > 0 draws from
    softmax(-V / alpha), V in value_fn's units; one value for all particles or one per
    particle (see :func:`particle_temperatures`). generator: seed or CPU generator.
    num_steps: reverse steps S (default: the policy's ``num_inference_steps``); a step costs M
    network passes, so fewer steps are proportionally cheaper.
    """
    b, m = n_particles, num_candidates
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

    t0 = time.perf_counter()
    gen = as_generator(generator)
    policy.model.eval()
    cond = policy.condition(task, b, start)                    # (B, c)
    cond_rep = cond.repeat_interleave(m, dim=0)                # (B*M, c), particle-major
    timesteps = policy.timesteps(num_steps)
    stats = SteerStats(b, m, len(timesteps))

    def network(x: torch.Tensor, t: int, c: torch.Tensor) -> torch.Tensor:
        stats.rows_per_call.append(int(x.shape[0]))
        return policy.predict_noise(x, t, c)

    x = policy.initial_noise(b, gen)                           # x_T, (B, H, d)
    eps = network(x, timesteps[0], cond)
    rows = torch.arange(b, device=x.device) * m
    values = np.zeros(b)
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
        v = _score(value_fn, policy.to_world(x0_hat)).reshape(b, m)
        stats.value_calls += 1
        stats.value_rows += b * m
        pick = _select(v, alphas, gen)
        keep = rows + torch.as_tensor(pick, device=x.device)
        x = cand[keep]
        if cand_eps is not None:
            eps = cand_eps[keep]                               # reused: no extra pass
        values = v[np.arange(b), pick]
        stats.kept_value.append(float(np.mean(values)))

    stats.network_passes = sum(stats.rows_per_call) // b
    stats.seconds = time.perf_counter() - t0
    return SteerResult(policy.to_world(x), values, stats)


# -- the paper's value function ---------------------------------------------------------------
def completion_index(trajectories: np.ndarray, tol: float) -> np.ndarray:
    """(N, H, d) -> (N,) int: first index from which the trajectory stays within ``tol`` of its
    final point, i.e. where the motion is done (demonstrations are padded with their last
    point). 0 for a trajectory that never moves."""
    traj = np.asarray(trajectories, dtype=np.float64)
    if traj.ndim != 3:
        raise ValueError(f"expected (N, H, d) trajectories, got shape {traj.shape}")
    if not tol > 0:
        raise ValueError(f"tol must be > 0, got {tol}")
    far = np.linalg.norm(traj - traj[:, -1:], axis=-1) > tol       # (N, H)
    h = traj.shape[1]
    last_far = h - 1 - np.argmax(far[:, ::-1], axis=1)
    return np.where(far.any(axis=1), last_far + 1, 0)


def proximity_cost(points: np.ndarray, beta: float) -> ValueFn:
    """S(xi) = max over the trajectory and over ``points`` (P, d) of exp(-beta ||x - p||):
    the paper's per-person spatial cost (Eq. 8) for someone standing at the given points."""
    pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
    if not beta > 0:
        raise ValueError(f"beta must be > 0, got {beta}")

    def cost(trajectories: np.ndarray) -> np.ndarray:
        traj = np.asarray(trajectories, dtype=np.float64)
        if traj.shape[-1] != pts.shape[1]:
            raise ValueError(f"cost points have d={pts.shape[1]}, trajectories "
                             f"d={traj.shape[-1]}")
        dist = np.linalg.norm(traj[:, :, None, :] - pts[None, None], axis=-1)  # (N, H, P)
        return np.exp(-beta * dist.min(axis=(1, 2)))

    return cost


def value_function(spatial_costs: Sequence[ValueFn], gamma: float, *, tol: float,
                   dt: float = 1.0, hold: ValueFn | None = None) -> ValueFn:
    """The paper's V(xi) = d(xi) + gamma * max_i S_i(xi), batched (N, H, d) -> (N,).

    d(xi) = completion_index * dt (seconds when dt is the time per trajectory point);
    spatial_costs: S_i of the concurrent human tasks C_j (empty: completion time only);
    hold: the seconds a safety monitor would add to each motion (None: the paper's V), so
    that V is the time the motion takes under the monitor (:mod:`rapidds.execution.slowdowns`).
    """
    costs = list(spatial_costs)
    if not (math.isfinite(gamma) and gamma >= 0):
        raise ValueError(f"gamma must be a finite number >= 0, got {gamma}")

    def value(trajectories: np.ndarray) -> np.ndarray:
        v = completion_index(trajectories, tol).astype(np.float64) * dt
        if costs and gamma > 0:
            s = np.stack([np.asarray(c(trajectories), dtype=np.float64) for c in costs])
            v = v + gamma * s.max(axis=0)
        if hold is not None:
            v = v + np.asarray(hold(trajectories), dtype=np.float64)
        return v

    return value
