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
import math
import random
import time
from bisect import bisect_left
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from rapidds.errors import RapiddsError
from rapidds.motion.interface import FixedDurationMotion, MotionModel, TrajectoryCache
from rapidds.problem import AGENTS, Agent, Problem
from rapidds.schedule import Item, Schedule, Wait, repair, validate
from rapidds.scheduler.active import AllocationOrders, longest_tails
from rapidds.scheduler.config import MUTATIONS, GAConfig
from rapidds.scheduler.diversity import AllocationHistory
from rapidds.scheduler.evaluate import Evaluation, evaluate_population

Progress = Callable[[int, float], None]
# (parent, rng, parent's expected start times (n,) or None) -> child before repair, or None
Operator = Callable[[Schedule, random.Random, np.ndarray | None], Schedule | None]


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


def _other(agent: Agent) -> Agent:
    return "robot" if agent == "human" else "human"


def _closure(ids: Sequence[str], edges: Sequence[tuple[str, str]]) -> dict[str, frozenset[str]]:
    """Transitive successors of every task."""
    succ: dict[str, list[str]] = {i: [] for i in ids}
    for a, b in edges:
        succ[a].append(b)
    out: dict[str, frozenset[str]] = {}

    def visit(u: str) -> frozenset[str]:
        if u not in out:
            acc: set[str] = set()
            for v in succ[u]:
                acc.add(v)
                acc |= visit(v)
            out[u] = frozenset(acc)
        return out[u]

    for i in ids:
        visit(i)
    return out


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
        self._allowed = {t.id: t.allowed for t in problem.tasks}
        self._index = problem.index
        self._shared = problem.shared_tasks
        self._desc = _closure(problem.ids, problem.precedence)
        self._anc = _closure(problem.ids, [(b, a) for a, b in problem.precedence])
        self._preds = problem.preceding
        self._succ = problem.following
        self._ops: dict[str, Operator] = {
            "move": self._move,
            "reorder": self._reorder,
            "crossover": self._crossover,
            "add_wait": self._add_wait,
            "remove_wait": self._remove_wait,
        }

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
        with _without_cyclic_gc():
            return self._search(human_samples, human_mean, gamma, lam, history, progress,
                                initial)

    def _search(
        self,
        human_samples: np.ndarray,
        human_mean: np.ndarray,
        gamma: float | None,
        lam: float | None,
        history: AllocationHistory | None,
        progress: Progress | None,
        initial: Sequence[Schedule],
    ) -> PlanResult:
        """The body of :meth:`solve`."""
        t0 = time.perf_counter()
        cfg = self.config
        problem = self.problem
        gamma = problem.objective.gamma if gamma is None else float(gamma)
        lam = problem.objective.lam if lam is None else float(lam)
        samples = np.atleast_2d(np.asarray(human_samples, dtype=float))
        mean = np.asarray(human_mean, dtype=float)
        rng = random.Random(cfg.seed)
        cache = TrajectoryCache(self.motion)
        d_init = np.asarray(self.motion.nominal_durations(problem), dtype=float)
        evaluated: dict[Schedule, Evaluation] = {}
        best: Evaluation | None = None
        best_time = 0.0
        improvements: list[tuple[float, float]] = []
        deadline = math.inf if cfg.time_limit_s is None else t0 + cfg.time_limit_s

        def late() -> bool:
            return time.perf_counter() > deadline

        searched: set[int] = set()  # allocations whose order has been searched, as bit masks

        def evaluate(schedules: Sequence[Schedule]) -> list[Evaluation]:
            """Evaluations of ``schedules`` and then, with ``order_search_nodes``, of the
            shortest order of each allocation among them not met before."""
            nonlocal best, best_time
            if cfg.order_search_nodes:
                schedules = [*schedules, *self._shortest_orders(schedules, searched, mean, d_init)]
            new = [s for s in dict.fromkeys(schedules) if s not in evaluated]
            full: dict[Schedule, Evaluation] = {}
            if new:
                fresh = evaluate_population(
                    problem, new, samples, mean, cache, d_init, gamma, lam, history,
                    cfg.max_overlap_iters,
                )
                for e in fresh:
                    full[e.schedule] = e
                    evaluated[e.schedule] = _slim(e)
                    if best is None or e.objective < best.objective:
                        best, best_time = e, time.perf_counter() - t0
                        improvements.append((best_time, e.objective))
            return [full[s] if s in full else evaluated[s] for s in schedules]

        def complete(evaluations: list[Evaluation]) -> list[Evaluation]:
            """``evaluations`` with their expected start times: cached slim ones are evaluated
            again (the same values; their motions are all in the memory M already)."""
            slim = [e.schedule for e in evaluations if e.feasible and not e.expected_start.size]
            if not slim:
                return evaluations
            again = {e.schedule: e for e in evaluate_population(
                problem, slim, samples, mean, cache, d_init, gamma, lam, history,
                cfg.max_overlap_iters)}
            return [again.get(e.schedule, e) for e in evaluations]

        search = _Search(evaluate, complete)

        seeds = self._seeds(initial, mean, d_init)
        population = self._initial_population(rng, mean, d_init, seeds)
        ranked = _rank(evaluate(population))
        assert best is not None
        history_best = [best.objective]
        if progress:
            progress(0, best.objective)
        n_elite = min(cfg.n_elite, len(ranked))
        stall = 0  # generations since the overall best improved (patience)
        local_stall = 0  # generations since this population's best improved (restart)
        polished: set[Schedule] = set()
        generations = 0
        timed_out = False
        for generation in range(1, cfg.generations + 1):
            if late():
                timed_out = True
                break
            generations = generation
            before, local_before = best.objective, ranked[0].objective
            elites = complete(_select_elites(ranked, n_elite, cfg.elites_per_allocation))
            children = self._children(
                elites, cfg.population - len(elites), rng, evaluated, mean, d_init
            )
            if not children:  # every mutant of the elite has been evaluated: nothing to gain
                history_best.append(best.objective)
                if progress:
                    progress(generation, best.objective)
                break
            ranked = _rank(evaluate(children) + elites)  # ties: newcomers first (plateau drift)
            local_stall = local_stall + 1 if ranked[0].objective >= local_before else 0
            if cfg.restart_after and local_stall >= cfg.restart_after:
                if cfg.polish and ranked[0].schedule not in polished:
                    polished.add(ranked[0].schedule)
                    polished.add(self._polish(ranked[0], search).schedule)
                ranked = _rank(evaluate(self._initial_population(rng, mean, d_init)))
                local_stall = 0
            stall = stall + 1 if best.objective >= before else 0
            history_best.append(best.objective)
            if progress:
                progress(generation, best.objective)
            if cfg.patience and stall >= cfg.patience:
                break
        if cfg.polish and best.schedule not in polished and not late():
            polished.add(self._polish(best, search, late).schedule)
        if cfg.polish and cfg.polish_allocations > 1 and not late():
            self._polish_runners_up(evaluated, search, polished, late)
        timed_out = timed_out or late()
        cache_stats = (cache.hits, cache.misses, len(cache))
        return PlanResult(
            best=best,
            best_by_generation=history_best,
            generations_run=generations,
            evaluations=len(evaluated),
            seconds=time.perf_counter() - t0,
            seconds_to_best=best_time,
            cache_hits=cache_stats[0],
            cache_misses=cache_stats[1],
            cache_size=cache_stats[2],
            improvements=improvements,
            timed_out=timed_out,
            seeds=seeds,
        )

    def _polish_runners_up(
        self,
        evaluated: dict[Schedule, Evaluation],
        search: _Search,
        polished: set[Schedule],
        late: Callable[[], bool],
    ) -> None:
        """The end of a solve: a polish of the best schedule of each of the
        ``polish_allocations`` best allocations, within ``polish_budget``. The trap it targets:
        the right allocation with an order no single move improves."""
        cfg = self.config
        limit = (1.0 + cfg.polish_budget) * len(evaluated)
        best_of: dict[frozenset[str], Evaluation] = {}
        for e in _rank(list(evaluated.values())):
            best_of.setdefault(_allocation(e.schedule), e)
        for e in list(best_of.values())[: cfg.polish_allocations]:
            if len(evaluated) > limit:
                return
            if e.schedule not in polished:
                polished.add(e.schedule)
                self._polish(e, search, lambda: len(evaluated) > limit or late())

    def _shortest_orders(self, schedules: Sequence[Schedule], searched: set[int],
                         mean: np.ndarray, d_init: np.ndarray) -> list[Schedule]:
        """The shortest order found by :meth:`AllocationOrders.search` for each allocation of
        ``schedules`` not in ``searched`` (then added to it). Without waits: they only delay,
        and the first schedule met with an allocation may carry any."""
        out = []
        for s in schedules:
            key = sum(1 << self._index[t] for t in s.tasks("human"))  # small, unlike a set
            if key not in searched:
                searched.add(key)
                bare = Schedule(s.tasks("human"), s.tasks("robot"))
                out += self._orders(bare, mean, d_init).search(self.config.order_search_nodes,
                                                               keep=1)[0]
        return out

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
        """The allocation of ``s`` on expected durations (human ``mean``, robot ``d_init``)."""
        index = self._index
        return AllocationOrders(
            s, self.problem,
            lambda t, a: mean[index[t]] if a == "human" else d_init[index[t]],
        )

    def mutate(
        self,
        parent: Schedule,
        rng: random.Random,
        weights: list[float] | None = None,
        start: np.ndarray | None = None,
    ) -> Schedule | None:
        """One repaired mutant that differs from ``parent``; None if no operator applies.
        ``start``: the parent's (n,) expected start times, where known (used by "move")."""
        weights = list(weights or self.config.weights())
        while sum(weights) > 0:
            k = rng.choices(range(len(MUTATIONS)), weights)[0]
            child = self._ops[MUTATIONS[k]](parent, rng, start)
            if child is not None:
                child = repair(child)
                if child != parent:
                    return child
            weights[k] = 0.0  # operator does not apply here; try the others
        return None

    def _polish(
        self,
        start: Evaluation,
        search: _Search,
        stop: Callable[[], bool] | None = None,
    ) -> Evaluation:
        """Best-improvement local search over :meth:`neighbours`, one batch per pass; ``stop``
        is asked before every pass."""
        current = start
        for _ in range(self.config.polish_passes):
            if stop is not None and stop():
                break
            current = search.complete([current])[0]  # the window needs its start times
            candidates = self.neighbours(current.schedule, current.expected_start,
                                         self.config.polish_window)
            if not candidates:
                break
            best = min(search.evaluate(candidates), key=lambda e: e.objective)
            if not best.objective < current.objective - 1e-12 * max(1.0, abs(current.objective)):
                break
            current = best
        return current

    # ------------------------------------------------------------------------- population

    def _seeds(self, initial: Sequence[Schedule], mean: np.ndarray, d_init: np.ndarray
               ) -> list[Schedule]:
        """The caller's ``initial`` schedules (validated, repaired, distinct) and, with
        ``exact_seed_work``, fixed robot durations and a job of ``exact_seed_min_tasks`` to
        ``exact_seed_tasks`` tasks, CP-SAT's schedule on the expected durations; at most a
        population's worth."""
        out: dict[Schedule, None] = {}
        for s in initial:
            validate(self.problem, s)
            out[repair(s)] = None
        cfg = self.config
        if (cfg.exact_seed_work > 0
                and cfg.exact_seed_min_tasks <= len(self.problem.tasks) <= cfg.exact_seed_tasks
                and isinstance(self.motion, FixedDurationMotion)):
            from rapidds.scheduler.exact import solve_exact  # OR-Tools: 0.5 s to import

            human = np.where([t.can("human") for t in self.problem.tasks], mean, np.nan)
            try:  # a deterministic budget, so the seed does not depend on the machine's load;
                # the wall-time limit only guards against a stalled solver
                exact = solve_exact(self.problem, time_limit_s=60.0 + 20 * cfg.exact_seed_work,
                                    human_mean=human, robot_durations=d_init, load_bound=True,
                                    deterministic_time=cfg.exact_seed_work)
            except (RapiddsError, ValueError):  # nothing found in time, or unusable durations
                pass
            else:
                out[exact.schedule] = None
        return list(out)[: cfg.population]

    def _initial_population(
        self, rng: random.Random, mean: np.ndarray, d_init: np.ndarray,
        seeds: Sequence[Schedule] = (),
    ) -> list[Schedule]:
        """``seeds`` and then distinct list schedules, C in all (fewer only if the problem
        has fewer distinct ones)."""
        size = self.config.population
        out: dict[Schedule, None] = dict.fromkeys(seeds)
        misses = 0
        while len(out) < size and misses < size:
            schedule = self.list_schedule(rng, mean, d_init)
            misses = misses + 1 if schedule in out else 0
            out[schedule] = None
        pool = list(out)
        misses = 0
        while len(out) < size and misses < size:  # tiny problems: top up with mutants
            child = self.mutate(rng.choice(pool), rng)
            misses = misses + 1 if child is None or child in out else 0
            if child is not None:
                out[child] = None
        return list(out)

    def list_schedule(self, rng: random.Random, mean: np.ndarray, d_init: np.ndarray) -> Schedule:
        """Randomised earliest-deadline-first list scheduling: always feasible.

        Repeatedly takes a ready task (all predecessors placed) and appends it to an agent. The
        task is the one with the earliest deadline, i.e. the longest remaining critical path
        (shortest-agent expected durations), after perturbing each key by uniform noise; the
        agent is the one that would finish the task first, or with some probability a random
        allowed one. The noise level and the greediness are drawn per schedule, so a population
        spans pure EDF/earliest-finish schedules and nearly random ones.
        """
        index = self._index
        durations = {
            t: {
                "human": float(mean[index[t]]) if "human" in self._allowed[t] else math.inf,
                "robot": float(d_init[index[t]]) if "robot" in self._allowed[t] else math.inf,
            }
            for t in self.problem.ids
        }
        tail = self._tails(durations)
        spread = max(tail.values())
        noise = rng.random() * spread
        greedy = rng.random()
        pending = {t: len(self._preds[t]) for t in self.problem.ids}
        ready = [t for t in self.problem.ids if pending[t] == 0]
        free = {"human": 0.0, "robot": 0.0}
        finish: dict[str, float] = {}
        seqs: dict[Agent, list[Item]] = {"human": [], "robot": []}
        while ready:
            keys = [tail[t] + noise * rng.random() for t in ready]
            task = ready.pop(keys.index(max(keys)))
            agents = [a for a in AGENTS if a in self._allowed[task]]
            gate = max((finish[p] for p in self._preds[task]), default=0.0)
            ends = {a: max(free[a], gate) + durations[task][a] for a in agents}
            if len(agents) == 2 and rng.random() < greedy:
                low = min(ends.values())
                agent = rng.choice([a for a in agents if ends[a] == low])
            else:
                agent = rng.choice(agents)
            finish[task] = free[agent] = ends[agent]
            seqs[agent].append(task)
            for nxt in self._succ[task]:
                pending[nxt] -= 1
                if pending[nxt] == 0:
                    ready.append(nxt)
        return Schedule(tuple(seqs["human"]), tuple(seqs["robot"]))

    def _tails(self, durations: dict[str, dict[str, float]]) -> dict[str, float]:
        """Longest path from the start of each task to the end of the job (its deadline slack
        counted backwards), with each task at its faster agent's duration."""
        return longest_tails(self.problem.ids, self._succ,
                             {t: min(d.values()) for t, d in durations.items()})

    # -------------------------------------------------------------------------- operators

    def _window(self, seq: Sequence[Item], task: str) -> tuple[int, int]:
        """Insertion positions [lo, hi] of ``task`` in ``seq`` that keep precedence: after its
        ancestors, before its descendants and before waits on them."""
        anc, desc = self._anc[task], self._desc[task]
        lo, hi = 0, len(seq)
        for k, x in enumerate(seq):
            if isinstance(x, Wait):
                if x.task in desc and k < hi:
                    hi = k
            elif x in anc:
                lo = k + 1
            elif x in desc and k < hi:
                hi = k
        return (lo, hi) if lo <= hi else (0, len(seq))

    def _move(self, s: Schedule, rng: random.Random, start: np.ndarray | None) -> Schedule | None:
        """A random shared task to the other agent. With the parent's expected start times it
        goes where its start falls in the other sequence (ahead of any waits there), so the new
        allocation is judged with a sensible order; otherwise to a random position. Either way
        within the precedence window. (Measured: fewer runs stuck above the optimum than with
        random positions only; "reorder" and activation still try the other positions.)"""
        if not self._shared:
            return None
        task = rng.choice(self._shared)
        src = s.agent_of(task)
        dst = _other(src)
        seq = list(s.sequence(dst))
        lo, hi = self._window(seq, task)
        if start is not None and start.size:
            at = start[self._index[task]]
            pos = next((k for k, x in enumerate(seq)
                        if isinstance(x, str) and start[self._index[x]] >= at), len(seq))
            while pos > 0 and isinstance(seq[pos - 1], Wait):
                pos -= 1
            seq.insert(min(max(pos, lo), hi), task)
        else:
            seq.insert(rng.randint(lo, hi), task)
        return s.replace(src, (x for x in s.sequence(src) if x != task)).replace(dst, seq)

    def _reorder(self, s: Schedule, rng: random.Random, _: np.ndarray | None) -> Schedule | None:
        slots = [(a, k) for a in AGENTS if len(s.sequence(a)) >= 2
                 for k in range(len(s.sequence(a)))]
        if not slots:
            return None
        agent, k = rng.choice(slots)
        seq = list(s.sequence(agent))
        if rng.random() < 0.5:  # swap with another item of the same sequence
            other = rng.choice([p for p in range(len(seq)) if p != k])
            seq[k], seq[other] = seq[other], seq[k]
            return s.replace(agent, seq)
        item = seq.pop(k)
        lo, hi = (0, len(seq)) if isinstance(item, Wait) else self._window(seq, item)
        choices = [p for p in range(lo, hi + 1) if p != k]
        if not choices:
            return None
        seq.insert(rng.choice(choices), item)
        return s.replace(agent, seq)

    def _crossover(self, s: Schedule, rng: random.Random, _: np.ndarray | None
                   ) -> Schedule | None:
        """Swap the tails after a cut point in each sequence. A task in a tail that the other
        agent may not do stays with its agent, after the incoming tail."""
        h, r = s.human, s.robot
        ch, cr = rng.randint(0, len(h)), rng.randint(0, len(r))
        if ch == len(h) and cr == len(r):
            return None
        tail_h, tail_r = h[ch:], r[cr:]

        def fits(x: Item, agent: Agent) -> bool:
            return isinstance(x, Wait) or agent in self._allowed[x]

        human = (*h[:ch], *(x for x in tail_r if fits(x, "human")),
                 *(x for x in tail_h if not fits(x, "robot")))
        robot = (*r[:cr], *(x for x in tail_h if fits(x, "robot")),
                 *(x for x in tail_r if not fits(x, "human")))
        return Schedule(human, robot)

    def _add_wait(self, s: Schedule, rng: random.Random, _: np.ndarray | None) -> Schedule | None:
        agents = [a for a in AGENTS if s.sequence(a) and s.tasks(_other(a))]
        if not agents:
            return None
        agent = rng.choice(agents)
        seq = list(s.sequence(agent))
        seq.insert(rng.randrange(len(seq)), Wait(rng.choice(s.tasks(_other(agent)))))
        return s.replace(agent, seq)

    def _remove_wait(self, s: Schedule, rng: random.Random, _: np.ndarray | None
                     ) -> Schedule | None:
        slots = [(a, k) for a in AGENTS for k, x in enumerate(s.sequence(a))
                 if isinstance(x, Wait)]
        if not slots:
            return None
        agent, k = rng.choice(slots)
        seq = s.sequence(agent)
        return s.replace(agent, seq[:k] + seq[k + 1 :])

    def neighbours(self, s: Schedule, start: np.ndarray | None = None,
                   window: int = 0) -> list[Schedule]:
        """Every single move, reorder, swap within an agent, pair of adjacent swaps (one in each
        agent), exchange of two tasks between agents, and wait removal of ``s`` (repaired,
        distinct, without ``s``): the polish neighbourhood, O(n^2) schedules.

        With ``window`` and the expected start times ``start`` (n,), only changes within
        ``window`` positions: an item moves at most that far in its sequence, a task goes to
        the other agent at most that far from where its start falls there, and the adjacent
        swaps and exchanges pair items at most that far apart in time order. O(n window)
        schedules; on sequences of at most ``window`` items, the whole neighbourhood.
        """
        near = window > 0 and start is not None and start.size > 0
        reach = window if near else 1 << 30
        at: dict[Item, dict[Agent, int]] = {}  # item -> where its start falls in each sequence
        if near:
            assert start is not None
            index = self._index
            for agent in AGENTS:
                seq = s.sequence(agent)
                slots = [k for k, x in enumerate(seq) if isinstance(x, str)]
                starts = [start[index[seq[k]]] for k in slots]  # nondecreasing along seq
                slots.append(len(seq))
                for item in self.problem.ids:
                    at.setdefault(item, {})[agent] = slots[bisect_left(starts,
                                                                       start[index[item]])]

        def anchor(item: Item, agent: Agent, k: int) -> int:
            """Where ``item`` (at ``k`` in the other sequence) falls in ``agent``'s."""
            seq = s.sequence(_other(agent))
            task = next((x for x in seq[k:] if isinstance(x, str)), None)
            return at[task][agent] if near and task is not None else len(s.sequence(agent))

        out: dict[Schedule, None] = {}
        for task in self._shared:
            src = s.agent_of(task)
            dst = _other(src)
            rest = tuple(x for x in s.sequence(src) if x != task)
            seq = s.sequence(dst)
            lo, hi = self._window(seq, task)
            if near:
                mid = at[task][dst]
                lo, hi = max(lo, mid - reach), min(hi, mid + reach)
            for p in range(lo, hi + 1):
                out[repair(s.replace(src, rest).replace(dst, (*seq[:p], task, *seq[p:])))] = None
        for agent in AGENTS:
            seq = s.sequence(agent)
            for k, item in enumerate(seq):
                rest = seq[:k] + seq[k + 1 :]
                if isinstance(item, Wait):
                    out[repair(s.replace(agent, rest))] = None
                lo, hi = (0, len(rest)) if isinstance(item, Wait) else self._window(rest, item)
                for p in range(max(lo, k - reach), min(hi, k + reach) + 1):
                    if p != k:
                        out[repair(s.replace(agent, (*rest[:p], item, *rest[p:])))] = None
                for j in range(k + 1, min(len(seq), k + reach + 1)):
                    swapped = (*seq[:k], seq[j], *seq[k + 1 : j], item, *seq[j + 1 :])
                    out[repair(s.replace(agent, swapped))] = None
        h, r = s.human, s.robot
        for i in range(len(h) - 1):  # adjacent swaps in both sequences at once: one agent's
            mid = anchor(h[i], "robot", i)  # new order often pays only with the other's
            for j in range(len(r) - 1):
                if abs(j - mid) <= reach:
                    out[repair(Schedule((*h[:i], h[i + 1], h[i], *h[i + 2 :]),
                                        (*r[:j], r[j + 1], r[j], *r[j + 2 :])))] = None
        for i, a in enumerate(h):
            if isinstance(a, Wait) or "robot" not in self._allowed[a]:
                continue
            mid = anchor(a, "robot", i)
            for j, b in enumerate(r):
                if isinstance(b, Wait) or "human" not in self._allowed[b] or abs(j - mid) > reach:
                    continue
                out[repair(Schedule((*h[:i], b, *h[i + 1 :]), (*r[:j], a, *r[j + 1 :])))] = None
        out.pop(s, None)
        return list(out)


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


@dataclass(frozen=True)
class _Search:
    """What a polish asks of the running search: ``evaluate`` schedules (cached ones come back
    slim) and ``complete`` slim evaluations with their expected start times."""

    evaluate: Callable[[Sequence[Schedule]], list[Evaluation]]
    complete: Callable[[list[Evaluation]], list[Evaluation]]


_NONE = np.empty(0)


def _slim(e: Evaluation) -> Evaluation:
    """What the search keeps of an evaluation it may meet again: the schedule and the
    objective. The samples' makespans, the motions, the overlaps and the timeline of every
    schedule evaluated would fill gigabytes on 64-128 tasks; the few cached schedules that
    become parents or polish starts are evaluated again for their start times."""
    return dataclasses.replace(e, makespan=_NONE, motions={}, overlaps={},
                               expected_start=_NONE, expected_finish=_NONE)


def _allocation(s: Schedule) -> frozenset[str]:
    """Who does which task, as the set of the human's tasks."""
    return frozenset(s.tasks("human"))


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
        key = _allocation(e.schedule)
        if taken.get(key, 0) < per_allocation:
            taken[key] = taken.get(key, 0) + 1
            chosen.append(e)
        else:
            skipped.append(e)
    return _rank(chosen + skipped[: count - len(chosen)])


def _rank(evaluations: list[Evaluation]) -> list[Evaluation]:
    """Best first; ties keep their order (deterministic). nan (never produced) sorts last."""
    return sorted(evaluations, key=lambda e: math.inf if math.isnan(e.objective) else e.objective)
