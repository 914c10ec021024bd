"""Settings of the genetic scheduler (paper Algorithm 1: C, G, K and the evolution step)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

MUTATIONS: tuple[str, ...] = ("move", "reorder", "crossover", "add_wait", "remove_wait")


def _number(value: object) -> bool:
    """A finite int or float, not a bool."""
    return (isinstance(value, int | float) and not isinstance(value, bool)
            and math.isfinite(value))


def _default_weights() -> dict[str, float]:
    return {"move": 0.35, "reorder": 0.3, "crossover": 0.15, "add_wait": 0.1, "remove_wait": 0.1}


@dataclass
class GAConfig:
    """Configuration of :class:`~rapidds.scheduler.ga.GeneticScheduler`.

    The defaults were tuned with ``benchmarks/bench_scheduler.py`` on random deterministic
    instances of 4-10 tasks against the CP-SAT optimum (see docs/benchmarks.md, "Scheduler").

    Attributes:
        population: C, candidate schedules per generation.
        generations: G, maximum number of generations (evolution steps).
        samples: K, Monte-Carlo samples of the human durations the caller should draw for one
            solve. The scheduler evaluates every candidate on the same K samples (common random
            numbers), so differences between candidates are not sampling noise.
        elite_fraction: share of the population carried unchanged into the next generation
            (elitist selection); the parents of the children are drawn from this elite.
        mutation_weights: relative probability of each mutation operator, keys from
            ``MUTATIONS``: "move" (a task to the other agent, where its expected start time
            falls in that agent's sequence), "reorder" (a task to another position of its
            agent's sequence, or a swap of two items there), "crossover" (swap the tails of the
            human and robot sequences after a cut point), "add_wait", "remove_wait". Missing
            keys weigh 0. Shifting weight between the operators by +-0.1 made no measurable
            difference on the tuning instances.
        max_overlap_iters: cap on the rounds of Algorithm 2's overlap loop ("while some C_j
            changed") per candidate; the loop can oscillate between overlap sets
            (docs/design-notes.md item 2).
        patience: stop when the best objective has not improved for this many generations;
            0 = always run all ``generations``.
        restart_after: when the current population's best has not improved for this many
            generations, polish it and replace the population with fresh list schedules (the
            overall best is kept aside); 0 = never restart. Independent restarts escape the
            allocation local optima that a converged population cannot leave.
        elites_per_allocation: at most this many elite schedules may share one allocation (the
            set of tasks the human does); the freed elite slots go to the next-best other
            allocations. 0 = no limit. Without it the elite collapses onto one allocation within
            a few generations, and single moves rarely cross to a better one.
        activate_children: also evaluate two active (left-justified) versions of every mutant,
            see :meth:`~rapidds.scheduler.ga.GeneticScheduler.activate`: one keeping the
            mutant's order where tasks compete, one giving the longest remaining path priority.
            A reorder of one agent often helps only together with a matching reorder of the
            other, and a moved task needs an order that suits its new allocation.
        polish: best-improvement local search over the whole single-step neighbourhood (see
            :meth:`~rapidds.scheduler.ga.GeneticScheduler.neighbours`), one batch per pass,
            applied to the best of each stalled population and to the final best. It costs
            O(n^2) evaluations per pass, and with a diffusion motion model as many new motion
            requests at most; turn it off where those are expensive.
        polish_passes: cap on the local-search passes of one polish.
        polish_window: the polish changes an item's position by at most this many places
            (see :meth:`~rapidds.scheduler.ga.GeneticScheduler.neighbours`); 0 = no limit.
            The whole neighbourhood has O(n^2) schedules: about 6,500 per pass on 64 tasks
            and 26,000 on 128. Sequences of at most this many items keep all of it, so jobs
            of up to 10 tasks (where the search was tuned) polish as before.
        polish_allocations: at the end, also polish the best schedule found for each of this
            many best allocations (who does which task), not only the overall best; 0 or 1 =
            the overall best only. Descents from runner-up allocations reach optima that the
            best one's single-step neighbourhood cannot (measured: the runs more than 2 %
            above the CP-SAT optimum on 8-10 tasks fell from about 1 in 170 to none in 600,
            with critical-path children; docs/design-notes.md, item 8).
        order_search_nodes: for every allocation (who does which task) the search meets
            for the first time, also evaluate the shortest order of that allocation on
            expected durations, found by branch and bound over its active schedules
            (:mod:`rapidds.scheduler.active`) within this many placements; 0 = off.
            Otherwise an allocation is judged by whatever order the mutations gave it, and the
            right allocation in a poor order loses to a worse allocation in a good one.
        polish_budget: the runner-up polishes stop (between passes) once they have evaluated
            this many times the schedules the search evaluated before them. With the order
            search, 0.5 and 1.0 both ended at the optimum in 1,500 of 1,500 runs on 8-10 tasks,
            0.5 in about 10 % less time.
        exact_seed_work: CP-SAT's budget, in its deterministic time units, for a seed of the
            initial population: when the motion model is a
            :class:`~rapidds.motion.interface.FixedDurationMotion` (fixed robot durations, no
            proximity term) and the job has at most ``exact_seed_tasks`` tasks, the
            minimum-makespan schedule on the expected durations that
            :func:`~rapidds.scheduler.exact.solve_exact` finds in that budget joins the first
            population; 0 = off. A deterministic budget keeps the seed, and so the result,
            independent of the machine's load (a unit took 0.4-2.4 s of wall time on 16-32
            tasks here). Other motion models (the loop's diffusion policy) are never seeded:
            their durations and costs depend on the overlaps that CP-SAT does not see.
        exact_seed_tasks: the CP-SAT seed only for jobs of at most this many tasks. Measured:
            1 unit proves the optimum of random 32-task jobs, but on 64 tasks it takes 8 s and
            ends about 19 % above the GA's schedule, on 128 tasks 17 s and 170 % above.
        exact_seed_min_tasks: and only for jobs of at least this many: on 4-10 tasks the search
            alone found CP-SAT's optimum in 210 of 210 runs (docs/benchmarks.md), so a seed
            there only costs importing OR-Tools (0.5 s of a 1 s ``rapidds plan``).
        time_limit_s: stop the search cleanly once this much wall time has passed (checked
            between generations and between polish passes) and return the best so far;
            None = no limit. A safety net for callers with a deadline, not a tuning knob.
        seed: seed of the random generator; the same seed and inputs give the same result
            (with ``time_limit_s``, only if the limit is not reached).
    """

    population: int = 48
    generations: int = 150
    samples: int = 64
    elite_fraction: float = 0.25
    mutation_weights: dict[str, float] = field(default_factory=_default_weights)
    max_overlap_iters: int = 8
    patience: int = 15
    restart_after: int = 10
    elites_per_allocation: int = 1
    activate_children: bool = True
    polish: bool = True
    polish_passes: int = 20
    polish_window: int = 10
    polish_allocations: int = 16
    polish_budget: float = 0.5
    order_search_nodes: int = 300
    exact_seed_work: float = 1.0
    exact_seed_tasks: int = 40
    exact_seed_min_tasks: int = 11
    time_limit_s: float | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("population", "generations", "samples", "max_overlap_iters"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"GAConfig.{name} must be an integer >= 1, got {value!r}")
        for name in ("patience", "restart_after", "elites_per_allocation", "polish_passes",
                     "polish_allocations", "order_search_nodes", "polish_window",
                     "exact_seed_tasks", "exact_seed_min_tasks", "seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"GAConfig.{name} must be an integer >= 0, got {value!r}")
        if self.population < 2:
            raise ValueError(f"GAConfig.population must be >= 2, got {self.population}")
        if not (isinstance(self.polish_budget, int | float) and math.isfinite(self.polish_budget)
                and self.polish_budget >= 0):
            raise ValueError(
                f"GAConfig.polish_budget must be a finite number >= 0, got {self.polish_budget!r}"
            )
        if not (_number(self.exact_seed_work) and self.exact_seed_work >= 0):
            raise ValueError(f"GAConfig.exact_seed_work must be a finite number >= 0, "
                             f"got {self.exact_seed_work!r}")
        if self.time_limit_s is not None and not (
                _number(self.time_limit_s) and self.time_limit_s > 0):
            raise ValueError(f"GAConfig.time_limit_s must be None or a finite number > 0, "
                             f"got {self.time_limit_s!r}")
        if not (0.0 < self.elite_fraction < 1.0):
            raise ValueError(
                f"GAConfig.elite_fraction must be in (0, 1), got {self.elite_fraction!r}"
            )
        unknown = set(self.mutation_weights) - set(MUTATIONS)
        if unknown:
            raise ValueError(
                f"GAConfig.mutation_weights: unknown operators {sorted(unknown)}; "
                f"known: {list(MUTATIONS)}"
            )
        for key, w in self.mutation_weights.items():
            if not isinstance(w, int | float) or not math.isfinite(w) or w < 0:
                raise ValueError(
                    f"GAConfig.mutation_weights['{key}'] must be a finite number >= 0, got {w!r}"
                )
        if sum(self.mutation_weights.values()) <= 0:
            raise ValueError("GAConfig.mutation_weights: at least one weight must be > 0")
        for name in ("polish", "activate_children"):
            value = getattr(self, name)
            if not isinstance(value, bool):
                raise ValueError(f"GAConfig.{name} must be True or False, got {value!r}")

    @property
    def n_elite(self) -> int:
        """Number of elite candidates kept per generation (at least 1)."""
        return max(1, round(self.elite_fraction * self.population))

    def weights(self) -> list[float]:
        """Operator weights in ``MUTATIONS`` order."""
        return [float(self.mutation_weights.get(m, 0.0)) for m in MUTATIONS]
