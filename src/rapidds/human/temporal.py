"""Temporal model of one person: a Normal-Inverse-Gamma belief about each task's duration.

Each human task i has a duration d ~ N(mu_i, sigma_i^2) with unknown (mu_i, sigma_i^2) and a
conjugate Normal-Inverse-Gamma belief NIG(mu, nu, alpha, beta) over them (paper, "Temporal
Adaptation"; docs/design-notes.md items 4 and 13). One observed duration x gives

    mu' = (nu*mu + x)/(nu+1),  nu' = nu+1,  alpha' = alpha+1/2,
    beta' = beta + nu*(x-mu)^2 / (2(nu+1)).

The scheduler plans with duration samples. Two ways to draw them:

* ``"predictive"`` (default): the posterior predictive, a Student-t with 2*alpha degrees of
  freedom, location mu and scale^2 = beta*(nu+1)/(alpha*nu). It carries the uncertainty about
  mu and sigma^2 itself, which matters most in early cycles when little has been observed.
* ``"plugin"``: the paper's N(E[mu], E[sigma^2]) with E[sigma^2] = beta/(alpha-1); it ignores
  that uncertainty and is kept for comparison with the paper.

Forgetting (beyond the paper, docs/design-notes.md "Teammates who change"): with a factor
f < 1 every update first flattens the belief, raising it to the power f (exponential
forgetting: nu, alpha and beta times f, mu kept), so an observation k updates old weighs f^k
and the belief holds about 1/(1 - f) observations' worth of evidence: it follows a person who
changes and never becomes more certain than that. The prior is forgotten too, so the mean is
the exponentially weighted mean of the observations, with no pull towards the population (a
"stabilised" variant that keeps the prior biased a settled belief by ~1/6 of the way back to
it at f = 0.8). f = 1 is the paper's update exactly. ``start`` drops the observations before
a detected change; ``base`` (None: the prior) is the belief that segment starts from, e.g. the
old person's belief moved by a person-level change seen on other tasks.

Durations are physical, so every sample is clipped at :data:`MIN_DURATION` (a Normal or
Student-t has mass below zero; a negative duration would let a schedule finish before it
starts). A task whose belief has beta = 0 (prior std 0 in the problem file, never contradicted
by an observation) samples exactly its mean.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, Field, StrictStr, ValidationError

from rapidds.errors import StateError
from rapidds.fileio import atomic_write_text
from rapidds.problem import Problem
from rapidds.settings import Int, NonNegative, Positive, Real, error_line, settings_dataclass

Sampling = Literal["predictive", "plugin"]
SAMPLING_METHODS: tuple[Sampling, Sampling] = ("predictive", "plugin")

MIN_DURATION = 1e-3
"""Floor (seconds) on sampled durations, so a heavy lower tail cannot produce a duration <= 0."""

DEFAULT_NU = 1.0
"""Prior pseudo-observations behind mu: one, so the person's first cycle already moves the mean
halfway from the prior to what was seen."""

DEFAULT_ALPHA = 2.0
"""Prior shape: the smallest round value with a finite E[sigma^2] (needs alpha > 1), i.e. a weak
belief about the variance that a handful of cycles overrides."""

_FORMAT = "rapidds.temporal"
_VERSION = 1


def _check_duration(x: float) -> float:
    x = float(x)
    if not math.isfinite(x) or x <= 0:
        raise ValueError(f"an observed duration must be a finite number > 0, got {x}")
    return x


def _check_sampling(sampling: str) -> Sampling:
    if sampling not in SAMPLING_METHODS:
        raise ValueError(f"sampling must be one of {', '.join(SAMPLING_METHODS)}, got {sampling!r}")
    return sampling


@settings_dataclass("NIGPrior")
class NIGPrior:
    """Normal-Inverse-Gamma parameters (mu, nu, alpha, beta): sigma^2 ~ IG(alpha, beta),
    mu | sigma^2 ~ N(mu, sigma^2/nu). Immutable: updates return a new value."""

    mu: Real
    nu: Positive
    alpha: Positive
    beta: NonNegative

    @classmethod
    def from_moments(
        cls, mean: float, std: float, nu: float = DEFAULT_NU, alpha: float = DEFAULT_ALPHA
    ) -> NIGPrior:
        """Prior with E[mu] = mean and E[sigma^2] = std^2, i.e. beta = std^2 * (alpha - 1).

        ``std`` is read as the person's own cycle-to-cycle spread. The prior predictive variance
        is then std^2 * (1 + 1/nu): that spread plus the uncertainty about the mean.
        """
        if alpha <= 1:
            raise ValueError(f"alpha must be > 1 for a finite E[sigma^2], got {alpha}")
        if not (math.isfinite(std) and std >= 0):
            raise ValueError(f"std must be a finite number >= 0, got {std}")
        return cls(float(mean), float(nu), float(alpha), float(std) ** 2 * (alpha - 1))

    def update(self, x: float) -> NIGPrior:
        """Posterior after one observed duration ``x``."""
        x = _check_duration(x)
        nu1 = self.nu + 1
        return NIGPrior(
            mu=(self.nu * self.mu + x) / nu1,
            nu=nu1,
            alpha=self.alpha + 0.5,
            beta=self.beta + self.nu * (x - self.mu) ** 2 / (2 * nu1),
        )

    def discounted(self, factor: float) -> NIGPrior:
        """This belief raised to the power ``factor`` in (0, 1] (and renormalised): the same mean,
        nu, alpha and beta times ``factor``. ``factor`` = 1 returns self. At f >= 0.75 a belief
        updated once per cycle keeps alpha >= 2 (a finite E[sigma^2] for plug-in sampling)."""
        if not 0 < factor <= 1:
            raise ValueError(f"forgetting factor must be in (0, 1], got {factor}")
        if factor == 1:
            return self
        return NIGPrior(mu=self.mu, nu=factor * self.nu, alpha=factor * self.alpha,
                        beta=factor * self.beta)

    def update_many(self, xs: Iterable[float]) -> NIGPrior:
        """Posterior after several observations at once (the batch form of :meth:`update`)."""
        arr = np.array([_check_duration(x) for x in xs], dtype=float)
        if arr.size == 0:
            return self
        n, xbar = arr.size, float(arr.mean())
        nu1 = self.nu + n
        return NIGPrior(
            mu=(self.nu * self.mu + n * xbar) / nu1,
            nu=nu1,
            alpha=self.alpha + n / 2,
            beta=self.beta
            + 0.5 * float(((arr - xbar) ** 2).sum())
            + n * self.nu * (xbar - self.mu) ** 2 / (2 * nu1),
        )

    @property
    def expected_variance(self) -> float:
        """E[sigma^2] = beta/(alpha-1); inf when alpha <= 1."""
        return self.beta / (self.alpha - 1) if self.alpha > 1 else math.inf

    @property
    def predictive_dof(self) -> float:
        return 2 * self.alpha

    @property
    def predictive_scale(self) -> float:
        """Scale of the Student-t posterior predictive (not its standard deviation)."""
        return math.sqrt(self.beta * (self.nu + 1) / (self.alpha * self.nu))

    def std(self, sampling: Sampling = "predictive") -> float:
        """Standard deviation of the distribution :meth:`sample` draws from (before clipping)."""
        if sampling == "plugin":
            return math.sqrt(self.expected_variance)
        if self.alpha <= 1:
            return math.inf
        return math.sqrt(self.beta * (self.nu + 1) / (self.nu * (self.alpha - 1)))

    def sample(
        self, k: int, rng: np.random.Generator, sampling: Sampling = "predictive"
    ) -> np.ndarray:
        """(k,) durations, clipped at MIN_DURATION; exactly mu when beta is 0."""
        return _draw(
            np.array([self.mu]), np.array([self.nu]), np.array([self.alpha]),
            np.array([self.beta]), k, rng, _check_sampling(sampling),
        )[:, 0]

    def to_dict(self) -> dict[str, float]:
        return {"mu": self.mu, "nu": self.nu, "alpha": self.alpha, "beta": self.beta}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> NIGPrior:
        return cls(float(d["mu"]), float(d["nu"]), float(d["alpha"]), float(d["beta"]))


def _draw(
    mu: np.ndarray,
    nu: np.ndarray,
    alpha: np.ndarray,
    beta: np.ndarray,
    k: int,
    rng: np.random.Generator,
    sampling: Sampling,
) -> np.ndarray:
    """(k, m) samples for m beliefs at once: one generator call, so a fixed seed gives the same
    numbers for every task regardless of which ones are deterministic."""
    if sampling == "plugin":
        if np.any(alpha <= 1):
            raise ValueError("plug-in sampling needs alpha > 1 (finite E[sigma^2])")
        z = rng.standard_normal((k, mu.size))
        scale = np.sqrt(beta / (alpha - 1))
    else:
        z = rng.standard_t(2 * alpha, size=(k, mu.size))
        scale = np.sqrt(beta * (nu + 1) / (alpha * nu))
    out = mu + scale * z
    return np.where(scale > 0, np.maximum(out, MIN_DURATION), mu)


@settings_dataclass("DurationModel", frozen=False)
class DurationModel:
    """Belief about one task's duration for one person: the prior, the observations and the
    current posterior (kept in step by :meth:`observe`).

    forgetting: factor f in (0, 1] of :meth:`NIGPrior.discounted` applied before each update
    (1: the paper's model). start: observations before this index are no longer believed (a
    detected change reset the belief); they stay listed as what happened. base: the belief the
    observations from ``start`` on update (None: ``prior``).
    """

    prior: NIGPrior
    observations: list[Positive] = field(default_factory=list)
    forgetting: Annotated[Real, Field(gt=0, le=1)] = 1.0
    start: Annotated[Int, Field(ge=0)] = 0
    base: NIGPrior | None = None
    posterior: NIGPrior = field(init=False)

    def __post_init__(self) -> None:
        if self.start > len(self.observations):
            raise ValueError(f"start {self.start} outside 0..{len(self.observations)}")
        self.posterior = self.fold(self.observations[self.start:], self.origin)

    @property
    def origin(self) -> NIGPrior:
        """The belief the current segment starts from."""
        return self.prior if self.base is None else self.base

    def fold(self, xs: Iterable[float], base: NIGPrior | None = None) -> NIGPrior:
        """The belief after ``xs`` starting from ``base`` (None: the prior), with this model's
        forgetting."""
        post = self.prior if base is None else base
        for x in xs:
            post = self._step(post, x)
        return post

    def _step(self, post: NIGPrior, x: float) -> NIGPrior:
        return post.discounted(self.forgetting).update(x)

    def observe(self, duration: float) -> None:
        self.posterior = self._step(self.posterior, duration)
        self.observations.append(float(duration))

    def restart(self, start: int, base: NIGPrior | None = None) -> None:
        """Believe only the observations from index ``start`` on (0 <= start <= len), starting
        from ``base`` (None: the prior)."""
        if not 0 <= start <= len(self.observations):
            raise ValueError(f"start {start} outside 0..{len(self.observations)}")
        self.start, self.base = int(start), base
        self.posterior = self.fold(self.observations[self.start:], base)

    def mean(self) -> float:
        return self.posterior.mu

    def std(self, sampling: Sampling = "predictive") -> float:
        return self.posterior.std(sampling)

    def sample(
        self, k: int, rng: np.random.Generator, sampling: Sampling = "predictive"
    ) -> np.ndarray:
        return self.posterior.sample(k, rng, sampling)

    def to_dict(self) -> dict[str, Any]:
        return {
            "prior": self.prior.to_dict(),
            "observations": list(self.observations),
            "forgetting": self.forgetting,
            "start": self.start,
            **({} if self.base is None else {"base": self.base.to_dict()}),
            "posterior": self.posterior.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> DurationModel:
        """Rebuild by replaying the observations on the prior; the stored posterior must agree."""
        model = cls(NIGPrior.from_dict(d["prior"]), [float(x) for x in d["observations"]],
                    float(d.get("forgetting", 1.0)), int(d.get("start", 0)),
                    NIGPrior.from_dict(d["base"]) if "base" in d else None)
        if "posterior" in d:
            stored = NIGPrior.from_dict(d["posterior"])
            for name in ("mu", "nu", "alpha", "beta"):
                a, b = getattr(stored, name), getattr(model.posterior, name)
                if not math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12):
                    raise ValueError(f"stored posterior {name}={a} does not match replay ({b})")
        return model


class _TemporalFile(BaseModel):
    """The stored form of a :class:`TemporalModel` (:meth:`TemporalModel.to_dict`); each
    task's belief is checked by :meth:`DurationModel.from_dict`."""

    format: Literal["rapidds.temporal"]
    version: Literal[1]
    sampling: Sampling
    tasks: list[StrictStr]
    models: dict[StrictStr, dict[str, Any]]


class TemporalModel:
    """Duration beliefs for every human-capable task of a problem, in problem task order.

    Columns of tasks the human may not do are NaN in :meth:`sample`, :meth:`mean` and
    :meth:`std`; the schedule fills them with robot durations.
    """

    def __init__(
        self,
        task_ids: Iterable[str],
        models: Mapping[str, DurationModel],
        sampling: Sampling = "predictive",
    ):
        self.task_ids: tuple[str, ...] = tuple(task_ids)
        unknown = set(models) - set(self.task_ids)
        if unknown:
            raise ValueError(f"duration models for unknown tasks {sorted(unknown)}")
        self.models: dict[str, DurationModel] = dict(models)
        self.sampling: Sampling = _check_sampling(sampling)

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def from_problem(
        cls,
        problem: Problem,
        *,
        nu: float = DEFAULT_NU,
        alpha: float = DEFAULT_ALPHA,
        sampling: Sampling = "predictive",
        forgetting: float = 1.0,
    ) -> TemporalModel:
        """Priors from each task's human mean/std in the problem file (see
        :meth:`NIGPrior.from_moments` for how std sets alpha and beta); ``forgetting`` as in
        :class:`DurationModel` (1: the paper's update)."""
        models = {
            t.id: DurationModel(NIGPrior.from_moments(t.human_mean, t.human_std or 0.0, nu, alpha),
                                forgetting=forgetting)
            for t in problem.tasks
            if t.can("human") and t.human_mean is not None
        }
        return cls(problem.ids, models, sampling)

    @classmethod
    def from_population(
        cls,
        problem: Problem,
        durations: Mapping[str, Iterable[float]],
        *,
        nu: float = DEFAULT_NU,
        alpha: float = DEFAULT_ALPHA,
        sampling: Sampling = "predictive",
        forgetting: float = 1.0,
    ) -> TemporalModel:
        """Priors from durations measured on other people: mean and sample std (ddof=1) of each
        task's list. Tasks not listed keep the problem file's prior.

        The confidence (nu, alpha) is not raised with the population size on purpose: the data
        describe other people, and the belief must stay ready to move toward this one.
        """
        model = cls.from_problem(problem, nu=nu, alpha=alpha, sampling=sampling,
                                 forgetting=forgetting)
        for tid, values in durations.items():
            if tid not in model.models:
                raise ValueError(f"population durations for '{tid}', which the human cannot do")
            arr = np.array([_check_duration(x) for x in values], dtype=float)
            if arr.size < 2:
                raise ValueError(f"task '{tid}': need at least 2 population durations")
            prior = NIGPrior.from_moments(float(arr.mean()), float(arr.std(ddof=1)), nu, alpha)
            model.models[tid] = DurationModel(prior, forgetting=forgetting)
        return model

    # -- updates and queries -------------------------------------------------------------------
    def observe(self, task_id: str, duration: float) -> None:
        """Bayesian update with one observed duration (seconds) of ``task_id``."""
        if task_id not in self.models:
            raise KeyError(f"no duration model for task '{task_id}' (not a human task)")
        self.models[task_id].observe(duration)

    def _params(self) -> tuple[np.ndarray, list[int], np.ndarray, np.ndarray, np.ndarray]:
        cols = [i for i, t in enumerate(self.task_ids) if t in self.models]
        posts = [self.models[self.task_ids[i]].posterior for i in cols]
        mu = np.array([p.mu for p in posts])
        return (
            mu,
            cols,
            np.array([p.nu for p in posts]),
            np.array([p.alpha for p in posts]),
            np.array([p.beta for p in posts]),
        )

    def sample(self, k: int, rng: np.random.Generator) -> np.ndarray:
        """(k, n) durations in problem task order; NaN columns for robot-only tasks."""
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        out = np.full((k, len(self.task_ids)), np.nan)
        mu, cols, nu, alpha, beta = self._params()
        if cols:
            out[:, cols] = _draw(mu, nu, alpha, beta, k, rng, self.sampling)
        return out

    def mean(self) -> np.ndarray:
        """(n,) posterior E[mu] per task (the mean of the sampled distribution before clipping)."""
        return np.array(
            [self.models[t].mean() if t in self.models else np.nan for t in self.task_ids]
        )

    def std(self) -> np.ndarray:
        """(n,) standard deviation of the distribution :meth:`sample` draws from."""
        return np.array(
            [self.models[t].std(self.sampling) if t in self.models else np.nan
             for t in self.task_ids]
        )

    # -- persistence ---------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-safe state; :meth:`from_dict` inverts it exactly."""
        return {
            "format": _FORMAT,
            "version": _VERSION,
            "sampling": self.sampling,
            "tasks": list(self.task_ids),
            "models": {t: m.to_dict() for t, m in self.models.items()},
        }

    @classmethod
    def from_dict(cls, d: Any) -> TemporalModel:
        """Inverse of :meth:`to_dict`; raises StateError on anything malformed."""
        try:
            f = _TemporalFile.model_validate(d)
        except ValidationError as exc:
            raise StateError(f"corrupt temporal model: {error_line(exc, with_input=True)}"
                             ) from None
        try:
            models = {t: DurationModel.from_dict(m) for t, m in f.models.items()}
            return cls(f.tasks, models, f.sampling)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise StateError(f"corrupt temporal model: {exc}") from None

    def save(self, path: str | Path) -> None:
        """Write JSON atomically (temp file in the same folder, then os.replace), so a crash
        mid-write leaves the previous file intact."""
        atomic_write_text(path, json.dumps(self.to_dict(), indent=1, allow_nan=False))

    @classmethod
    def load(cls, path: str | Path) -> TemporalModel:
        """Read a file written by :meth:`save`; StateError if missing, unreadable or corrupt."""
        path = Path(path)
        try:
            raw = json.loads(path.read_text())
        except FileNotFoundError:
            raise StateError(f"{path}: no such file") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise StateError(f"{path}: corrupt temporal model: {exc}") from None
        try:
            return cls.from_dict(raw)
        except StateError as exc:
            raise StateError(f"{path}: {exc}") from None
