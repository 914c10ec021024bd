"""CP-SAT baseline against brute force; allowed agents, precedence, overrides, errors."""

from __future__ import annotations

import numpy as np
import pytest
from reference import brute_force

from rapidds.errors import ProblemError
from rapidds.problem import Problem, Task
from rapidds.schedule import CompiledSchedule, validate
from rapidds.scheduler import solve_exact

BOTH = frozenset({"human", "robot"})


def _random_problem(rng: np.random.Generator, n: int) -> Problem:
    tasks = []
    for i in range(n):
        u = rng.random()
        allowed = BOTH if u >= 0.3 else frozenset({"human" if u < 0.15 else "robot"})
        tasks.append(Task(f"t{i}", allowed, round(float(rng.uniform(1, 10)), 2), 0.0,
                          round(float(rng.uniform(1, 10)), 2)))
    edges = tuple((f"t{i}", f"t{j}") for i in range(n) for j in range(i + 1, n)
                  if rng.random() < 0.3)
    return Problem(f"r{n}", tuple(tasks), edges)


@pytest.mark.parametrize("seed", range(24))
def test_cp_sat_agrees_with_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    p = _random_problem(rng, 3 + seed % 4)
    result = solve_exact(p, time_limit_s=10)
    assert result.optimal and result.status == "OPTIMAL"
    assert result.makespan == pytest.approx(brute_force(p), abs=1e-9)
    assert result.bound == pytest.approx(result.makespan, abs=1e-9)
    validate(p, result.schedule)  # every task once, each on an allowed agent
    assert not any(not isinstance(x, str) for a in ("human", "robot")
                   for x in result.schedule.sequence(a))  # no waits


def test_respects_allowed_agents_and_precedence() -> None:
    # The robot is far faster at everything, but b and d are human-only and c needs b.
    p = Problem(
        "restricted",
        (
            Task("a", BOTH, 9.0, 0.0, 1.0),
            Task("b", frozenset({"human"}), 3.0, 0.0),
            Task("c", BOTH, 9.0, 0.0, 1.0),
            Task("d", frozenset({"human"}), 1.0, 0.0),
        ),
        (("b", "c"),),
    )
    result = solve_exact(p)
    assert set(result.schedule.human) == {"b", "d"}
    assert set(result.schedule.robot) == {"a", "c"}
    compiled = CompiledSchedule.build(p, result.schedule)
    assert compiled is not None
    tl = compiled.simulate(compiled.durations(np.array([[9.0, 3.0, 9.0, 1.0]]),
                                              np.array([1.0, np.nan, 1.0, np.nan])))
    idx = p.index
    assert tl.finish[0, idx["b"]] <= tl.start[0, idx["c"]]  # precedence across agents
    assert result.makespan == pytest.approx(4.0)  # b 0-3, d 3-4; a 0-1, c 3-4


def test_duration_overrides_change_the_allocation() -> None:
    p = Problem("two", (Task("a", BOTH, 1.0, 0.0, 5.0), Task("b", BOTH, 1.0, 0.0, 5.0)))
    assert solve_exact(p).makespan == pytest.approx(2.0)  # human does both
    slow_human = solve_exact(p, human_mean=np.array([10.0, 10.0]))
    assert slow_human.makespan == pytest.approx(10.0)  # one each, or the robot does both
    fast_robot = solve_exact(p, robot_durations=np.array([0.5, 0.5]))
    assert fast_robot.schedule.human == () and fast_robot.makespan == pytest.approx(1.0)


def test_rounding_to_the_time_scale_is_reported_on_true_durations() -> None:
    p = Problem("round", (Task("a", BOTH, 1.004, 0.0, 3.0), Task("b", BOTH, 1.004, 0.0, 3.0)))
    result = solve_exact(p, scale=100)
    assert result.makespan == pytest.approx(2.008)  # 1.004 s each, not the rounded 1.00


def test_bad_arguments_and_unsolved_problems() -> None:
    p = Problem("one", (Task("a", BOTH, 1.0, 0.0, 1.0),))
    with pytest.raises(ValueError, match="shape"):
        solve_exact(p, human_mean=np.array([1.0, 2.0]))
    with pytest.raises(ValueError, match="must be > 0"):
        solve_exact(p, robot_durations=np.array([0.0]))
    with pytest.raises(ValueError, match="scale"):
        solve_exact(p, scale=0)
    big = _random_problem(np.random.default_rng(0), 40)
    with pytest.raises(ProblemError, match="CP-SAT"):
        solve_exact(big, time_limit_s=1e-9)
