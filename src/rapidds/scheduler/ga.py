"""Genetic scheduler with trajectory adaptation: one cycle of paper Algorithm 1 (lines 3-9).

A candidate is a :class:`~rapidds.schedule.Schedule` (per-agent sequences with wait tokens). The
initial population comes from randomised earliest-deadline-first list scheduling (the paper's
"EDF"), which is always feasible. Each generation keeps an elite and fills the rest with mutants
of elite parents: five operators (move, reorder, crossover, add wait, remove wait), each followed
by :func:`~rapidds.schedule.repair`; no operator puts a task on an agent that may not do it.
Evaluation (Algorithm 2) is batched over the generation and cached by schedule; the memory M (a
:class:`TrajectoryCache`) lives for one solve, i.e. one cycle.

Additions to the paper's loop, each measured on random instances against CP-SAT
(``benchmarks/bench_scheduler.py``) and each switchable in :class:`GAConfig`:

- every allocation (who does which task) the search meets is also evaluated in the shortest
  order a small branch and bound finds for it (``order_search_nodes``,
  :mod:`rapidds.scheduler.active`), so an allocation is not judged by a poor order;
- every mutant is evaluated together with two *active* versions (:meth:`GeneticScheduler.activate`,
  Giffler-Thompson left-justification, by the mutant's order and by critical path): a change in
  one agent's order often pays off only if the other agent's order follows, which single
  mutations rarely do together;
- the elite holds at most ``elites_per_allocation`` schedules per allocation (who does which
  task), so the population does not collapse onto one allocation;
- a stalled population is replaced by a fresh list-scheduled one (``restart_after``);
- the best schedule of each stalled population, the final best and the best schedule of each
  of the next-best allocations get a local search over their whole single-step neighbourhood
  (``polish``, ``polish_allocations``).
"""

from __future__ import annotations

import dataclasses
import gc
import random
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from rapidds.motion.interface import MotionModel, TrajectoryCache
from rapidds.problem import Problem
from rapidds.schedule import Schedule
from rapidds.scheduler import polish as polishing
from rapidds.scheduler import seeding
from rapidds.scheduler.active import AllocationOrders
from rapidds.scheduler.config import GAConfig
from rapidds.scheduler.diversity import AllocationHistory
from rapidds.scheduler.evaluate import Evaluation, EvaluationContext
from rapidds.scheduler.evaluator import Evaluator, allocation, expected_orders, rank
from rapidds.scheduler.operators import Operators

Progress = Callable[[int, float], None]


@dataclass(frozen=True, eq=False)
class PlanResult:
    """Outcome of one :meth:`GeneticScheduler.solve`.

    Attributes:
        best: evaluation of the best schedule found (its motions are the ones to deploy).
        best_by_generation: best objective after each generation; entry 0 is the initial
            population, so the length is ``generations_run + 1``. A final polish can still
            improve on the last entry; ``best.objective`` is the final value.
        generations_run: generations evolved (fewer than configured when patience stopped it).
        evaluations: distinct schedules evaluated.
        seconds: wall time of the solve.
        seconds_to_best: wall time until the final best was first evaluated.
        cache_hits, cache_misses, cache_size: statistics of the memory M.
        improvements: (seconds, objective) each time the best objective improved, from the
            first evaluation on: how fast the search got how close.
        timed_out: True when ``GAConfig.time_limit_s`` stopped the search.
        seeds: schedules that joined the first population from outside the search (the
            caller's ``initial`` ones and the CP-SAT seed), after validation.
    """

    best: Evaluation
    best_by_generation: list[float]
    generations_run: int
    evaluations: int
    seconds: float
    seconds_to_best: float
    cache_hits: int
    cache_misses: int
    cache_size: int
    improvements: list[tuple[float, float]] = dataclasses.field(default_factory=list)
    timed_out: bool = False
    seeds: list[Schedule] = dataclasses.field(default_factory=list)


@dataclass
class _Loop:
    """The state of the generation loop: the ranked population, the best objective after each
    generation, and the counters that stop it or restart the population."""

    ranked: list[Evaluation]
    history_best: list[float]
    polished: set[Schedule] = dataclasses.field(default_factory=set)
    generations: int = 0
    timed_out: bool = False
    stall: int = 0  # generations since the overall best improved (patience)
    local_stall: int = 0  # generations since this population's best improved (restart)


class GeneticScheduler:
    """Plans one cycle: the schedule, waits and robot motions minimising z_t + gamma z_s + lam z_d.

    Args:
        problem: the job.
        motion: answers (j, C_j) motion requests; it is wrapped in a fresh memory M per solve.
        config: search settings (defaults: :class:`GAConfig`).
    """

    def __init__(self, problem: Problem, motion: MotionModel, config: GAConfig | None = None):
        self.problem = problem
        self.motion = motion
        self.config = config or GAConfig()
        self.ops = Operators(problem, self.config.weights())

    # ----------------------------------------------------------------------------- search

    def solve(
        self,
        human_samples: np.ndarray,
        human_mean: np.ndarray,
        *,
        gamma: float | None = None,
        lam: float | None = None,
        history: AllocationHistory | None = None,
        progress: Progress | None = None,
        initial: Sequence[Schedule] = (),
    ) -> PlanResult:
        """Search schedules for one cycle.

        Args:
            human_samples: (K, n) sampled human durations in problem task order; every candidate
                is evaluated on these same samples.
            human_mean: (n,) expected human durations: the expected timeline that defines C_j,
                and the durations the initial list scheduling plans with.
            gamma, lam: objective weights; default ``problem.objective``.
            history: past allocations for the diversity term.
            progress: called as ``progress(generation, best_objective)`` after the initial
                population (generation 0) and after every generation.
            initial: schedules that join the first population, e.g. last cycle's best ones
                (re-use across cycles); each must hold every task once on an allowed agent
                (ValueError otherwise). Empty (the default) leaves the search as it was.
        """
        t0 = time.perf_counter()
        problem = self.problem
        ev = Evaluator(EvaluationContext(
            problem, np.atleast_2d(np.asarray(human_samples, dtype=float)),
            np.asarray(human_mean, dtype=float), TrajectoryCache(self.motion),
            np.asarray(self.motion.nominal_durations(problem), dtype=float),
            problem.objective.gamma if gamma is None else float(gamma),
            problem.objective.lam if lam is None else float(lam),
            history,
        ), self.config, t0)
        with _without_cyclic_gc():
            return self._search(ev, progress, initial)

    def _search(self, ev: Evaluator, progress: Progress | None, initial: Sequence[Schedule]
                ) -> PlanResult:
        """The body of :meth:`solve`: the first population, the generations, the polish."""
        cfg = self.config
        rng = random.Random(cfg.seed)
        seeds = seeding.seeds(self.ops, self.motion, cfg, initial, ev.mean, ev.d_init)
        population = seeding.initial_population(self.ops, cfg.population, rng, ev.mean,
                                                ev.d_init, seeds)
        ranked = rank(ev.evaluate(population))
        assert ev.best is not None
        loop = _Loop(ranked, [ev.best.objective])
        if progress:
            progress(0, ev.best.objective)
        n_elite = min(cfg.n_elite, len(ranked))
        for generation in range(1, cfg.generations + 1):
            if ev.late():
                loop.timed_out = True
                break
            loop.generations = generation
            if not self._generation(ev, rng, loop, n_elite, progress):
                break
        self._final_polish(ev, loop.polished)
        best = ev.best
        return PlanResult(
            best=best,
            best_by_generation=loop.history_best,
            generations_run=loop.generations,
            evaluations=len(ev.evaluated),
            seconds=time.perf_counter() - ev.t0,
            seconds_to_best=ev.best_time,
            cache_hits=ev.cache.hits,
            cache_misses=ev.cache.misses,
            cache_size=len(ev.cache),
            improvements=ev.improvements,
            timed_out=loop.timed_out or ev.late(),
            seeds=seeds,
        )

    def _generation(self, ev: Evaluator, rng: random.Random, loop: _Loop, n_elite: int,
                    progress: Progress | None) -> bool:
        """One generation: elites, their children, a restart of a stalled population. False
        when the search should stop (nothing new to evaluate, or out of patience)."""
        cfg = self.config
        assert ev.best is not None
        before, local_before = ev.best.objective, loop.ranked[0].objective
        elites = ev.complete(_select_elites(loop.ranked, n_elite, cfg.elites_per_allocation))
        children = self._children(elites, cfg.population - len(elites), rng, ev.evaluated,
                                  ev.mean, ev.d_init)
        if not children:  # every mutant of the elite has been evaluated: nothing to gain
            loop.history_best.append(ev.best.objective)
            if progress:
                progress(loop.generations, ev.best.objective)
            return False
        loop.ranked = rank(ev.evaluate(children) + elites)  # ties: newcomers first (plateau drift)
        loop.local_stall = loop.local_stall + 1 if loop.ranked[0].objective >= local_before else 0
        if cfg.restart_after and loop.local_stall >= cfg.restart_after:
            self._restart(ev, rng, loop)
        loop.stall = loop.stall + 1 if ev.best.objective >= before else 0
        loop.history_best.append(ev.best.objective)
        if progress:
            progress(loop.generations, ev.best.objective)
        return not (cfg.patience and loop.stall >= cfg.patience)

    def _restart(self, ev: Evaluator, rng: random.Random, loop: _Loop) -> None:
        """A stalled population: polish its best, then start again from list schedules."""
        head = loop.ranked[0]
        if self.config.polish and head.schedule not in loop.polished:
            loop.polished.add(head.schedule)
            loop.polished.add(polishing.polish(self.ops, self.config, head, ev).schedule)
        loop.ranked = rank(ev.evaluate(seeding.initial_population(
            self.ops, self.config.population, rng, ev.mean, ev.d_init)))
        loop.local_stall = 0

    def _final_polish(self, ev: Evaluator, polished: set[Schedule]) -> None:
        """The end of a solve: polish the best, then the best of the runner-up allocations."""
        cfg = self.config
        assert ev.best is not None
        if cfg.polish and ev.best.schedule not in polished and not ev.late():
            polished.add(polishing.polish(self.ops, cfg, ev.best, ev, ev.late).schedule)
        if cfg.polish and cfg.polish_allocations > 1 and not ev.late():
            polishing.polish_runners_up(self.ops, cfg, ev, polished)

    def _children(
        self,
        parents: list[Evaluation],
        count: int,
        rng: random.Random,
        evaluated: dict[Schedule, Evaluation],
        mean: np.ndarray,
        d_init: np.ndarray,
    ) -> list[Schedule]:
        """Up to ``count`` distinct schedules never evaluated before (fewer on tiny problems):
        mutants of the parents and, with ``activate_children``, their active versions."""
        weights = self.config.weights()
        out: dict[Schedule, None] = {}
        misses = 0  # consecutive mutants seen before: many means the parents' surroundings are
        while len(out) < count and misses < 2 * count:  # exhausted (tiny problems)
            parent = rng.choice(parents)
            child = self.mutate(parent.schedule, rng, weights, parent.expected_start)
            if child is None or child in evaluated or child in out:
                misses += 1
                continue
            misses = 0
            out[child] = None
            if self.config.activate_children:
                orders = self._orders(child, mean, d_init)
                for by_path in (False, True):
                    active = orders.active(by_path)
                    if len(out) < count and active is not None and active not in evaluated:
                        out[active] = None
        return list(out)

    # ------------------------------------------------------------------ public building blocks

    def activate(self, s: Schedule, mean: np.ndarray, d_init: np.ndarray,
                 critical_path: bool = False) -> Schedule | None:
        """Giffler-Thompson left-justification of ``s`` on expected durations.

        Keeps the allocation and rebuilds both sequences on the expected durations (human
        ``mean``, robot ``d_init``) so that no task could start earlier without delaying another
        (an active schedule); among tasks that compete for an agent the one earlier in ``s``
        goes first, or with ``critical_path`` the one with the longest path to the end of the
        job under this allocation (ties: earlier in ``s``).
        A wait token stays attached in front of the task that followed it. The result is
        usually shorter than ``s`` and never deadlocks through order alone, so this also
        repairs many deadlocked mutants. None if the waits make every order cyclic.
        """
        return self._orders(s, mean, d_init).active(critical_path)

    def _orders(self, s: Schedule, mean: np.ndarray, d_init: np.ndarray) -> AllocationOrders:
        return expected_orders(self.problem, s, mean, d_init)

    def mutate(self, parent: Schedule, rng: random.Random, weights: list[float] | None = None,
               start: np.ndarray | None = None) -> Schedule | None:
        """One repaired mutant that differs from ``parent``; None if no operator applies
        (:meth:`Operators.mutate`)."""
        return self.ops.mutate(parent, rng, weights, start)

    def list_schedule(self, rng: random.Random, mean: np.ndarray, d_init: np.ndarray) -> Schedule:
        """Randomised earliest-deadline-first list scheduling (:func:`seeding.list_schedule`)."""
        return seeding.list_schedule(self.ops, rng, mean, d_init)

    def neighbours(self, s: Schedule, start: np.ndarray | None = None,
                   window: int = 0) -> list[Schedule]:
        """The polish neighbourhood of ``s`` (:func:`polish.neighbours`)."""
        return polishing.neighbours(self.ops, s, start, window)


@contextmanager
def _without_cyclic_gc() -> Iterator[None]:
    """Python's cyclic garbage collector off for the block (back on after, if it was on).

    A search allocates millions of small objects that the cache keeps alive, so the collector
    keeps rescanning a growing heap for cycles the search does not make: on 64 tasks that was
    a quarter of the run. Reference counting still frees everything as usual."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _select_elites(ranked: list[Evaluation], count: int, per_allocation: int) -> list[Evaluation]:
    """The ``count`` best, at most ``per_allocation`` of them with the same allocation (who does
    which task; 0 = no limit); slots left when allocations run out go to the best of the rest.
    """
    if not per_allocation:
        return ranked[:count]
    taken: dict[frozenset[str], int] = {}
    chosen: list[Evaluation] = []
    skipped: list[Evaluation] = []
    for e in ranked:
        if len(chosen) == count:
            break
        key = allocation(e.schedule)
        if taken.get(key, 0) < per_allocation:
            taken[key] = taken.get(key, 0) + 1
            chosen.append(e)
        else:
            skipped.append(e)
    return rank(chosen + skipped[: count - len(chosen)])
