"""The live cell re-plans the rest of the cycle when the person deviates (issue 34 item 4):
the re-planner on what a hub sees, and end to end in a live painting cell on localhost (the
hub, the MuJoCo robot and the person as three processes), where the person's first task runs
three times its drawn duration (a pause, a slow hand) and the hub re-plans the robot's rest.

Simulated time runs 4x faster than the wall clock (``--time-scale 4``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from test_bridge_e2e import LiveCycle, reactive_painting_cycle

from rapidds.bridge import ros2
from rapidds.bridge.live import LivePlan
from rapidds.bridge.nodes.sim_human import SimHuman
from rapidds.bridge.replan import LiveReplanner
from rapidds.execution import Replanning
from rapidds.worlds.registry import make_world

SLOW = 3.0  # the person's first task takes this many times its drawn duration


def _replanner(robot: list[str]) -> LiveReplanner:
    """Painting's tasks; a robot whose mix_r beside the person's secure_piece costs 10 (its
    spatial cost), mix_l 7 s, mix_r 6 s, brush 4 s."""
    problem = make_world("painting").problem()
    human = ["prep_vise", "secure_piece"]
    after = {"prep_vise": [], "secure_piece": ["prep_vise"]}
    prev = None
    for t in robot:
        after[t] = sorted({*problem.preceding[t], *([prev] if prev else [])})
        prev = t
    mean = {"prep_vise": 4.0, "secure_piece": 6.0, "brush": 5.0}
    rp = Replanning(mean=mean, std={t: 0.5 for t in mean},
                    robot={"mix_l": 7.0, "mix_r": 6.0, "brush": 4.0},
                    spatial=lambda j, near: 10.0 * (j == "mix_r" and "secure_piece" in near),
                    gamma=1.0)
    return LiveReplanner(problem, {"human": human, "robot": list(robot)}, after, rp)


def test_a_task_past_its_quantile_is_an_overrun_that_replans_the_robots_rest():
    rp = _replanner(["mix_r", "mix_l", "brush"])
    start = {"prep_vise": 0.0}
    assert rp.deviations(4.5, start, {}, ["prep_vise"]) == []  # within mean + z sd
    assert rp.deviations(4.7, start, {}, ["prep_vise"]) == [("overran", "prep_vise")]
    assert rp.deviations(9.0, start, {}, ["prep_vise"]) == []  # once per task
    # as planned, mix_r would run beside secure_piece (cost 10); mix_l first avoids it
    entry = rp.replan(4.7, "overran", "prep_vise", start, {}, [])
    assert entry["changed"] and entry["before"]["robot"] == ["mix_r", "mix_l", "brush"]
    assert rp.order["robot"] == ["mix_l", "mix_r", "brush"] == entry["after"]["robot"]
    assert entry["expected_makespan_cost"] < entry["expected_cost_before"]
    assert "mix_l" in rp.after["mix_r"] and "mix_r" not in rp.after["mix_l"]
    assert set(rp.problem.preceding["brush"]) | {"mix_r"} <= set(rp.after["brush"])


def test_a_replan_keeps_what_was_sent_first_and_an_unchanged_rest_as_planned():
    rp = _replanner(["mix_r", "mix_l", "brush"])
    before = {t: list(v) for t, v in rp.after.items()}
    entry = rp.replan(8.0, "overran", "prep_vise", {"prep_vise": 0.0, "mix_r": 1.0}, {},
                      ["mix_r"])
    assert not entry["changed"] and rp.order["robot"] == ["mix_r", "mix_l", "brush"]
    assert rp.after == before


def test_a_person_starting_another_of_their_tasks_is_an_order_deviation():
    rp = _replanner(["mix_l", "mix_r"])
    rp.order["human"] = ["secure_piece", "prep_vise"]  # as if the plan had them the other way
    assert rp.deviations(0.5, {"prep_vise": 0.2}, {}, ["prep_vise"]) == [("order", "prep_vise")]


class _Slow(SimHuman):
    """The reference person, whose first task of each plan takes SLOW times its drawn
    duration (they stand at its last row meanwhile)."""

    def _begin(self, now: int) -> None:
        super()._begin(now)
        if self._doing is not None and self._next == 0:  # began the plan's first task
            self._doing.duration *= SLOW


def slow_person_cycle(tmp_path: Path, person: type[SimHuman] = _Slow,
                      extra: tuple[str, ...] = ()) -> LiveCycle:
    """One reactive painting cycle with ``person`` (a SimHuman class) as the left-slow teammate,
    watching the plan and the events; ``extra``: more arguments of the hub."""
    world = make_world("painting")
    teammate = world.teammate("left-slow")
    teammate.at(0).perform(world.problem().ids[0], np.random.default_rng(0))
    watch = {ros2.PLAN_TOPIC: "std_msgs/msg/String", ros2.EVENTS_TOPIC: "std_msgs/msg/String"}
    return reactive_painting_cycle(
        tmp_path, lambda link: person(world, teammate, link, seed=1), watch, extra)


def test_the_live_cell_replans_when_the_person_overruns(tmp_path: Path) -> None:
    cell = slow_person_cycle(tmp_path)
    assert cell.code == 0, cell.err[-3000:]
    (rec,), seen = cell.records, cell.seen
    plan = LivePlan.parse(next(r for r in seen if r.topic == ros2.PLAN_TOPIC).msg.data)
    first = plan.order["human"][0]
    overran = [r for r in rec["replans"] if r["reason"] == "overran" and r["task"] == first]
    assert overran, rec["replans"]
    r = overran[0]
    assert r["evaluated"] >= 1 and r["latency_s"] >= 0.0 and r["time"] > 0.0
    # the robot ran its tasks in the order the last re-plan left (sent ones first)
    events = [ros2.parse_event(x.msg.data) for x in seen if x.topic == ros2.EVENTS_TOPIC]
    ran = [ev.task for ev in events if ev.agent == "robot" and ev.event == "start"]
    assert sorted(ran) == sorted(plan.order["robot"])
    last = rec["replans"][-1]
    assert ran[len(ran) - len(last["after"]["robot"]):] == last["after"]["robot"]
    assert rec["executed"]["robot"] == ran  # the cycle is realised in the order it ran
    assert "re-planned at" in cell.err
