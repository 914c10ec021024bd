"""The live cell re-plans the rest of the cycle when the person deviates (issue 34 item 4):
the re-planner on what a hub sees, and end to end in a live painting cell on localhost (the
hub, the MuJoCo robot and the person as three processes), where the person's first task runs
three times its drawn duration (a pause, a slow hand) and the hub re-plans the robot's rest.

Simulated time runs 4x faster than the wall clock (``--time-scale 4``)."""

from __future__ import annotations

import json
import os
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
from test_bridge_e2e import CLI, SEARCH, _endpoint, _start, _stop

from rapidds.bridge import ros2
from rapidds.bridge.link import Link
from rapidds.bridge.live import LivePlan
from rapidds.bridge.nodes.sim_human import SimHuman
from rapidds.bridge.replan import LiveReplanner
from rapidds.execution import Replanning
from rapidds.worlds.registry import make_world

SLOW = 3.0  # the person's first task takes this many times its drawn duration


def _replanner(robot: list[str]) -> LiveReplanner:
    problem = make_world("painting").problem()
    human = ["prep_vise", "secure_piece"]
    after = {"prep_vise": [], "secure_piece": ["prep_vise"]}
    prev = None
    for t in robot:
        after[t] = sorted({*problem.preceding[t], *([prev] if prev else [])})
        prev = t
    mean = {"prep_vise": 4.0, "secure_piece": 6.0, "brush": 5.0}
    rp = Replanning(mean=mean, std={t: 0.5 for t in mean},
                    robot={"mix_l": 3.0, "mix_r": 6.0, "brush": 4.0},
                    spatial=lambda j, near: 0.0, gamma=1.0)
    return LiveReplanner(problem, {"human": human, "robot": list(robot)}, after, rp)


def test_a_task_past_its_quantile_is_an_overrun_that_replans_the_robots_rest():
    rp = _replanner(["mix_r", "mix_l", "brush"])
    start = {"prep_vise": 0.0, "mix_r": 0.0}
    assert rp.deviations(4.5, start, {}, ["prep_vise"]) == []  # within mean + z sd
    assert rp.deviations(4.7, start, {}, ["prep_vise"]) == [("overran", "prep_vise")]
    assert rp.deviations(9.0, start, {}, ["prep_vise"]) == []  # once per task
    entry = rp.replan(4.7, "overran", "prep_vise", start, {}, ["mix_r"])
    assert entry["before"]["robot"] == ["mix_l", "brush"] and entry["evaluated"] >= 1
    assert rp.order["robot"][0] == "mix_r"  # sent: stays first
    assert set(rp.order["robot"]) == {"mix_r", "mix_l", "brush"}
    for a, b in zip(rp.order["robot"][1:], rp.order["robot"][2:], strict=False):
        assert a in rp.after[b]  # the robot's new order gates its dispatch
    assert set(rp.problem.preceding["brush"]) <= set(rp.after["brush"])


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


def test_the_live_cell_replans_when_the_person_overruns(tmp_path: Path) -> None:
    world = make_world("painting")
    teammate = world.teammate("left-slow")
    teammate.at(0).perform(world.problem().ids[0], np.random.default_rng(0))
    ep, out = _endpoint(), tmp_path / "run"
    robot = _start(["sim-robot", "painting", "--connect", ep], tmp_path / "robot.log")
    watch = {ros2.PLAN_TOPIC: "std_msgs/msg/String", ros2.EVENTS_TOPIC: "std_msgs/msg/String"}
    stop = threading.Event()
    hub_out, hub_err = tmp_path / "hub.out", tmp_path / "hub.err"
    with open(hub_out, "wb") as o, open(hub_err, "wb") as e:
        hub = subprocess.Popen(
            [*CLI, "deploy", "painting", "--listen", ep, "--cycles", "1", "--out", str(out),
             "--json", "--time-scale", "4", "--execution", "reactive",
             "--startup-timeout", "90", *SEARCH], stdout=o, stderr=e,
            env={**os.environ, "RAPIDDS_LOG": "info"})
    try:
        with Link(SimHuman.topics(), connect=ep) as plink, Link(watch, connect=ep) as wlink:
            person = _Slow(world, teammate, plink, seed=1)

            def act() -> None:
                while not stop.is_set():
                    person.spin(until=time.monotonic() + 0.2)

            t = threading.Thread(target=act, daemon=True)
            t.start()
            code = hub.wait(240)
            stop.set()
            t.join(5)
            seen = wlink.drain()
    finally:
        stop.set()
        _stop(robot, hub)
    assert code == 0, hub_err.read_text()[-3000:]
    (rec,) = [json.loads(x) for x in hub_out.read_text().splitlines()]
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
    assert "re-planned at" in hub_err.read_text()
