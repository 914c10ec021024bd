"""Evidence about a person's gamma from a deployed cycle, and SIMULATED people's comfort.

:func:`cycle_evidence` turns what a person said (a comfort answer 1-7) and signalled ("too
close" at times t) into the learner's :class:`~rapidds.human.gamma.GammaEvidence`, tied to where
the robot was: the closeness exp(-beta * separation) over the realised cycle.

:class:`SimulatedComfort` is a SIMULATED person's own comfort: a true gamma and a response model
that is deliberately NOT the learner's likelihood (docs/design-notes.md "Learning each person's
gamma"), so a benchmark that learns it does not just prove the model agrees with itself:

* they feel nearness sharply: intrusion f(t) = (gamma / g_ref) * c(t)^2 (the learner: linear);
* "too close": a leaky integrator a(t) (time constant TAU) of f crossing a threshold that is
  redrawn (log-normal) after each signal, then a refractory pause (the learner: Poisson);
* the answer: felt = log(gamma / g_ref) + log(peak of c averaged over 1 s / 0.5) + the
  person's own bias + Gaussian noise, rounded onto 1..7 in steps of 0.7 (the learner: an
  ordered logit on the instantaneous peak, no bias);
* reactions (with ``--reacts``): they slow down (stop) where the moving robot's momentary felt
  intrusion (gamma / g_ref) c^2 exceeds what a reference person feels at the comfort (stop)
  distance drawn for them from the cell's population, i.e. at that distance plus
  log(gamma / g_ref) / (2 beta), fixed for the run (the learner: a linear closeness threshold
  with fresh logistic noise on every approach).

:func:`reaction_evidence` reads what the person did from the executor's pauses of agent
"person" (held back by the robot: slowed or stopped; a deviation's pause is not a reaction).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rapidds.human.gamma import GammaEvidence
from rapidds.loop.deploy import Deployment, separations
from rapidds.loop.observation import Said
from rapidds.worlds.base import World
from rapidds.worlds.reactions import Reaction, cell_reactions

__all__ = ["SimulatedComfort", "closeness", "cycle_evidence", "reaction_anchor",
           "reaction_evidence", "said_and_signalled", "simulated_comfort"]

TAU = 1.5  # s, how long felt intrusion lingers
THETA = 0.4  # median threshold of the integrated intrusion that makes them signal
THETA_SD = 0.3  # log-normal spread of that threshold, redrawn after every signal
REFRACTORY = 2.0  # s without a second signal after one
ANSWER_SD = 0.45  # Gaussian noise of an answer, log-units
BIAS_SD = 0.2  # a person's fixed answer bias, log-units
STEP = 0.7  # log-units per answer point
POPULATION_SPREAD = 3.0  # a simulated population's gamma: one log-sd is a factor 3


def closeness(world: World, dep: Deployment, beta: float) -> tuple[np.ndarray, np.ndarray]:
    """(times, c(t) = exp(-beta * separation(t))) over the realised cycle."""
    times, gaps = separations(world, dep)
    return times, np.exp(-beta * gaps)


def cycle_evidence(world: World, dep: Deployment, beta: float, answer: int | None,
                   too_close: Sequence[float]) -> GammaEvidence:
    """The learner's evidence of one cycle: the answer and signals with the cycle's proximity."""
    times, c = closeness(world, dep, beta)
    at = tuple(float(v) for v in np.interp(too_close, times, c)) if times.size else ()
    return GammaEvidence(answer, tuple(float(t) for t in too_close), at,
                         float(c.max()) if c.size else 0.0, float(c.sum() * world.dt))


def reaction_anchor(world: World, beta: float) -> float:
    """The closeness at which a reference person starts reacting in this cell: at the mean
    comfort distance the cell states for its people (the scale's anchor, as the answers' is
    the half distance: a cell's population, not this person)."""
    population, _ = cell_reactions(world)
    return math.exp(-beta * population.comfort[0])


def _episodes(dep: Deployment) -> list[float]:
    """Start times of the person's reaction episodes: their pauses held back by the robot,
    contiguous ones (slowed, then stopped) merged into one."""
    starts: list[float] = []
    end = -math.inf
    for p in sorted((p for p in dep.pauses if p.get("agent") == "person"
                     and p.get("reason") != "deviation"), key=lambda p: p["start"]):
        if p["start"] > end + 1e-9:
            starts.append(float(p["start"]))
        end = max(end, float(p["end"]))
    return starts


def reaction_evidence(world: World, dep: Deployment, beta: float
                      ) -> tuple[tuple[tuple[float, float], ...], float]:
    """What the person did about the robot this cycle: per reaction episode (closeness one
    sample before it began, closeness when it began), and the peak closeness while both were
    busy (person and robot each running a task) and the robot was not stopped (speed and
    separation monitoring's stops): when a reaction could happen."""
    times, c = closeness(world, dep, beta)
    if not times.size:
        return (), 0.0
    onsets = tuple((float(np.interp(t - world.dt, times, c)), float(np.interp(t, times, c)))
                   for t in _episodes(dep))
    tl = dep.timeline
    idx, start, finish = tl.problem.index, tl.start[0], tl.finish[0]

    def busy(agent: str) -> np.ndarray:
        m = np.zeros(times.shape, bool)
        for t in tl.schedule.tasks(agent):
            m |= (times >= start[idx[t]]) & (times < finish[idx[t]])
        return m

    both = busy("human") & busy("robot")
    for p in dep.pauses:  # a robot stopped for the person is no threat: nobody reacts to it
        if p.get("agent") == "robot" and str(p.get("reason", "")).endswith("(stop)"):
            both &= ~((times >= p["start"]) & (times < p["end"]))
    return onsets, float(c[both].max()) if both.any() else 0.0


def said_and_signalled(world: World, dep: Deployment, beta: float,
                       comfort: SimulatedComfort | None, said: Said | None, seed: int,
                       cycle: int) -> GammaEvidence | None:
    """Cycle ``cycle``'s evidence: from the SIMULATED person's response model (``comfort``,
    drawing from (seed, cycle)), else from what a live person ``said`` (their source's
    :class:`~rapidds.loop.observation.Said`; None: they cannot say, or were not asked)."""
    if comfort is not None:
        rng = np.random.default_rng([seed, cycle, 26])
        answer, signals = comfort.respond(world, dep, beta, rng)
    elif said is None:
        return None
    else:
        answer, signals = said.answer, list(said.too_close)
    return cycle_evidence(world, dep, beta, answer, signals)


@dataclass(frozen=True)
class SimulatedComfort:
    """A SIMULATED person's comfort with the robot: their true gamma, the reference gamma their
    scale is anchored to (the world's default) and their fixed answer bias."""

    gamma: float
    g_ref: float
    bias: float = 0.0

    def respond(self, world: World, dep: Deployment, beta: float,
                rng: np.random.Generator) -> tuple[int, list[float]]:
        """(comfort answer 1-7, times of "too close" signals) for a deployed cycle."""
        times, c = closeness(world, dep, beta)
        if not times.size:
            return 1, []
        dt, ratio = world.dt, self.gamma / self.g_ref
        signals, a, quiet_until = [], 0.0, -1.0
        theta = THETA * math.exp(rng.normal(0.0, THETA_SD))
        decay = math.exp(-dt / TAU)
        for t, ck in zip(times.tolist(), c.tolist(), strict=True):
            a = a * decay + ratio * ck * ck * dt
            if t >= quiet_until and a > theta:
                signals.append(float(t))
                a, quiet_until = 0.0, t + REFRACTORY
                theta = THETA * math.exp(rng.normal(0.0, THETA_SD))
        width = max(1, round(1.0 / dt))
        felt_peak = float(np.convolve(c, np.ones(width) / width, mode="same").max())
        felt = (math.log(ratio) + math.log(max(felt_peak, 1e-12) / 0.5) + self.bias
                + rng.normal(0.0, ANSWER_SD))
        return int(np.clip(round(4 + felt / STEP), 1, 7)), signals

    def reaction(self, drawn: Reaction, beta: float) -> Reaction:
        """Their reaction to the robot: ``drawn`` (from the cell's population, as a reference
        person's) moved out or in by log(gamma / g_ref) / (2 beta), where their felt intrusion
        (gamma / g_ref) exp(-2 beta d) equals a reference person's at the drawn distance; kept
        positive (at least a quarter of the drawn one) and the stop inside the comfort."""
        shift = math.log(self.gamma / self.g_ref) / (2 * beta)
        comfort = max(drawn.comfort + shift, 0.25 * drawn.comfort)
        stop = min(max(drawn.stop + shift, 0.25 * drawn.stop), 0.9 * comfort)
        return Reaction(comfort, stop, drawn.slow)

    def to_dict(self) -> dict[str, Any]:
        return {"simulated": True, "true_gamma": self.gamma, "bias": self.bias}


def simulated_comfort(g_ref: float, seed: int, gamma: float | None) -> SimulatedComfort:
    """A SIMULATED teammate's comfort: true gamma ``gamma``, or drawn from the population
    (log-normal about the world's default, one log-sd a factor :data:`POPULATION_SPREAD`); the
    answer bias drawn too. Seeded by the run's seed."""
    rng = np.random.default_rng([seed, 26_026])
    drawn = g_ref * math.exp(rng.normal(0.0, math.log(POPULATION_SPREAD)))
    bias = float(rng.normal(0.0, BIAS_SD))
    return SimulatedComfort(float(gamma) if gamma is not None else drawn, g_ref, bias)
