"""Genetic scheduler, Algorithm 2 evaluation and the diversity term."""

from __future__ import annotations

import itertools
import math
import random
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pytest
from reference import brute_force, sequence_makespan

from rapidds.errors import StateError
from rapidds.motion.interface import (
    FixedDurationMotion,
    MotionKey,
    MotionPlan,
    TrajectoryCache,
)
from rapidds.problem import Problem, Task
from rapidds.schedule import CompiledSchedule, Schedule, Wait, repair, validate
from rapidds.scheduler import (
    AllocationHistory,
    EvaluationContext,
    GAConfig,
    GeneticScheduler,
    diversity,
    evaluate_population,
    solve_exact,
)

BOTH = frozenset({"human", "robot"})
HUMAN = frozenset({"human"})
ROBOT = frozenset({"robot"})


# ----------------------------------------------------------------------------- helpers


def random_problem(rng: np.random.Generator, n: int, restrict: float = 0.2) -> Problem:
    """Durations in 0.01 s steps, about two precedence edges per task pair in n."""
    tasks = []
    for i in range(n):
        u = rng.random()
        allowed = BOTH if u >= restrict else (HUMAN if u < restrict / 2 else ROBOT)
        tasks.append(Task(f"t{i}", allowed, round(float(rng.uniform(1, 10)), 2), 0.0,
                          round(float(rng.uniform(1, 10)), 2)))
    p_edge = min(0.3, 2.0 / n)
    edges = tuple((f"t{i}", f"t{j}") for i in range(n) for j in range(i + 1, n)
                  if rng.random() < p_edge)
    return Problem(f"random{n}", tuple(tasks), edges)


def means(problem: Problem) -> np.ndarray:
    return np.array([np.nan if t.human_mean is None else t.human_mean for t in problem.tasks])


class ConcurrencyMotion:
    """A motion model whose robot duration and spatial cost are a function of C_j; it records
    every batch it is asked for."""

    def __init__(self, cost: Callable[[frozenset[str]], tuple[float, float]], nominal: float):
        self.cost = cost
        self.nominal = nominal
        self.batches: list[list[MotionKey]] = []

    def nominal_durations(self, problem: Problem) -> np.ndarray:
        return np.array([self.nominal if t.can("robot") else np.nan for t in problem.tasks])

    def plan(self, requests: Sequence[MotionKey]) -> list[MotionPlan]:
        self.batches.append(list(requests))
        return [MotionPlan(j, c, *self.cost(c)) for j, c in requests]


def _chain_problem(n_human: int) -> Problem:
    """Human-only tasks h1..hN of 1 s in a chain, one robot-only task r."""
    tasks = [Task(f"h{i}", HUMAN, 1.0, 0.0) for i in range(1, n_human + 1)]
    tasks.append(Task("r", ROBOT, robot_duration=1.0))
    return Problem("chain", tuple(tasks))


def _evaluate(problem: Problem, schedules: list[Schedule], motion, *, gamma: float = 1.0,
              lam: float = 0.0, history: AllocationHistory | None = None,
              max_overlap_iters: int = 8, samples: np.ndarray | None = None):
    mean = means(problem)
    samples = np.nan_to_num(mean)[None] if samples is None else samples
    return evaluate_population(EvaluationContext(
        problem, samples, np.nan_to_num(mean), TrajectoryCache(motion),
        motion.nominal_durations(problem), gamma, lam, history, max_overlap_iters,
    ), schedules)


# ---------------------------------------------------------------------------- diversity


def _three_tasks() -> Problem:
    return Problem(
        "div",
        (Task("t0", BOTH, 1.0, 0.0, 1.0), Task("t1", BOTH, 1.0, 0.0, 1.0),
         Task("t2", HUMAN, 1.0, 0.0)),
    )


def test_diversity_closed_form_with_history() -> None:
    p = _three_tasks()
    hist = AllocationHistory({"t0": {"human": 2, "robot": 0}, "t1": {"human": 1, "robot": 1}})
    # t0 by human: r = (3, 0) -> |1.5-3| + |1.5-0| = 3; t1 by robot: r = (1, 2) -> 1; /(2*3)
    assert diversity(p, Schedule(("t0", "t2"), ("t1",)), hist) == pytest.approx(4 / 6)
    # t0 to the robot, which has done it less: r = (2, 1) -> 1; t1 stays 1
    assert diversity(p, Schedule(("t2",), ("t0", "t1")), hist) == pytest.approx(2 / 6)
    # t1 to the human: r = (2, 1) -> 1; t0 to the robot -> 1
    assert diversity(p, Schedule(("t1", "t2"), ("t0",)), hist) == pytest.approx(2 / 6)


def test_diversity_without_history_is_the_same_for_every_allocation() -> None:
    p = _three_tasks()
    for s in (Schedule(("t0", "t1", "t2"), ()), Schedule(("t2",), ("t0", "t1"))):
        assert diversity(p, s, None) == pytest.approx(2 / 6)
        assert diversity(p, s, AllocationHistory()) == pytest.approx(2 / 6)


def test_allocation_history_records_and_round_trips() -> None:
    hist = AllocationHistory()
    hist.record(Schedule(("t0", "t2"), ("t1",)))
    hist.record(Schedule(("t2",), ("t0", "t1")))
    assert hist.count("t0", "human") == 1 and hist.count("t0", "robot") == 1
    assert hist.count("t1", "robot") == 2 and hist.count("t1", "human") == 0
    assert AllocationHistory.from_dict(hist.to_dict()) == hist
    p = _three_tasks()
    # after these two cycles t1 was always the robot's: giving it to the human scores lower
    assert diversity(p, Schedule(("t1", "t2"), ("t0",)), hist) < diversity(
        p, Schedule(("t2",), ("t0", "t1")), hist
    )


@pytest.mark.parametrize(
    "data",
    [{"t0": {"human": -1}}, {"t0": {"alien": 1}}, {"t0": {"human": 1.5}}, {"t0": 3}, [1]],
)
def test_allocation_history_rejects_bad_data(data: object) -> None:
    with pytest.raises(StateError):
        AllocationHistory.from_dict(data)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- evaluation


def test_evaluation_matches_the_timeline_and_uses_common_samples() -> None:
    rng = np.random.default_rng(3)
    p = random_problem(rng, 7)
    mean = np.nan_to_num(means(p))
    samples = mean * rng.uniform(0.5, 1.5, size=(32, len(p.tasks)))
    scheduler = GeneticScheduler(p, FixedDurationMotion(p))
    py = random.Random(0)
    schedules = list(dict.fromkeys(scheduler.list_schedule(py, mean, scheduler.motion
                                                           .nominal_durations(p))
                                   for _ in range(10)))
    evals = _evaluate(p, schedules, FixedDurationMotion(p), samples=samples)
    robot = FixedDurationMotion(p).nominal_durations(p)
    for s, e in zip(schedules, evals, strict=True):
        c = CompiledSchedule.build(p, s)
        assert c is not None and e.feasible and e.converged
        makespan = c.simulate(c.durations(samples, robot)).makespan
        np.testing.assert_allclose(e.makespan, makespan)
        assert e.makespan_mean == pytest.approx(makespan.mean())
        assert e.makespan_std == pytest.approx(makespan.std())
        assert e.objective == pytest.approx(makespan.mean() + 1.0 * e.spatial)
        expected = c.simulate(c.durations(mean[None], robot))
        assert e.overlaps == expected.overlaps(0)  # vectorised C_j == Timeline.overlaps
        np.testing.assert_allclose(e.expected_finish, expected.finish[0])


def test_objective_adds_weighted_diversity() -> None:
    p = _three_tasks()
    hist = AllocationHistory({"t0": {"human": 2, "robot": 0}})
    s = Schedule(("t0", "t2"), ("t1",))
    (e,) = _evaluate(p, [s], FixedDurationMotion(p), gamma=2.0, lam=3.0, history=hist)
    assert e.diversity == pytest.approx(diversity(p, s, hist))
    assert e.objective == pytest.approx(e.makespan_mean + 3.0 * e.diversity)


def test_infeasible_schedules_get_inf_and_feasible_ones_do_not() -> None:
    p = Problem("pair", (Task("a", BOTH, 1.0, 0.0, 1.0), Task("b", BOTH, 1.0, 0.0, 1.0)),
                (("a", "b"),))
    dead = Schedule(("b", "a"), ())
    cycle = Schedule((Wait("b"), "a"), (Wait("a"), "b"))
    fine = Schedule(("a",), ("b",))
    evals = _evaluate(p, [dead, cycle, fine], FixedDurationMotion(p))
    assert [e.feasible for e in evals] == [False, False, True]
    assert math.isinf(evals[0].objective) and math.isinf(evals[1].objective)
    assert evals[2].objective == pytest.approx(2.0)


def test_invalid_schedule_is_an_error_not_inf() -> None:
    p = _three_tasks()
    with pytest.raises(ValueError, match="missing"):
        _evaluate(p, [Schedule(("t0",), ("t1",))], FixedDurationMotion(p))
    with pytest.raises(ValueError, match="not allowed"):
        _evaluate(p, [Schedule(("t0",), ("t1", "t2"))], FixedDurationMotion(p))
    ok = _evaluate(p, [Schedule(("t0", "t2"), ("t1",))], FixedDurationMotion(p))[0]
    assert ok.feasible  # the valid schedule the broken ones below are made from
    bad = {  # the fast set check must refuse what the item-by-item validate refuses
        "repeated": Schedule(("t0", "t2", "t0"), ("t1",)),
        "unknown task 'x'": Schedule(("t0", "t2", "x"), ("t1",)),
        "unknown task 'y'": Schedule(("t0", Wait("y"), "t2"), ("t1",)),
    }
    for message, schedule in bad.items():
        with pytest.raises(ValueError, match=message):
            _evaluate(p, [schedule], FixedDurationMotion(p))


def test_overlap_loop_converges_when_overlaps_settle() -> None:
    # r's duration = |C| + 1 and human tasks are 1 s each: C grows one task per round
    # {h1} -> {h1,h2} -> ... -> all five, where duration 6 covers all five and it settles.
    p = _chain_problem(5)
    sets = [frozenset(f"h{i}" for i in range(1, k + 1)) for k in range(1, 6)]
    motion = ConcurrencyMotion(lambda c: (len(c) + 1.0, 0.1 * len(c)), nominal=1.0)
    s = Schedule(("h1", "h2", "h3", "h4", "h5"), ("r",))
    (e,) = _evaluate(p, [s], motion, max_overlap_iters=10)
    assert e.converged and e.overlap_iterations == 5
    assert e.motions["r"].concurrent == sets[-1] == e.overlaps["r"]
    assert e.makespan_mean == pytest.approx(6.0) and e.spatial == pytest.approx(0.5)


def test_overlap_loop_is_capped_and_keeps_the_best_variant() -> None:
    p = _chain_problem(5)
    sets = [frozenset(f"h{i}" for i in range(1, k + 1)) for k in range(1, 6)]
    motion = ConcurrencyMotion(lambda c: (len(c) + 1.0, 0.1 * len(c)), nominal=1.0)
    s = Schedule(("h1", "h2", "h3", "h4", "h5"), ("r",))
    (e,) = _evaluate(p, [s], motion, max_overlap_iters=3)
    assert not e.converged and e.overlap_iterations == 3
    # variants: C={h1} (d 2, cost .1), {h1,h2} (d 3, .2), {h1..h3} (d 4, .3); makespan 5 each
    assert e.motions["r"].concurrent == sets[0]
    assert e.objective == pytest.approx(5.0 + 0.1)
    assert e.overlaps["r"] == sets[1]  # what the chosen motion actually overlaps


def test_overlap_oscillation_is_detected() -> None:
    # h1 [0,2], h2 [2,4]. d_init 1 -> C={h1}; plan(C={h1}) takes 3 s -> C={h1,h2};
    # plan({h1,h2}) takes 1 s -> C={h1} again: a two-cycle.
    p = Problem("osc", (Task("h1", HUMAN, 2.0, 0.0), Task("h2", HUMAN, 2.0, 0.0),
                        Task("r", ROBOT, robot_duration=1.0)))
    table = {frozenset({"h1"}): (3.0, 0.5), frozenset({"h1", "h2"}): (1.0, 0.2)}
    motion = ConcurrencyMotion(table.__getitem__, nominal=1.0)
    (e,) = _evaluate(p, [Schedule(("h1", "h2"), ("r",))], motion, max_overlap_iters=50)
    assert not e.converged and e.overlap_iterations == 2
    assert e.motions["r"].concurrent == frozenset({"h1", "h2"})  # cost 4 + 0.2 < 4 + 0.5
    assert e.objective == pytest.approx(4.2)


def test_overlap_rounds_ask_the_motion_model_once_per_round_for_all_candidates() -> None:
    p = _chain_problem(5)
    motion = ConcurrencyMotion(lambda c: (len(c) + 1.0, 0.0), nominal=1.0)
    order = ("h1", "h2", "h3", "h4", "h5")
    candidates = [Schedule(order, ("r",)), Schedule(order, (Wait("h1"), "r")),
                  Schedule(order, (Wait("h3"), "r"))]
    evals = _evaluate(p, candidates, motion, max_overlap_iters=10)
    assert all(e.converged for e in evals)
    assert len(motion.batches) == max(e.overlap_iterations for e in evals)
    first = motion.batches[0]  # round 1: r waiting for nothing, for h1 and for h3
    assert set(first) == {("r", frozenset({"h1"})), ("r", frozenset({"h2"})),
                          ("r", frozenset({"h4"}))}
    asked = [k for batch in motion.batches for k in batch]
    assert len(asked) == len(set(asked))  # the memory M answers repeats


# ----------------------------------------------------------------------------------- GA


@pytest.mark.parametrize("seed", range(6))
def test_ga_reaches_the_brute_force_optimum(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    p = random_problem(rng, 4 + seed % 3)
    mean = np.nan_to_num(means(p))
    result = GeneticScheduler(p, FixedDurationMotion(p), GAConfig(exact_seed_work=0)).solve(
        np.tile(mean, (4, 1)), mean, gamma=0.0
    )  # the search on its own, without the CP-SAT seed
    assert result.best.makespan_mean == pytest.approx(brute_force(p), abs=1e-9)
    validate(p, result.best.schedule)


def test_ga_is_deterministic_for_a_seed() -> None:
    rng = np.random.default_rng(7)
    p = random_problem(rng, 8)
    mean = np.nan_to_num(means(p))
    samples = mean * rng.uniform(0.7, 1.3, size=(16, 8))
    config = GAConfig(seed=11, generations=30, population=16)
    runs = [GeneticScheduler(p, FixedDurationMotion(p), config).solve(samples, mean)
            for _ in range(2)]
    assert runs[0].best.schedule == runs[1].best.schedule
    assert runs[0].best_by_generation == runs[1].best_by_generation
    assert runs[0].evaluations == runs[1].evaluations


def test_ga_result_bookkeeping_and_progress() -> None:
    rng = np.random.default_rng(8)
    p = random_problem(rng, 6)
    mean = np.nan_to_num(means(p))
    calls: list[tuple[int, float]] = []
    config = GAConfig(generations=12, population=10, patience=0, restart_after=0)
    result = GeneticScheduler(p, FixedDurationMotion(p), config).solve(
        mean[None], mean, progress=lambda g, b: calls.append((g, b))
    )
    assert result.generations_run == 12
    assert [g for g, _ in calls] == list(range(13))
    assert len(result.best_by_generation) == 13
    assert all(a >= b for a, b in itertools.pairwise(result.best_by_generation))
    assert result.best.objective <= result.best_by_generation[-1]
    assert 0 <= result.seconds_to_best <= result.seconds
    assert result.cache_misses == result.cache_size  # each (j, C_j) planned once
    assert result.cache_hits > 0
    assert result.evaluations > config.population


def test_mutations_and_activation_respect_allowed_agents() -> None:
    rng = np.random.default_rng(9)
    p = random_problem(rng, 9, restrict=0.5)
    scheduler = GeneticScheduler(p, FixedDurationMotion(p))
    mean = np.nan_to_num(means(p))
    d_init = scheduler.motion.nominal_durations(p)
    py = random.Random(1)
    s = scheduler.list_schedule(py, mean, d_init)
    for _ in range(2000):
        child = scheduler.mutate(s, py)
        assert child is not None and child != s
        validate(p, child)
        active = scheduler.activate(child, mean, d_init)
        if active is not None:
            validate(p, active)
            assert active.assignment == child.assignment
            assert CompiledSchedule.build(p, active) is not None
        s = child if CompiledSchedule.build(p, child) is not None else s


def test_move_puts_the_task_where_its_expected_start_falls() -> None:
    p = Problem("mv", tuple(Task(t, BOTH, 1.0, 0.0, 1.0) for t in "abcdef"))
    scheduler = GeneticScheduler(p, FixedDurationMotion(p))
    parent = Schedule(("a", "c", "e"), ("b", Wait("e"), "d", "f"))
    start = np.array([0.0, 0.5, 1.0, 2.0, 3.0, 4.0])  # a b c d e f
    py = random.Random(0)
    moved = set()
    for _ in range(60):
        child = scheduler.mutate(parent, py, [1.0, 0, 0, 0, 0], start)
        assert child is not None
        (task,) = set(child.tasks("human")) ^ set(parent.tasks("human"))
        moved.add(task)
        for agent in ("human", "robot"):  # both sequences stay in start-time order
            times = [start[p.index[t]] for t in child.tasks(agent)]
            assert times == sorted(times)
        if task == "c":  # in front of the wait that gates d: c must not inherit it
            assert child.robot == ("b", "c", Wait("e"), "d", "f")
        if task == "e":  # the wait on e is now on its own agent: repaired away
            assert child.robot == ("b", "d", "e", "f")
    assert moved == set("abcdef")


def test_list_schedules_are_always_feasible() -> None:
    rng = np.random.default_rng(10)
    p = random_problem(rng, 12, restrict=0.3)
    scheduler = GeneticScheduler(p, FixedDurationMotion(p))
    mean = np.nan_to_num(means(p))
    py = random.Random(2)
    for _ in range(200):
        s = scheduler.list_schedule(py, mean, scheduler.motion.nominal_durations(p))
        validate(p, s)
        assert CompiledSchedule.build(p, s) is not None


def test_activation_left_justifies_the_other_agent() -> None:
    # t0 -> t1 and t3 -> t4 across agents. Human [t0, t3] makes the robot's [t1, t4] wait for
    # t0 before t1, while t4 could run as soon as t3 is done: activation must swap them.
    p = Problem(
        "gt",
        (Task("t0", HUMAN, 4.0, 0.0), Task("t1", ROBOT, robot_duration=5.0),
         Task("t3", HUMAN, 1.0, 0.0), Task("t4", ROBOT, robot_duration=1.0)),
        (("t0", "t1"), ("t3", "t4")),
    )
    scheduler = GeneticScheduler(p, FixedDurationMotion(p))
    mean = np.nan_to_num(means(p))
    d_init = scheduler.motion.nominal_durations(p)
    s = Schedule(("t3", "t0"), ("t1", "t4"))  # t1 waits for t0 until 5; t4 after it: 11
    active = scheduler.activate(s, mean, d_init)
    assert active == Schedule(("t3", "t0"), ("t4", "t1"))  # t4 1-2, t1 5-10
    assert sequence_makespan(p, active.human, active.robot) == pytest.approx(10.0)
    assert sequence_makespan(p, s.human, s.robot) == pytest.approx(11.0)


def test_ga_plans_waits_when_proximity_costs_more_than_waiting() -> None:
    # The human does h (1 s) then x (3 s). The robot's r (2 s) costs 10 (gamma 1) if it
    # overlaps h: starting r at 0 costs 4 + 10, waiting for h costs nothing (r 1-3, z_t 4),
    # waiting for x costs 2 s (r 4-6).
    p = Problem("wait", (Task("h", HUMAN, 1.0, 0.0), Task("x", HUMAN, 3.0, 0.0),
                         Task("r", ROBOT, robot_duration=2.0)), (("h", "x"),))
    motion = ConcurrencyMotion(lambda c: (2.0, 10.0 if "h" in c else 0.0), nominal=2.0)
    mean = np.nan_to_num(means(p))
    result = GeneticScheduler(p, motion, GAConfig(generations=40)).solve(mean[None], mean,
                                                                        gamma=1.0)
    best = result.best
    assert best.spatial == 0.0
    assert best.objective == pytest.approx(4.0)
    assert best.schedule == Schedule(("h", "x"), (Wait("h"), "r"))


def _table_problem(rows: list[tuple[str, str, float, float]],
                   edges: list[tuple[str, str]]) -> Problem:
    agents = {"h": "human", "r": "robot"}
    return Problem("hard", tuple(
        Task(i, frozenset(agents[c] for c in allowed), h if "h" in allowed else None,
             0.0 if "h" in allowed else None, r if "r" in allowed else None)
        for i, allowed, h, r in rows), tuple(edges))


TRAP_INSTANCES = [
    # Two random 9-task instances (bench_scheduler.random_instance) on which the GA without
    # critical-path children and runner-up allocation polishes ended 4.5 % and 4.3 % above the
    # optimum for every seed tried: the best allocation's single-step neighbourhood is a trap.
    ([("t0", "hr", 6.6, 9.35), ("t1", "r", 9.42, 7.6), ("t2", "hr", 8.78, 7.41),
      ("t3", "hr", 9.28, 4.45), ("t4", "hr", 7.87, 1.27), ("t5", "hr", 7.97, 7.46),
      ("t6", "hr", 7.9, 4.76), ("t7", "hr", 3.41, 7.6), ("t8", "hr", 4.68, 2.82)],
     [("t0", "t7"), ("t0", "t8"), ("t1", "t6"), ("t1", "t7"), ("t1", "t8"), ("t2", "t3"),
      ("t2", "t8"), ("t3", "t5"), ("t4", "t8"), ("t5", "t8")]),
    ([("t0", "hr", 7.81, 7.58), ("t1", "hr", 7.25, 5.16), ("t2", "hr", 5.05, 2.73),
      ("t3", "hr", 3.57, 2.75), ("t4", "hr", 9.55, 4.37), ("t5", "hr", 9.86, 9.34),
      ("t6", "hr", 8.34, 1.49), ("t7", "hr", 1.07, 2.12), ("t8", "hr", 4.96, 3.11)],
     [("t0", "t2"), ("t0", "t7"), ("t3", "t4"), ("t4", "t7"), ("t5", "t6"), ("t7", "t8")]),
    # Two 10-task instances on which the GA without the order search ends 2.27 % and 2.93 %
    # above the optimum with seed 1: the optimal allocation is met only in poor orders.
    ([("t0", "hr", 5.47, 2.69), ("t1", "hr", 7.83, 4.18), ("t2", "hr", 5.84, 8.23),
      ("t3", "r", 8.57, 9.3), ("t4", "hr", 1.69, 9.0), ("t5", "hr", 6.52, 7.37),
      ("t6", "hr", 5.0, 5.34), ("t7", "hr", 8.15, 7.31), ("t8", "hr", 7.06, 2.21),
      ("t9", "hr", 8.25, 9.54)],
     [("t0", "t6"), ("t0", "t9"), ("t2", "t8"), ("t2", "t9"), ("t3", "t4"), ("t4", "t5"),
      ("t7", "t8")]),
    ([("t0", "hr", 2.16, 1.27), ("t1", "hr", 8.02, 2.62), ("t2", "hr", 3.25, 5.84),
      ("t3", "hr", 6.96, 7.65), ("t4", "hr", 9.31, 9.14), ("t5", "hr", 7.75, 1.83),
      ("t6", "r", 2.66, 8.96), ("t7", "hr", 2.73, 9.78), ("t8", "hr", 7.76, 1.58),
      ("t9", "hr", 5.78, 7.98)],
     [("t0", "t3"), ("t0", "t8"), ("t1", "t3"), ("t1", "t5"), ("t2", "t5"), ("t4", "t6")]),
]


@pytest.mark.parametrize("case", range(len(TRAP_INSTANCES)))
@pytest.mark.parametrize("seed", [0, 1])
def test_ga_defaults_reach_the_cp_sat_optimum_on_trap_instances(case: int, seed: int) -> None:
    p = _table_problem(*TRAP_INSTANCES[case])
    mean = np.nan_to_num(means(p))
    config = GAConfig(seed=seed, exact_seed_work=0)  # the search on its own, without CP-SAT
    result = GeneticScheduler(p, FixedDurationMotion(p), config).solve(
        np.tile(mean, (2, 1)), mean, gamma=0.0)
    assert result.best.makespan_mean == pytest.approx(solve_exact(p).makespan, abs=1e-6)
    validate(p, result.best.schedule)


@pytest.mark.parametrize(
    ("field", "value"),
    [("population", 1), ("generations", 0), ("samples", 0), ("elite_fraction", 1.0),
     ("elite_fraction", 0.0), ("max_overlap_iters", 0), ("patience", -1), ("seed", -2),
     ("mutation_weights", {"teleport": 1.0}), ("mutation_weights", {"move": -1.0}),
     ("mutation_weights", {"move": 0.0}), ("polish", "yes"), ("population", 2.5),
     ("restart_after", -1), ("elites_per_allocation", -1), ("polish_allocations", -1),
     ("polish_budget", -0.5), ("polish_budget", float("nan")), ("order_search_nodes", -3),
     ("order_search_nodes", 1.5), ("polish_window", -1), ("exact_seed_work", -1.0),
     ("exact_seed_work", True), ("time_limit_s", 0.0), ("time_limit_s", float("inf"))],
)
def test_config_rejects_bad_values(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field):
        GAConfig(**{field: value})  # type: ignore[arg-type]


def test_config_defaults_are_valid_and_weights_follow_the_operator_order() -> None:
    c = GAConfig(mutation_weights={"reorder": 2.0})
    assert c.weights() == [0.0, 2.0, 0.0, 0.0, 0.0]
    assert 1 <= GAConfig().n_elite < GAConfig().population


# ------------------------------------------------------------------- seeds, limits, scale


def test_polish_window_keeps_short_sequences_whole_and_bounds_long_ones() -> None:
    rng = np.random.default_rng(21)
    p = Problem("free", random_problem(rng, 24, restrict=0.0).tasks)  # no precedence
    mean = np.nan_to_num(means(p))
    motion = FixedDurationMotion(p)
    ga = GeneticScheduler(p, motion)
    s = ga.list_schedule(random.Random(0), mean, motion.nominal_durations(p))
    start = evaluate_population(EvaluationContext(p, mean[None], mean, TrajectoryCache(motion),
                                                  motion.nominal_durations(p), 0.0, 0.0),
                                [s])[0].expected_start
    whole = ga.neighbours(s)
    assert ga.neighbours(s, start, window=len(p.tasks)) == whole  # same schedules, same order
    near = ga.neighbours(s, start, window=2)
    assert set(near) < set(whole) and len(near) < len(whole) / 2
    for agent in ("human", "robot"):  # a reorder within the window is kept, one beyond is not
        seq = s.sequence(agent)
        if len(seq) >= 6:
            moved = repair(s.replace(agent, (*seq[1:3], seq[0], *seq[3:])))
            far = repair(s.replace(agent, (*seq[1:6], seq[0], *seq[6:])))
            assert moved in near and far in whole and far not in near


def test_initial_schedules_join_the_first_population() -> None:
    rng = np.random.default_rng(22)
    p = random_problem(rng, 9)
    mean = np.nan_to_num(means(p))
    optimum = solve_exact(p)
    config = GAConfig(generations=1, population=6, polish=False, order_search_nodes=0,
                      activate_children=False, exact_seed_work=0)
    result = GeneticScheduler(p, FixedDurationMotion(p), config).solve(
        mean[None], mean, gamma=0.0, initial=[optimum.schedule])
    assert result.seeds == [optimum.schedule]
    assert result.best_by_generation[0] == pytest.approx(optimum.makespan, abs=1e-9)
    with pytest.raises(ValueError, match="each task once"):
        GeneticScheduler(p, FixedDurationMotion(p), config).solve(
            mean[None], mean, initial=[Schedule(("t0",), ())])


def test_cp_sat_seeds_fixed_durations_only() -> None:
    rng = np.random.default_rng(23)
    p = random_problem(rng, 10)
    mean = np.nan_to_num(means(p))
    optimum = solve_exact(p, load_bound=True)
    assert optimum.optimal
    config = GAConfig(generations=2, population=8, exact_seed_work=5.0,  # proves it in less
                      exact_seed_min_tasks=10)
    seeded = GeneticScheduler(p, FixedDurationMotion(p), config).solve(
        mean[None], mean, gamma=0.0)
    assert seeded.seeds == [optimum.schedule]
    assert seeded.best_by_generation[0] == pytest.approx(optimum.makespan, abs=1e-9)
    motion = ConcurrencyMotion(lambda cj: (3.0, 0.0), 3.0)  # durations CP-SAT cannot see
    other = GeneticScheduler(p, motion, config).solve(mean[None], mean, gamma=0.0)
    assert other.seeds == []


def test_small_jobs_are_not_seeded_and_plan_never_imports_or_tools() -> None:
    rng = np.random.default_rng(23)
    p = random_problem(rng, 10)
    mean = np.nan_to_num(means(p))
    config = GAConfig(generations=2, population=8)  # defaults: seed from 11 tasks
    assert GeneticScheduler(p, FixedDurationMotion(p), config).solve(
        mean[None], mean, gamma=0.0).seeds == []
    # a fresh process: this one has imported OR-Tools for the exact solver's tests
    code = ("import sys\nfrom rapidds.cli import main\ntry:\n    main()\n"
            "except SystemExit as e:\n    assert not e.code, e.code\n"
            "assert 'ortools' not in sys.modules, 'plan imported OR-Tools'")
    fetch = Path(__file__).resolve().parents[1] / "examples" / "fetch.yaml"
    out = subprocess.run([sys.executable, "-c", code, "plan", str(fetch), "--seed", "0",
                          "--generations", "3"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]


def test_time_limit_stops_the_search_with_a_feasible_best() -> None:
    rng = np.random.default_rng(24)
    p = random_problem(rng, 40)
    mean = np.nan_to_num(means(p))
    config = GAConfig(time_limit_s=0.3, patience=0)
    result = GeneticScheduler(p, FixedDurationMotion(p), config).solve(mean[None], mean)
    assert result.timed_out and result.generations_run < config.generations
    assert result.best.feasible
    validate(p, result.best.schedule)


def test_improvements_trace_the_best_objective() -> None:
    rng = np.random.default_rng(25)
    p = random_problem(rng, 12)
    mean = np.nan_to_num(means(p))
    result = GeneticScheduler(p, FixedDurationMotion(p), GAConfig(seed=3)).solve(
        mean[None], mean)
    times = [t for t, _ in result.improvements]
    values = [v for _, v in result.improvements]
    assert times == sorted(times) and all(a > b for a, b in itertools.pairwise(values))
    assert values[-1] == result.best.objective
    assert times[-1] == result.seconds_to_best
    assert not result.timed_out


@pytest.mark.parametrize("seed", range(4))
def test_agent_load_bound_keeps_the_optimum(seed: int) -> None:
    p = random_problem(np.random.default_rng(300 + seed), 8)
    plain, bounded = solve_exact(p), solve_exact(p, load_bound=True)
    assert plain.optimal and bounded.optimal
    assert bounded.makespan == pytest.approx(plain.makespan, abs=1e-9)
    assert bounded.makespan == pytest.approx(brute_force(p), abs=1e-9)
