"""Schedule semantics: timelines computed by hand, deadlocks, repair, validation, overlaps."""

from __future__ import annotations

import numpy as np
import pytest

from rapidds.problem import Problem, Task
from rapidds.schedule import (
    CompiledSchedule,
    Schedule,
    ScheduleBatch,
    Wait,
    compile_schedule,
    parse_item,
    repair,
    validate,
)

BOTH = frozenset({"human", "robot"})


def _problem(precedence: tuple[tuple[str, str], ...] = (("a", "c"),)) -> Problem:
    # human means a=2 b=4 c=3 d=1; robot durations a=3 b=1 c=2 d=5
    return Problem(
        "hand",
        (
            Task("a", BOTH, 2.0, 0.0, 3.0),
            Task("b", BOTH, 4.0, 0.0, 1.0),
            Task("c", BOTH, 3.0, 0.0, 2.0),
            Task("d", BOTH, 1.0, 0.0, 5.0),
        ),
        precedence,
    )


HUMAN = np.array([[2.0, 4.0, 3.0, 1.0]])
ROBOT = np.array([3.0, 1.0, 2.0, 5.0])


def _timeline(problem: Problem, schedule: Schedule, human: np.ndarray = HUMAN):
    compiled = CompiledSchedule.build(problem, schedule)
    assert compiled is not None
    return compiled.simulate(compiled.durations(human, ROBOT))


def test_timeline_with_wait_by_hand() -> None:
    # human: a 0-2, c (after a) 2-5; robot: b 0-1, waits for a until 2, d 2-7
    s = Schedule(("a", "c"), ("b", Wait("a"), "d"))
    tl = _timeline(_problem(), s)
    np.testing.assert_allclose(tl.start, [[0, 0, 2, 2]])
    np.testing.assert_allclose(tl.finish, [[2, 1, 5, 7]])
    np.testing.assert_allclose(tl.makespan, [7])


def test_without_the_wait_the_robot_goes_on() -> None:
    # robot: b 0-1, d 1-6; human unchanged
    tl = _timeline(_problem(), Schedule(("a", "c"), ("b", "d")))
    np.testing.assert_allclose(tl.start, [[0, 0, 2, 1]])
    np.testing.assert_allclose(tl.finish, [[2, 1, 5, 6]])


def test_timeline_is_vectorised_over_samples() -> None:
    # sample 2: a=4, c=1 -> human a 0-4, c 4-5; robot b 0-1, wait a -> 4, d 4-9
    human = np.array([[2.0, 4.0, 3.0, 1.0], [4.0, 4.0, 1.0, 1.0]])
    tl = _timeline(_problem(), Schedule(("a", "c"), ("b", Wait("a"), "d")), human)
    np.testing.assert_allclose(tl.start, [[0, 0, 2, 2], [0, 0, 4, 4]])
    np.testing.assert_allclose(tl.finish, [[2, 1, 5, 7], [4, 1, 5, 9]])
    np.testing.assert_allclose(tl.makespan, [7, 9])


def test_precedence_across_agents_and_wait_on_unfinished_task() -> None:
    # precedence b -> c with b on the robot (duration 1) and a long robot task first:
    # robot: d 0-5, b 5-6; human: a 0-2, waits for d until 5, c waits for b -> 6-9
    p = _problem((("b", "c"),))
    s = Schedule(("a", Wait("d"), "c"), ("d", "b"))
    tl = _timeline(p, s)
    np.testing.assert_allclose(tl.start, [[0, 5, 6, 0]])
    np.testing.assert_allclose(tl.finish, [[2, 6, 9, 5]])


def test_robot_only_schedule_and_durations_columns() -> None:
    p = _problem(())
    compiled = CompiledSchedule.build(p, Schedule((), ("d", "a", "b", "c")))
    assert compiled is not None
    d = compiled.durations(HUMAN, ROBOT)
    np.testing.assert_allclose(d, [ROBOT])  # every column taken from the robot
    tl = compiled.simulate(d)
    np.testing.assert_allclose(tl.start, [[5, 8, 9, 0]])
    np.testing.assert_allclose(tl.makespan, [11])


@pytest.mark.parametrize(
    ("schedule", "precedence"),
    [
        # each agent waits for the other's first task
        (Schedule((Wait("b"), "a", "c"), (Wait("a"), "b", "d")), ()),
        # c must follow a but the human does c first
        (Schedule(("c", "a"), ("b", "d")), (("a", "c"),)),
        # c needs d (robot, after b), b needs a (human, after c)
        (Schedule(("c", "a"), ("b", "d")), (("a", "b"), ("d", "c"))),
        # a wait and a precedence edge close the cycle: robot waits for c before b, c needs b
        (Schedule(("a", "c"), (Wait("c"), "b", "d")), (("b", "c"),)),
    ],
)
def test_deadlocks_compile_to_none(
    schedule: Schedule, precedence: tuple[tuple[str, str], ...]
) -> None:
    assert compile_schedule(_problem(precedence), schedule) is None


def test_same_orders_without_the_cycle_compile() -> None:
    assert compile_schedule(_problem((("a", "b"),)), Schedule(("a", "c"), ("b", "d"))) is not None


def test_wait_on_a_task_nobody_does_deadlocks() -> None:
    p = _problem(())
    assert CompiledSchedule.build(p, Schedule(("a", Wait("x"), "c"), ("b", "d"))) is None


def test_repair_drops_waits_that_cannot_matter() -> None:
    s = Schedule(
        (Wait("c"), "a", Wait("b"), "c", Wait("b"), Wait("d")),  # own, kept, repeated, trailing
        ("b", Wait("a"), Wait("a"), "d", Wait("c")),  # kept, repeated, trailing
    )
    fixed = repair(s)
    assert fixed == Schedule(("a", Wait("b"), "c"), ("b", Wait("a"), "d"))
    assert repair(fixed) == fixed


def test_repair_drops_several_trailing_waits_and_keeps_empty_sequences() -> None:
    s = Schedule(("a", "c", Wait("b"), Wait("d")), (Wait("a"),))
    assert repair(s) == Schedule(("a", "c"), ())


def test_validate_accepts_a_complete_schedule() -> None:
    validate(_problem(), Schedule(("a", Wait("b"), "c"), ("b", "d")))


@pytest.mark.parametrize(
    ("schedule", "message"),
    [
        (Schedule(("a", "c", "x"), ("b", "d")), "unknown task 'x'"),
        (Schedule(("a", Wait("x"), "c"), ("b", "d")), "unknown task 'x'"),
        (Schedule(("a", "c"), ("b",)), "missing ['d']"),
        (Schedule(("a", "c", "d"), ("b", "d")), "repeated ['d']"),
    ],
)
def test_validate_errors(schedule: Schedule, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        validate(_problem(), schedule)


def test_validate_rejects_a_task_on_a_disallowed_agent() -> None:
    p = Problem(
        "restricted",
        (Task("a", frozenset({"human"}), 1.0, 0.0), Task("b", BOTH, 1.0, 0.0, 1.0)),
    )
    with pytest.raises(ValueError, match="'a' is not allowed to the robot"):
        validate(p, Schedule(("b",), ("a",)))


def test_overlaps_need_positive_length() -> None:
    # robot b [0,1] overlaps human a [0,2]; robot d [2,7] overlaps c [2,5] and only touches a
    tl = _timeline(_problem(), Schedule(("a", "c"), ("b", Wait("a"), "d")))
    assert tl.overlaps() == {"b": frozenset({"a"}), "d": frozenset({"c"})}


def test_overlaps_per_sample() -> None:
    # sample 1: a [0,4], c [4,5]; robot b [0,1], d [4,9]
    human = np.array([[2.0, 4.0, 3.0, 1.0], [4.0, 4.0, 1.0, 1.0]])
    tl = _timeline(_problem(), Schedule(("a", "c"), ("b", Wait("a"), "d")), human)
    assert tl.overlaps(1) == {"b": frozenset({"a"}), "d": frozenset({"c"})}
    tl2 = _timeline(_problem(), Schedule(("a", "c"), ("b", "d")), human)
    # without the wait d starts at 1 and overlaps both human tasks in sample 1
    assert tl2.overlaps(1) == {"b": frozenset({"a"}), "d": frozenset({"a", "c"})}


def test_schedule_json_round_trip_and_assignment() -> None:
    s = Schedule(("a", Wait("b"), "c"), ("b", "d"))
    assert Schedule.from_json(s.to_json()) == s
    assert parse_item("wait:b") == Wait("b") and parse_item("b") == "b"
    assert s.assignment == {"a": "human", "c": "human", "b": "robot", "d": "robot"}
    assert len({s, Schedule.from_json(s.to_json())}) == 1


def test_batch_timelines_equal_one_by_one_timelines_bit_for_bit() -> None:
    """ScheduleBatch: the same starts and finishes as CompiledSchedule, the same deadlocks,
    for schedules with waits, precedence across agents and cycles, in one batch."""
    p = _problem((("a", "c"), ("b", "d")))
    rng = np.random.default_rng(3)
    items = ["a", "b", "c", "d"]
    schedules = []
    for _ in range(300):
        order = [str(x) for x in rng.permutation(items)]
        cut = int(rng.integers(0, 5))
        human: list = order[:cut]
        robot: list = order[cut:]
        for _ in range(int(rng.integers(0, 3))):  # waits anywhere, on any task (even own)
            seq = human if rng.random() < 0.5 else robot
            seq.insert(int(rng.integers(0, len(seq) + 1)), Wait(str(rng.choice(items))))
        schedules.append(Schedule(tuple(human), tuple(robot)))
    rows = np.vstack([HUMAN, HUMAN * rng.uniform(0.5, 2.0, size=(5, 4))])
    batch = ScheduleBatch(p, schedules)
    start, finish, feasible = batch.simulate(batch.durations(rows, ROBOT))
    assert 0 < feasible.sum() < len(schedules)  # both kinds occur
    for b, s in enumerate(schedules):
        compiled = CompiledSchedule.build(p, s)
        assert feasible[b] == (compiled is not None), s
        if compiled is not None:
            tl = compiled.simulate(compiled.durations(rows, ROBOT))
            assert np.array_equal(start[b].T, tl.start) and np.array_equal(finish[b].T, tl.finish)
