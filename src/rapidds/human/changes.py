"""Has the person changed? Bayesian online change-point detection on one task's durations.

The temporal model believes a task's durations come from one N(mu, sigma^2) forever (the paper's
assumption). Fatigue, practice or a new habit break it. Adams & MacKay's change-point detector
(2007, "Bayesian Online Changepoint Detection") keeps, after n observations, a posterior over
the *run length* r: how many of the latest observations come from the person as they are now.
Each hypothesis r has its own Normal-Inverse-Gamma belief (the task's prior updated with the
last r observations, with the model's forgetting), hence its own Student-t predictive, and a new
observation x moves the mass by

    P(r + 1) ∝ P(r) (1 - H) t(x | belief_r)          (the same person)
    P(1)     ∝ H t(x | prior)                         (a new person since x)

with hazard H, the prior probability of a change at any one observation. Everything is exact
for the conjugate model; the run-length posterior is recomputed from the observations (a
person repeats a task at most a few hundred times, so the O(n^2) replay costs microseconds and
needs no state of its own: a resumed run gets the same answer).

No maintained package on PyPI does this for a conjugate NIG model with our forgetting (ruptures
is offline segmentation; the BOCPD packages found are unmaintained single-file ports), and the
recursion is a dozen lines of NumPy/SciPy, so it lives here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import gammaln, logsumexp

from rapidds.human.temporal import DurationModel

__all__ = ["Change", "detect_change", "run_length_posterior"]


def _logpred(mu: np.ndarray, nu: np.ndarray, alpha: np.ndarray, beta: np.ndarray,
             x: float) -> np.ndarray:
    """log density of ``x`` under each belief's Student-t posterior predictive."""
    out = np.where(x == mu, 0.0, -np.inf)  # a deterministic belief: only its own value
    live = beta > 0
    if live.any():
        # scipy.stats.t.logpdf written out: the same numbers without its per-call overhead
        a, n = alpha[live], nu[live]
        scale = np.sqrt(beta[live] * (n + 1) / (a * n))
        df = 2 * a
        z = (x - mu[live]) / scale
        out[live] = (gammaln(a + 0.5) - gammaln(a) - 0.5 * np.log(df * np.pi) - np.log(scale)
                     - (a + 0.5) * np.log1p(z * z / df))
    return out


def run_length_posterior(model: DurationModel, xs: Sequence[float], hazard: float) -> np.ndarray:
    """P(r = k | xs) for k = 0..n (index k), n = len(xs); entry 0 is 0 once n >= 1.

    ``model`` supplies the prior a new run starts from, the belief the whole segment starts
    from (its ``origin``) and the forgetting of each run's belief (the updates of
    :meth:`NIGPrior.discounted` and :meth:`NIGPrior.update`, on arrays: one per run length).
    """
    if not 0 < hazard < 1:
        raise ValueError(f"hazard must be in (0, 1), got {hazard}")
    p, o, f = model.prior, model.origin, model.forgetting
    logp = np.array([0.0])          # log P(r = k), k = 0..len
    mu, nu = np.array([o.mu]), np.array([o.nu])        # belief of run length k
    alpha, beta = np.array([o.alpha]), np.array([o.beta])
    lh, l1h = math.log(hazard), math.log1p(-hazard)
    for x in xs:
        pred = _logpred(mu, nu, alpha, beta, float(x))
        new = np.full(len(logp) + 1, -np.inf)
        new[1:] = logp + l1h + pred
        # a change at x: x is the first observation of the new person, scored by the prior
        new[1] = np.logaddexp(new[1], lh + pred[0])  # belief 0 is the prior
        norm = logsumexp(new)
        logp = new - norm if math.isfinite(norm) else np.log(np.full(len(new), 1 / len(new)))
        nu_f, alpha_f, beta_f = f * nu, f * alpha, f * beta
        nu1 = nu_f + 1
        beta = np.concatenate([[p.beta], beta_f + nu_f * (x - mu) ** 2 / (2 * nu1)])
        mu = np.concatenate([[p.mu], (nu_f * mu + x) / nu1])
        nu = np.concatenate([[p.nu], nu1])
        alpha = np.concatenate([[p.alpha], alpha_f + 0.5])
    return np.exp(logp)


@dataclass(frozen=True)
class Change:
    """A detected change in one task: the person is believed new from observation ``index``
    (into the model's observations) on, with ``probability`` that the run began within the
    detector's window; ``before`` and ``after`` are the believed mean durations (s) of the old
    segment and of the new one."""

    index: int
    probability: float
    before: float
    after: float

    @property
    def direction(self) -> str:
        return "slower" if self.after > self.before else "faster"


def detect_change(model: DurationModel, *, hazard: float, threshold: float,
                  min_before: int = 2) -> Change | None:
    """A change inside the model's current segment, if the run-length posterior puts more than
    ``threshold`` on the person having changed after at least ``min_before`` of its observations
    (P(1 <= r <= n - min_before)); None otherwise. The change point is the most probable such
    run length."""
    xs = model.observations[model.start:]
    n = len(xs)
    if n <= min_before:
        return None
    post = run_length_posterior(model, xs, hazard)
    inside = post[1:n - min_before + 1]
    p = float(inside.sum())
    if p <= threshold:
        return None
    r = 1 + int(np.argmax(inside))
    index = len(model.observations) - r
    before = model.fold(model.observations[model.start:index], model.base).mu
    after = model.fold(model.observations[index:]).mu
    return Change(index, p, before, after)
