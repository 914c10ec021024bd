"""The memory of one GA solve: every schedule evaluated (slim), the best so far and when it was
found, the allocations whose order has been searched, and the deadline. The search loop, the
polish and the seeding all evaluate through one :class:`Evaluator`."""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence

import numpy as np

from rapidds.motion.interface import FixedDurationMotion
from rapidds.problem import Problem
from rapidds.schedule import Schedule, ScheduleBatch
from rapidds.scheduler.active import AllocationOrders
from rapidds.scheduler.config import GAConfig
from rapidds.scheduler.diversity import diversity_term
from rapidds.scheduler.evaluate import Evaluation, EvaluationContext, evaluate_population

_NONE = np.empty(0)


def slim(e: Evaluation) -> Evaluation:
    """What the search keeps of an evaluation it may meet again: the schedule and the
    objective. The samples' makespans, the motions, the overlaps and the timeline of every
    schedule evaluated would fill gigabytes on 64-128 tasks; the few cached schedules that
    become parents or polish starts are evaluated again for their start times."""
    return dataclasses.replace(e, makespan=_NONE, motions={}, overlaps={},
                               expected_start=_NONE, expected_finish=_NONE)


def allocation(s: Schedule) -> frozenset[str]:
    """Who does which task, as the set of the human's tasks."""
    return frozenset(s.tasks("human"))


def rank(evaluations: list[Evaluation]) -> list[Evaluation]:
    """Best first; ties keep their order (deterministic). nan (never produced) sorts last."""
    return sorted(evaluations, key=lambda e: math.inf if math.isnan(e.objective) else e.objective)


def expected_orders(problem: Problem, s: Schedule, mean: np.ndarray, d_init: np.ndarray
                    ) -> AllocationOrders:
    """The allocation of ``s`` on expected durations (human ``mean``, robot ``d_init``)."""
    index = problem.index
    return AllocationOrders(
        s, problem, lambda t, a: mean[index[t]] if a == "human" else d_init[index[t]],
    )


class Evaluator:
    """Evaluates schedules for one solve (Algorithm 2 through :func:`evaluate_population`) and
    remembers them.

    Args:
        context: the job, the (K, n) sampled and (n,) expected human durations, the (n,)
            nominal robot durations, the memory M of this solve and the objective's weights;
            its cap on the overlap loop is replaced by ``config.max_overlap_iters``.
        config: the search settings.
        t0: ``time.perf_counter()`` at the start of the solve.
    """

    def __init__(self, context: EvaluationContext, config: GAConfig, t0: float):
        self.context = dataclasses.replace(context, max_overlap_iters=config.max_overlap_iters)
        self.problem, self.config = context.problem, config
        samples = context.human_samples
        self.samples, self.mean, self.d_init = samples, context.human_mean, context.d_init
        self.cache, self.gamma, self.lam = context.cache, context.gamma, context.lam
        self.history = context.history
        self.t0 = t0
        self.deadline = math.inf if config.time_limit_s is None else t0 + config.time_limit_s
        self.evaluated: dict[Schedule, Evaluation] = {}
        self.best: Evaluation | None = None
        self.best_time = 0.0
        self.improvements: list[tuple[float, float]] = []
        self.searched: set[int] = set()  # allocations whose order was searched, as bit masks
        self._sample_mean = samples.mean(axis=0)[None]  # (1, n): the row of lower_bound

    @property
    def bounded(self) -> bool:
        """Whether :meth:`lower_bounds` bound the objective: robot durations that no overlap
        changes and no spatial cost (a :class:`FixedDurationMotion`)."""
        return isinstance(self.cache.motion, FixedDurationMotion)

    def lower_bounds(self, schedules: Sequence[Schedule]) -> tuple[np.ndarray, np.ndarray]:
        """Two (B,) lower bounds of objectives where :attr:`bounded`, both on the samples'
        mean durations plus lam z_d: each schedule's makespan (inf where it deadlocks), and
        the larger agent's load, which bounds every order of the schedule's allocation. A
        makespan is a max of sums of durations, so convex in them, and the mean of the K
        samples' makespans is at least the makespan of their mean (Jensen). One timeline row
        instead of K + 1 and no overlap loop: about a fifteenth of an evaluation."""
        if not schedules:
            return np.empty(0), np.empty(0)
        batch = ScheduleBatch(self.problem, schedules)
        durations = batch.durations(self._sample_mean, self.d_init)
        _, finish, feasible = batch.simulate(durations)
        z_d = diversity_term(self.problem, self.history)
        extra = self.lam * np.array([z_d(s) for s in schedules])
        bound = finish[:, :, 0].max(axis=1) + extra
        bound[~feasible] = math.inf
        d = durations[:, :, 0]
        load = np.maximum(np.where(batch.human, d, 0.0).sum(axis=1),
                          np.where(batch.human, 0.0, d).sum(axis=1)) + extra
        return bound, load

    def late(self) -> bool:
        return time.perf_counter() > self.deadline

    def evaluate(self, schedules: Sequence[Schedule]) -> list[Evaluation]:
        """Evaluations of ``schedules`` (cached ones come back slim) and then, with
        ``order_search_nodes``, of the shortest order of each allocation among them not met
        before."""
        if self.config.order_search_nodes:
            schedules = [*schedules, *self.shortest_orders(schedules)]
        new = [s for s in dict.fromkeys(schedules) if s not in self.evaluated]
        full: dict[Schedule, Evaluation] = {}
        if new:
            for e in self._run(new):
                full[e.schedule] = e
                self.evaluated[e.schedule] = slim(e)
                if self.best is None or e.objective < self.best.objective:
                    self.best, self.best_time = e, time.perf_counter() - self.t0
                    self.improvements.append((self.best_time, e.objective))
        return [full[s] if s in full else self.evaluated[s] for s in schedules]

    def complete(self, evaluations: list[Evaluation]) -> list[Evaluation]:
        """``evaluations`` with their expected start times: cached slim ones are evaluated
        again (the same values; their motions are all in the memory M already)."""
        bare = [e.schedule for e in evaluations if e.feasible and not e.expected_start.size]
        if not bare:
            return evaluations
        again = {e.schedule: e for e in self._run(bare)}
        return [again.get(e.schedule, e) for e in evaluations]

    def _run(self, schedules: list[Schedule]) -> list[Evaluation]:
        return evaluate_population(self.context, schedules)

    def shortest_orders(self, schedules: Sequence[Schedule]) -> list[Schedule]:
        """The shortest order found by :meth:`AllocationOrders.search` for each allocation of
        ``schedules`` not searched before. Without waits: they only delay, and the first
        schedule met with an allocation may carry any."""
        out = []
        index = self.problem.index
        for s in schedules:
            key = sum(1 << index[t] for t in s.tasks("human"))  # small, unlike a set
            if key not in self.searched:
                self.searched.add(key)
                bare = Schedule(s.tasks("human"), s.tasks("robot"))
                orders = expected_orders(self.problem, bare, self.mean, self.d_init)
                out += orders.search(self.config.order_search_nodes, keep=1)[0]
        return out
