"""The screened polish of big jobs: its lower bound, where it stops, the optimum it reaches on a
small stochastic job when forced on, and determinism."""

from __future__ import annotations

import itertools
import random
import time

import numpy as np
import pytest
from test_scheduler import random_problem

from rapidds.motion.interface import FixedDurationMotion, TrajectoryCache
from rapidds.problem import Problem
from rapidds.schedule import Schedule
from rapidds.scheduler import (
    AllocationHistory,
    EvaluationContext,
    GAConfig,
    GeneticScheduler,
    evaluate_population,
)
from rapidds.scheduler import polish as polishing
from rapidds.scheduler.evaluator import Evaluator
from rapidds.scheduler.operators import Operators
from rapidds.scheduler.seeding import list_schedule


def _job(seed: int, n: int) -> tuple[Problem, np.ndarray, np.ndarray]:
    """A random job and K = 24 human duration samples 30 % around the means."""
    rng = np.random.default_rng(seed)
    p = random_problem(rng, n)
    mean = np.array([t.human_mean or 0.0 for t in p.tasks])
    return p, mean * rng.uniform(0.7, 1.3, size=(24, n)), mean


def _evaluator(p: Problem, samples: np.ndarray, mean: np.ndarray, config: GAConfig,
               lam: float = 0.0, history: AllocationHistory | None = None) -> Evaluator:
    motion = FixedDurationMotion(p)
    context = EvaluationContext(p, samples, mean, TrajectoryCache(motion),
                                motion.nominal_durations(p), 0.0, lam, history)
    return Evaluator(context, config, time.perf_counter())


def test_lower_bound_is_below_every_objective() -> None:
    p, samples, mean = _job(3, 14)
    history = AllocationHistory()
    history.record(Schedule(p.ids, ()))  # z_d then differs between allocations
    ev = _evaluator(p, samples, mean, GAConfig(order_search_nodes=0), lam=2.0, history=history)
    ops = Operators(p, GAConfig().weights())
    rng = random.Random(0)
    schedules = list(dict.fromkeys(list_schedule(ops, rng, mean, ev.d_init) for _ in range(40)))
    schedules += polishing.neighbours(ops, schedules[0])
    bound, load = ev.lower_bounds(schedules)
    objective = np.array([e.objective for e in ev.evaluate(schedules)])
    feasible = np.isfinite(objective)
    assert feasible.sum() > 100
    assert np.array_equal(np.isfinite(bound), feasible)
    assert np.all(bound[feasible] <= objective[feasible] + 1e-9)
    assert np.all(load[feasible] <= bound[feasible] + 1e-9)  # an agent's load never overlaps
    assert np.all(np.isfinite(load))  # a deadlocked order's allocation still has its loads
    assert np.any(bound[feasible] > objective[feasible] - 1e-3 * objective[feasible]), \
        "a bound this loose would screen nothing"


@pytest.mark.parametrize("seed", range(3))
def test_screened_polish_stops_only_where_no_neighbour_improves(seed: int) -> None:
    p, samples, mean = _job(40 + seed, 16)
    config = GAConfig(order_search_nodes=0, polish_window=0)
    ev = _evaluator(p, samples, mean, config)
    ops = Operators(p, config.weights())
    start = ev.evaluate([list_schedule(ops, random.Random(seed), mean, ev.d_init)])[0]
    end = polishing.polish(ops, config, start, ev)
    assert end.objective < start.objective
    every = ev.evaluate(polishing.neighbours(ops, end.schedule))  # no screen: each in full
    assert min(e.objective for e in every) >= end.objective - 1e-9


def _stochastic_optimum(p: Problem, samples: np.ndarray, mean: np.ndarray) -> float:
    """The least mean makespan on ``samples`` over every allocation and pair of orders (waits
    only delay when robot durations are fixed)."""
    schedules = []
    for agents in itertools.product(*(sorted(t.allowed) for t in p.tasks)):
        h = [t for t, a in zip(p.ids, agents, strict=True) if a == "human"]
        r = [t for t, a in zip(p.ids, agents, strict=True) if a == "robot"]
        schedules += [Schedule(a, b) for a in itertools.permutations(h)
                      for b in itertools.permutations(r)]
    motion = FixedDurationMotion(p)
    out = evaluate_population(EvaluationContext(p, samples, mean, TrajectoryCache(motion),
                                                motion.nominal_durations(p), 0.0, 0.0),
                              schedules)
    return min(e.objective for e in out)


@pytest.mark.parametrize("seed", range(4))
def test_screened_polish_reaches_the_optimum_of_a_small_stochastic_job(seed: int) -> None:
    p, samples, mean = _job(60 + seed, 6)
    config = GAConfig(seed=seed, population=6, generations=3, order_search_nodes=0,
                      exact_seed_work=0, polish_screen_min_tasks=0, polish_screen_chunk=2)
    result = GeneticScheduler(p, FixedDurationMotion(p), config).solve(samples, mean, gamma=0.0)
    assert result.best.objective == pytest.approx(_stochastic_optimum(p, samples, mean),
                                                  rel=1e-12)


def test_screened_polish_is_deterministic_and_applies_from_its_size_on() -> None:
    p, samples, mean = _job(9, 16)
    config = GAConfig(seed=5, population=16, generations=20, exact_seed_work=0)
    runs = [GeneticScheduler(p, FixedDurationMotion(p), config).solve(samples, mean)
            for _ in range(2)]
    assert runs[0].best.schedule == runs[1].best.schedule
    assert runs[0].best_by_generation == runs[1].best_by_generation
    assert runs[0].evaluations == runs[1].evaluations
    whole = GeneticScheduler(p, FixedDurationMotion(p), config.replace(
        polish_screen_min_tasks=17)).solve(samples, mean)
    assert runs[0].evaluations < whole.evaluations  # the screen skipped neighbours
