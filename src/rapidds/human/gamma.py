"""A Bayesian belief over one person's efficiency-proximity trade-off gamma.

The paper plans with one gamma for everybody (its limitation 2). Here gamma is a property of
the person, learned like their durations and paths: a posterior over log gamma on a fixed grid
(docs/design-notes.md "Learning each person's gamma"), updated after every cycle from what the
person said about it, what they signalled during it and how they reacted to the robot (slowing
or pausing near it), each tied to how close the robot came.

Model (the LEARNER's; a simulated person answers through another one, :mod:`rapidds.loop.comfort`):

* prior: log gamma ~ Normal(log g0, s0^2) (g0 the world's default gamma or ``--gamma-prior``);
* proximity of a cycle: closeness c(t) = exp(-beta * separation(t)) of the robot to the person
  (the spatial model's point cost, Eq. 7, time-synchronised); x = max_t c(t), E = int c(t) dt;
* comfort answer a in 1..7 (agreement with "the robot came too close to me"): ordered logit on
  u = log(gamma / g_ref) + log(x / X_REF), P(a <= k) = sigmoid((CUT * (k - 3.5) - u) / SCALE):
  someone with the reference gamma g_ref (the world's default) is neutral (4) when the robot's
  closest approach has closeness X_REF, i.e. at the decay's half distance; a share LAPSE of
  answers is taken as given at random (a lapse rate: people misread, misclick, or answer 1
  whenever the robot was far, whatever their gamma), so no single answer is decisive;
* "too close" signals: a Poisson process of intensity RATE * (gamma / g_ref) * c(t), so their
  count n ~ Poisson(RATE * gamma / g_ref * E) (the event times matter only through c, which
  does not depend on gamma: they are stored, not weighed);
* reactions (what the person DOES: slowing or pausing near the moving robot): on each approach
  they start to react once the closeness reaches their threshold c*, log c* = log(c_R) -
  log(gamma / g_ref) + Logistic(0, REACT_SCALE) drawn per approach, c_R the closeness at which
  a reference person reacts in this cell (the evidence's ``anchor``). An episode that began at
  closeness c after a sample at c- < c has probability F(z(c)) - F(z(c-)) (the threshold lay
  between them; F(z(c)) when c- >= c), F the logistic cdf, z(c) = (log(gamma / g_ref) +
  log(c / c_R)) / REACT_SCALE: the nearer it began, the lower gamma. A cycle without an
  episode while both were busy, at peak closeness x, has probability 1 - F(z(x)). Each mixed
  with a lapse REACT_LAPSE (an episode or its absence unrelated to the robot).

Planning uses the posterior's geometric mean exp(E[log gamma]) (``mean``: with no evidence it
is the prior's g0 exactly, so a run that learns nothing plans as the fixed prior gamma) or its
upper quantile (``cautious``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "ANSWERS",
    "DEFAULT_SPREAD",
    "GammaBelief",
    "GammaEvidence",
    "parse_gamma_prior",
]

ANSWERS = range(1, 8)  # the 7-point agreement scale
DEFAULT_SPREAD = 4.0  # prior: one standard deviation of log gamma is a factor 4
X_REF = 0.5  # closeness at which a reference person is neutral (exp(-beta d) at d = ln 2 / beta)
CUT = 0.7  # log-units between neighbouring answers' cut points
SCALE = 0.35  # logistic scale of an answer's noise, log-units
LAPSE = 0.1  # share of answers taken as given at random (uniform over the scale)
RATE = 0.3  # "too close" signals per second at closeness 1 for the reference gamma
REACT_SCALE = 0.5  # logistic scale of a reaction threshold, log-units of closeness
REACT_LAPSE = 0.1  # share of reactions (or their absence) taken as unrelated to the robot
CAUTIOUS_Q = 0.8  # the quantile a cautious robot plans with
_GRID = 241  # grid points over +-5 prior standard deviations
_SPEC = re.compile(r"^\s*([^:\s]+)\s*(?::\s*([^:\s]+)\s*)?$")


def parse_gamma_prior(spec: str) -> tuple[float, float]:
    """``"G"`` or ``"G:SPREAD"`` -> (median g0 > 0, spread > 1: the factor of one standard
    deviation of log gamma; default :data:`DEFAULT_SPREAD`); ValueError on anything else."""
    m = _SPEC.match(spec)
    try:
        if m is None:
            raise ValueError
        g0 = float(m.group(1))
        spread = float(m.group(2)) if m.group(2) is not None else DEFAULT_SPREAD
    except ValueError:
        raise ValueError("a gamma prior is G or G:SPREAD (e.g. 1.75 or 1.75:4)") from None
    if not (math.isfinite(g0) and g0 > 0 and math.isfinite(spread) and spread > 1):
        raise ValueError("a gamma prior needs G > 0 and SPREAD > 1")
    return g0, spread


@dataclass(frozen=True)
class GammaEvidence:
    """What one cycle says about gamma: the comfort answer (None: not asked or not given), the
    times of "too close" signals (s into the cycle), the closeness at each, and the cycle's
    proximity: peak closeness x and exposure E = int c(t) dt (s).

    What the person did (empty unless their reactions were watched): ``reactions``, per episode
    of slowing or pausing (closeness one sample before it began, closeness when it began);
    ``calm_peak``, the peak closeness while both were busy (None: reactions not watched);
    ``anchor``, the closeness at which a reference person reacts in this cell. ``asked``: False
    when the person could not answer or signal (then only their reactions count)."""

    answer: int | None
    too_close: tuple[float, ...]
    closeness_at: tuple[float, ...]
    peak: float
    exposure: float
    reactions: tuple[tuple[float, float], ...] = ()
    calm_peak: float | None = None
    anchor: float = 0.0
    asked: bool = True

    def __post_init__(self) -> None:
        if self.answer is not None and self.answer not in ANSWERS:
            raise ValueError(f"a comfort answer is an integer 1-7, got {self.answer!r}")
        if not (0 <= self.peak <= 1 and self.exposure >= 0):
            raise ValueError(f"proximity out of range: peak {self.peak}, exposure "
                             f"{self.exposure}")
        if self.watched and not 0 < self.anchor <= 1:
            raise ValueError(f"a reaction anchor is a closeness in (0, 1], got {self.anchor}")
        if not self.asked and (self.answer is not None or self.too_close):
            raise ValueError("a person who was not asked cannot have answered or signalled")

    @property
    def watched(self) -> bool:
        """Whether the person's reactions were watched this cycle."""
        return self.calm_peak is not None or bool(self.reactions)

    @property
    def empty(self) -> bool:
        """No answer, no exposure to the robot, no reaction watched: nothing to learn from (a
        signal with the robot nowhere near would still count: it says gamma is large)."""
        said = self.asked and (self.answer is not None or self.too_close or self.exposure > 0)
        return not said and not self.watched

    def to_dict(self) -> dict[str, Any]:
        """The record's comfort evidence; the reaction keys only where reactions were watched,
        so records without them read as before."""
        out: dict[str, Any] = {"answer": self.answer, "too_close": list(self.too_close),
                               "closeness_at": list(self.closeness_at), "peak": self.peak,
                               "exposure": self.exposure}
        if not self.asked:
            out["asked"] = False
        if self.watched:
            out["reactions"] = {"onsets": [list(r) for r in self.reactions],
                                "calm_peak": self.calm_peak, "anchor": self.anchor}
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> GammaEvidence:
        """A record's comfort evidence back (records before reactions were learned from too)."""
        r = d.get("reactions") or {}
        return cls(d["answer"], tuple(float(t) for t in d["too_close"]),
                   tuple(float(c) for c in d["closeness_at"]), float(d["peak"]),
                   float(d["exposure"]),
                   tuple((float(b), float(a)) for b, a in r.get("onsets", ())),
                   None if r.get("calm_peak") is None else float(r["calm_peak"]),
                   float(r.get("anchor", 0.0)), bool(d.get("asked", True)))


def _sigmoid(z: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * z))


class GammaBelief:
    """Grid posterior over log gamma. g_ref is the reference gamma of the likelihood (the
    world's default), g0 and spread the prior's median and factor."""

    def __init__(self, g0: float, spread: float, g_ref: float,
                 log_post: Sequence[float] | None = None, evidence: int = 0):
        self.g0, self.spread, self.g_ref = float(g0), float(spread), float(g_ref)
        s = math.log(self.spread)
        self.grid = math.log(self.g0) + np.linspace(-5 * s, 5 * s, _GRID)
        prior = -0.5 * ((self.grid - math.log(self.g0)) / s) ** 2
        self.log_post = (prior - prior.max() if log_post is None
                         else np.asarray(log_post, dtype=float))
        if self.log_post.shape != self.grid.shape:
            raise ValueError(f"gamma belief has {self.log_post.size} grid values, expected "
                             f"{self.grid.size}")
        self.evidence = int(evidence)

    # -- the posterior --------------------------------------------------------------------------
    @property
    def weights(self) -> np.ndarray:
        w = np.exp(self.log_post - self.log_post.max())
        return w / w.sum()

    def mean(self) -> float:
        """exp(E[log gamma]): the posterior's geometric mean. Before any evidence it is the
        prior's median g0 by symmetry; returned exactly, so grid rounding (~1e-15) cannot make
        a run that learned nothing plan differently from one with the fixed prior gamma."""
        if self.evidence == 0:
            return self.g0
        return float(math.exp(float(self.weights @ self.grid)))

    def quantile(self, q: float) -> float:
        """The q-quantile of gamma, interpolated on the cumulative weights (each grid point's
        weight spread over its cell, so the cdf at a point counts half of its own)."""
        w = self.weights
        cdf = np.cumsum(w) - 0.5 * w
        return float(math.exp(float(np.interp(q, cdf, self.grid))))

    def planning(self, setting: str) -> float:
        """The gamma to plan with: ``mean`` or ``cautious`` (an upper quantile)."""
        if setting == "mean":
            return self.mean()
        if setting == "cautious":
            return self.quantile(CAUTIOUS_Q)
        raise ValueError(f"gamma planning setting is mean or cautious, got {setting!r}")

    def summary(self) -> dict[str, float | int]:
        """What a cycle record keeps of the posterior."""
        w = self.weights
        m = float(w @ self.grid)
        return {"mean": self.mean(), "median": self.quantile(0.5), "q10": self.quantile(0.1),
                "q90": self.quantile(0.9), "sd_log": float(math.sqrt(w @ (self.grid - m) ** 2)),
                "evidence": self.evidence}

    # -- the likelihood -------------------------------------------------------------------------
    def answer_likelihood(self, answer: int, peak: float) -> np.ndarray:
        """P(answer | gamma, peak closeness) on the grid (the ordered logit)."""
        u = self.grid - math.log(self.g_ref) + math.log(max(peak, 1e-12) / X_REF)
        upper = 1.0 if answer == 7 else _sigmoid((CUT * (answer - 3.5) - u) / SCALE)
        lower = 0.0 if answer == 1 else _sigmoid((CUT * (answer - 4.5) - u) / SCALE)
        p = np.asarray(upper - lower, dtype=float)
        return np.maximum((1 - LAPSE) * p + LAPSE / len(ANSWERS), 1e-300)

    def reaction_likelihood(self, ev: GammaEvidence) -> np.ndarray:
        """P(the cycle's reactions | gamma) on the grid (the threshold model above): each
        episode's onset, or, without one, calm up to the peak closeness while both were busy."""
        def cdf(c: float) -> np.ndarray:
            z = (self.grid - math.log(self.g_ref) + math.log(max(c, 1e-12) / ev.anchor))
            return _sigmoid(z / REACT_SCALE)

        p = np.ones_like(self.grid)
        for before, at in ev.reactions:
            q = cdf(at) - cdf(before) if before < at else cdf(at)
            p = p * ((1 - REACT_LAPSE) * q + REACT_LAPSE / 2)
        if not ev.reactions and ev.calm_peak is not None:
            p = p * ((1 - REACT_LAPSE) * (1 - cdf(ev.calm_peak)) + REACT_LAPSE / 2)
        return np.maximum(p, 1e-300)

    def log_likelihood(self, ev: GammaEvidence) -> np.ndarray:
        """log P(evidence | gamma) on the grid, up to a constant."""
        ll = np.zeros_like(self.grid)
        if ev.answer is not None:
            ll += np.log(self.answer_likelihood(ev.answer, ev.peak))
        if ev.asked:
            rate = RATE * np.exp(self.grid) / self.g_ref * ev.exposure
            ll += len(ev.too_close) * np.log(np.maximum(rate, 1e-300)) - rate
        if ev.watched:
            ll += np.log(self.reaction_likelihood(ev))
        return ll

    def observe(self, ev: GammaEvidence) -> None:
        if ev.empty:
            return
        self.log_post = self.log_post + self.log_likelihood(ev)
        self.log_post -= self.log_post.max()
        self.evidence += 1

    # -- storage --------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {"g0": self.g0, "spread": self.spread, "g_ref": self.g_ref,
                "log_post": self.log_post.tolist(), "evidence": self.evidence}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> GammaBelief:
        return cls(float(d["g0"]), float(d["spread"]), float(d["g_ref"]),
                   [float(v) for v in d["log_post"]], int(d["evidence"]))
