"""Settings of the genetic scheduler (paper Algorithm 1: C, G, K and the evolution step)."""

from __future__ import annotations

from typing import Annotated, ClassVar

from pydantic import Field, field_validator

from rapidds.settings import Flag, Int, Real, Settings

MUTATIONS: tuple[str, ...] = ("move", "reorder", "crossover", "add_wait", "remove_wait")


def _default_weights() -> dict[str, float]:
    return {"move": 0.35, "reorder": 0.3, "crossover": 0.15, "add_wait": 0.1, "remove_wait": 0.1}


class GAConfig(Settings):
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
            :meth:`~rapidds.scheduler.ga.GeneticScheduler.neighbours`), one batch per pass
            (screened on big jobs, see ``polish_screen_chunk``), applied to the best of each
            stalled population and to the final best. It costs
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
        polish_screen_chunk: on big jobs with fixed robot durations, a polish pass ranks the
            neighbours by a lower bound of their objective (the makespan on the samples' mean
            durations), drops those that cannot improve, evaluates the rest this many at a
            time, best bound first, and moves to the best of the first chunk that improves
            (:func:`~rapidds.scheduler.polish.screened`); 0 = evaluate every neighbour and
            take the best. A polish still ends only where no neighbour improves.
        polish_screen_orders: with the screen, still search the shortest order of every
            allocation the neighbours reach (the screened-out ones too) and evaluate those
            first, as evaluating every neighbour would. Without it the screen was about twice
            as fast on 64 tasks but ended 0.3-1.4 % worse on 2 of 4 instances over 3 seeds.
        polish_screen_min_tasks: the screen only on jobs of at least this many tasks, so the
            jobs of up to 11 tasks where the search was tuned (and the paper's) polish as
            before, bit for bit.
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

    label: ClassVar[str] = "GAConfig"

    population: Annotated[Int, Field(ge=2)] = 48
    generations: Annotated[Int, Field(ge=1)] = 150
    samples: Annotated[Int, Field(ge=1)] = 64
    elite_fraction: Annotated[Real, Field(gt=0, lt=1)] = 0.25
    mutation_weights: dict[str, Annotated[Real, Field(ge=0)]] = Field(
        default_factory=_default_weights)
    max_overlap_iters: Annotated[Int, Field(ge=1)] = 8
    patience: Annotated[Int, Field(ge=0)] = 15
    restart_after: Annotated[Int, Field(ge=0)] = 10
    elites_per_allocation: Annotated[Int, Field(ge=0)] = 1
    activate_children: Flag = True
    polish: Flag = True
    polish_passes: Annotated[Int, Field(ge=0)] = 20
    polish_window: Annotated[Int, Field(ge=0)] = 10
    polish_allocations: Annotated[Int, Field(ge=0)] = 16
    polish_budget: Annotated[Real, Field(ge=0)] = 0.5
    polish_screen_chunk: Annotated[Int, Field(ge=0)] = 64
    polish_screen_orders: Flag = True
    polish_screen_min_tasks: Annotated[Int, Field(ge=0)] = 12
    order_search_nodes: Annotated[Int, Field(ge=0)] = 300
    exact_seed_work: Annotated[Real, Field(ge=0)] = 1.0
    exact_seed_tasks: Annotated[Int, Field(ge=0)] = 40
    exact_seed_min_tasks: Annotated[Int, Field(ge=0)] = 11
    time_limit_s: Annotated[Real, Field(gt=0)] | None = None
    seed: Annotated[Int, Field(ge=0)] = 0

    @field_validator("mutation_weights")
    @classmethod
    def _known_operators(cls, weights: dict[str, float]) -> dict[str, float]:
        unknown = set(weights) - set(MUTATIONS)
        if unknown:
            raise ValueError(f"unknown operators {sorted(unknown)}; known: {list(MUTATIONS)}")
        if sum(weights.values()) <= 0:
            raise ValueError("at least one weight must be > 0")
        return weights

    @property
    def n_elite(self) -> int:
        """Number of elite candidates kept per generation (at least 1)."""
        return max(1, round(self.elite_fraction * self.population))

    def weights(self) -> list[float]:
        """Operator weights in ``MUTATIONS`` order."""
        return [float(self.mutation_weights.get(m, 0.0)) for m in MUTATIONS]
