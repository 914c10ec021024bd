"""Active schedules of one allocation: the branch and bound against brute force, its budget,
and waits kept through a reorder."""

from __future__ import annotations

import numpy as np
import pytest
from reference import best_order, sequence_makespan
from test_scheduler import BOTH, HUMAN, ROBOT, means, random_problem

from rapidds.motion.interface import FixedDurationMotion
from rapidds.problem import Problem, Task
from rapidds.schedule import CompiledSchedule, Schedule, Wait, validate
from rapidds.scheduler import GAConfig, GeneticScheduler
from rapidds.scheduler.active import AllocationOrders, longest_tails


def _orders(p: Problem, s: Schedule) -> AllocationOrders:
    return GeneticScheduler(p, FixedDurationMotion(p))._orders(
        s, np.nan_to_num(means(p)), FixedDurationMotion(p).nominal_durations(p))


def _random_allocation(p: Problem, rng: np.random.Generator) -> Schedule:
    """Every task on a random allowed agent, each agent's tasks in problem order (which
    respects precedence, since edges go from lower to higher ids)."""
    agent = {t.id: sorted(t.allowed)[int(rng.integers(len(t.allowed)))] for t in p.tasks}
    return Schedule(tuple(t for t in p.ids if agent[t] == "human"),
                    tuple(t for t in p.ids if agent[t] == "robot"))


@pytest.mark.parametrize("seed", range(8))
def test_search_finds_the_brute_force_best_order_of_an_allocation(seed: int) -> None:
    rng = np.random.default_rng(300 + seed)
    p = random_problem(rng, 6 + seed % 2, restrict=0.0)
    s = _random_allocation(p, rng)
    found, finished = _orders(p, s).search(max_nodes=100_000)
    assert finished and found
    shortest = found[0]
    validate(p, shortest)
    assert set(shortest.human) == set(s.human)  # the allocation is kept
    assert sequence_makespan(p, shortest.human, shortest.robot) == pytest.approx(
        best_order(p, s.human, s.robot), abs=1e-9)
    spans = [sequence_makespan(p, x.human, x.robot) for x in found]
    assert spans == sorted(spans) and len(set(spans)) == len(spans)  # strictly improving


def test_a_small_budget_still_returns_the_first_complete_order() -> None:
    p = random_problem(np.random.default_rng(5), 9, restrict=0.0)
    s = Schedule(tuple(p.ids[:5]), tuple(p.ids[5:]))
    found, finished = _orders(p, s).search(max_nodes=1)
    assert not finished and len(found) == 1
    validate(p, found[0])
    full, done = _orders(p, s).search(max_nodes=100_000)
    assert done
    assert sequence_makespan(p, full[0].human, full[0].robot) <= sequence_makespan(
        p, found[0].human, found[0].robot)


def test_waits_stay_in_front_of_their_task_and_gate_it() -> None:
    # Robot: r1 (1 s), then a wait for the human's h1 (5 s), then r2 (1 s). Without the wait
    # r2 would go first at 0; with it r2 cannot start before 5 whatever the order.
    p = Problem("w", (Task("h1", HUMAN, 5.0, 0.0), Task("r1", ROBOT, robot_duration=1.0),
                      Task("r2", ROBOT, robot_duration=1.0)))
    s = Schedule(("h1",), ("r1", Wait("h1"), "r2"))
    found, finished = _orders(p, s).search(max_nodes=1000)
    assert finished
    assert found[0].robot == ("r1", Wait("h1"), "r2")
    timeline = CompiledSchedule.build(p, found[0]).simulate(np.array([[5.0, 1.0, 1.0]]))
    assert timeline.makespan[0] == pytest.approx(6.0)


def test_cyclic_waits_give_no_order() -> None:
    # Each agent waits for the other's only task: no order can run.
    p = Problem("c", (Task("h", BOTH, 1.0, 0.0, 1.0), Task("r", BOTH, 1.0, 0.0, 1.0)))
    s = Schedule((Wait("r"), "h"), (Wait("h"), "r"))
    assert _orders(p, s).search(max_nodes=100) == ([], True)
    assert _orders(p, s).active() is None


def test_longest_tails_follow_the_heaviest_successor_chain() -> None:
    succ = {"a": ["b", "c"], "b": ["d"], "c": [], "d": []}
    tails = longest_tails(["a", "b", "c", "d"], succ, {"a": 1.0, "b": 2.0, "c": 5.0, "d": 1.0})
    assert tails == {"a": 6.0, "b": 3.0, "c": 5.0, "d": 1.0}


def test_search_starts_the_critical_chain_first() -> None:
    # The robot's a (2 s) gates the human's h (4 s): a first gives 6, b first gives 7.
    p = Problem("r", (Task("a", ROBOT, robot_duration=2.0), Task("b", ROBOT, robot_duration=1.0),
                      Task("h", HUMAN, 4.0, 0.0)), (("a", "h"),))
    found, finished = _orders(p, Schedule(("h",), ("b", "a"))).search(max_nodes=100)
    assert finished and found[0].robot == ("a", "b")
    assert sequence_makespan(p, found[0].human, found[0].robot) == pytest.approx(6.0)


def test_ga_evaluates_the_shortest_order_of_every_allocation_it_meets() -> None:
    # Every task fixed to one agent: one allocation, met in the initial population. With one
    # generation of wait mutants and no activation or polish, only the order search can make
    # the result optimal; without it some of these instances end above the optimum.
    gaps = {True: [], False: []}
    for seed in range(6):
        p = random_problem(np.random.default_rng(400 + seed), 8, restrict=1.0)
        mean = np.nan_to_num(means(p))
        h = [t.id for t in p.tasks if t.allowed == HUMAN]
        r = [t.id for t in p.tasks if t.allowed == ROBOT]
        optimum = best_order(p, h, r)
        for search in (True, False):
            config = GAConfig(population=2, generations=1, activate_children=False,
                              polish=False, order_search_nodes=300 * search,
                              mutation_weights={"add_wait": 1.0}, exact_seed_work=0,
                              seed=seed)
            result = GeneticScheduler(p, FixedDurationMotion(p), config).solve(
                mean[None], mean, gamma=0.0)
            gaps[search].append(result.best.makespan_mean - optimum)
    assert max(gaps[True]) == pytest.approx(0.0, abs=1e-9)
    assert max(gaps[False]) > 0.1
