"""A live painting cell on localhost: three processes (the planner as hub, the MuJoCo robot, the
simulated person) run two cycles over Zenoh; the robot dies mid-cycle 1, the hub stops without
recording it, and ``--resume`` with a fresh robot completes the run.

Simulated time runs 4x faster than the wall clock (``--time-scale 4``): a painting cycle of
about 17-20 cell seconds takes about 5 wall seconds."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pytest
from cli_helpers import cli_cmd

from rapidds.loop.config import RunConfig
from rapidds.store import RunStore

SEARCH = ["--population", "8", "--generations", "4", "--samples", "8", "--particles", "2",
          "--candidates", "4"]


def _endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _start(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    env = {**os.environ, "RAPIDDS_LOG": "info"}
    with open(log, "wb") as f:
        return subprocess.Popen(cli_cmd(*args), stdout=f, stderr=subprocess.STDOUT, env=env)


def _wait_text(path: Path, text: str, proc: subprocess.Popen[bytes], timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text():
            return
        assert proc.poll() is None, f"exited {proc.returncode}: {path.read_text()[-2000:]}"
        time.sleep(0.2)
    raise AssertionError(f"{text!r} not in {path} after {timeout} s: {path.read_text()[-2000:]}")


def _inject_faults(ep: str, point: str, hub_err: Path, hub: subprocess.Popen[bytes]) -> None:
    """Bytes that are no CDR, an event of no task in the plan and a tracked point from the past,
    from a new peer; the peer stays until the hub has logged all three (a put is queued, not
    sent, when it returns)."""
    from rapidds.bridge import ros2
    from rapidds.bridge.link import Link
    from rapidds.bridge.live import tracking_topic

    with Link({}, connect=ep) as peer:
        peer.publish_raw(ros2.EVENTS_TOPIC, b"\x00\x01\x02 not CDR")
        peer.publish(ros2.EVENTS_TOPIC, ros2.event_message(
            ros2.Event("paint_wall", "human", "start")))
        peer.publish(tracking_topic(point), ros2.point_stamped((0.0, 0.0, 0.0), 1))
        for line in ("malformed message on /rapidds/events", "'paint_wall'",
                     f"{tracking_topic(point)} stamped"):
            _wait_text(hub_err, line, hub, timeout=60)


def _stop(*procs: subprocess.Popen[bytes]) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()


class LiveCycle(NamedTuple):
    code: int  # the hub's exit code
    err: str  # its stderr
    records: list[dict[str, Any]]  # its --json records
    seen: list[Any]  # what a listener to the watched topics heard


def reactive_painting_cycle(tmp_path: Path, person: Callable[[Any], Any],
                            watch: dict[str, str], extra: tuple[str, ...] = ()) -> LiveCycle:
    """One reactive painting cycle on three processes: the hub (``deploy``), ``sim-robot``,
    and ``person(link)`` (a SimHuman on this process's link) spun on a thread. Cell time runs
    at 2x, not 4x: the hub's blind-monitor limit is 1 cell s, which at 4x is 0.25 wall s of
    a stall of the in-process person or the hub: with one busy process beside it the hold test
    failed 1 run in 4 at 4x (the failures read: tracking 1.6 s old, the monitor blind), 0 in 5
    at 2x. ``extra``: more arguments of ``deploy`` (a seed whose plan a test needs)."""
    from rapidds.bridge.link import Link
    from rapidds.bridge.nodes.sim_human import SimHuman

    ep, out = _endpoint(), tmp_path / "run"
    robot = _start(["sim-robot", "painting", "--connect", ep], tmp_path / "robot.log")
    stop = threading.Event()
    hub_out, hub_err = tmp_path / "hub.out", tmp_path / "hub.err"
    with open(hub_out, "wb") as o, open(hub_err, "wb") as e:  # a node connects to a hub
        hub = subprocess.Popen(
            cli_cmd("deploy", "painting", "--listen", ep, "--cycles", "1", "--out", str(out),
             "--json", "--time-scale", "2", "--execution", "reactive",
             "--startup-timeout", "90", *SEARCH, *extra), stdout=o, stderr=e,
            env={**os.environ, "RAPIDDS_LOG": "info"})
    try:
        with Link(SimHuman.topics(), connect=ep) as plink, Link(watch, connect=ep) as wlink:
            node = person(plink)

            def act() -> None:
                while not stop.is_set():
                    node.spin(until=time.monotonic() + 0.2)

            t = threading.Thread(target=act, daemon=True)
            t.start()
            code = hub.wait(240)
            stop.set()
            t.join(5)
            seen = wlink.drain()
    finally:
        stop.set()
        _stop(robot, hub)
    return LiveCycle(code, hub_err.read_text(),
                     [json.loads(x) for x in hub_out.read_text().splitlines()], seen)


@pytest.mark.slow
def test_two_live_painting_cycles_survive_a_dead_robot_and_resume(tmp_path: Path) -> None:
    from rapidds.worlds.base import body_point_names
    from rapidds.worlds.registry import make_world

    ep, out = _endpoint(), tmp_path / "run"
    point = body_point_names(make_world("painting"))[0]  # the person's tracked left wrist
    deploy = ["deploy", "painting", "--bridge", "zenoh", "--listen", ep, "--cycles", "2",
              "--out", str(out), "--json", "--time-scale", "4", "--robot-timeout", "2",
              "--startup-timeout", "90", *SEARCH]
    robot = _start(["sim-robot", "painting", "--connect", ep], tmp_path / "robot1.log")
    human = _start(["sim-human", "painting", "--human", "left-slow", "--connect", ep],
                   tmp_path / "human.log")
    robot2 = hub = None
    try:
        hub_out, hub_err = tmp_path / "hub1.out", tmp_path / "hub1.err"
        with open(hub_out, "wb") as o, open(hub_err, "wb") as e:
            hub = subprocess.Popen(cli_cmd(*deploy), stdout=o, stderr=e,
                                   env={**os.environ, "RAPIDDS_LOG": "info"})
        # a faulty peer mid-cycle 0: bytes that are no message, an event of no task in the
        # plan, a tracked point from the past; each is dropped with one line
        _wait_text(hub_err, "cycle 0: human prep_vise start", hub, timeout=240)
        _inject_faults(ep, point, hub_err, hub)
        # the robot dies once it is moving in cycle 1
        _wait_text(hub_err, "cycle 1: robot ", hub, timeout=240)
        robot.kill()
        assert hub.wait(60) == 3
        err = hub_err.read_text().strip().splitlines()
        dropped = [x for x in err if "dropped" in x]
        assert any("malformed message on /rapidds/events" in x for x in dropped), err
        assert any("'paint_wall'" in x for x in dropped)
        assert any(f"/rapidds/human/{point} stamped" in x for x in dropped)
        # the robot's process is gone: its liveliness token goes with it (or, on a link that
        # did not notice, its joint states stop)
        assert err[-1].startswith(("rapidds: error: cycle 1 stopped, not recorded: the robot "
                                   "node left the link", "rapidds: error: cycle 1 stopped, not "
                                   "recorded: the robot has been silent")), err[-3:]
        first = [json.loads(x) for x in hub_out.read_text().splitlines()]
        assert [r["cycle"] for r in first] == [0]
        with RunStore.open_readonly(out / "run.sqlite") as st:
            assert [r["cycle"] for r in st.records(st.run_ids()[0])] == [0]
        _wait_text(tmp_path / "human.log", "sim-human: stop", human, timeout=30)

        robot2 = _start(["sim-robot", "painting", "--connect", ep], tmp_path / "robot2.log")
        again = subprocess.run(cli_cmd(*deploy, "--resume"), capture_output=True, text=True,
                               timeout=300, env={**os.environ})
        assert again.returncode == 0, again.stderr[-3000:]
        second = [json.loads(x) for x in again.stdout.splitlines()]
        assert [r["cycle"] for r in second] == [1]
    finally:
        _stop(*(p for p in (robot, human, robot2, hub) if p is not None))

    with RunStore.open_readonly(out / "run.sqlite") as st:
        rid = st.run_ids()[0]
        records = st.records(rid)
        assert [r["cycle"] for r in records] == [0, 1]
        for rec in records:
            arrays = st.arrays(rid, rec["cycle"])
            assert set(rec["observed"]) == set(rec["human"]) - {x for x in rec["human"]
                                                                 if x.startswith("wait:")}
            for task, d in rec["observed"].items():
                path = arrays[f"human/{task}"]
                # the left-slow person's own durations (means 6.0 / 5.0 / 6.6 s, cv 0.1), rows
                # every 0.15 s, starting and ending at rest
                assert 2.5 < d < 10.0
                assert path.shape == (int(np.ceil(d / 0.15 - 1e-9)) + 1, 4, 3)
                assert np.isfinite(path).all()
                assert np.ptp(path[:, 0], axis=0).max() > 0.1  # the left hand moved
        state0 = st.state(rid, 0)
    assert first[0]["observed"] == records[0]["observed"]
    # what the link saw beyond the deployment is stored with the cycle, as --json printed it
    assert [r["live"] for r in records] == [first[0]["live"], second[0]["live"]]
    live = second[0]["live"]
    assert set(live["robot_durations"]) == set(records[1]["robot"]) - {
        x for x in records[1]["robot"] if x.startswith("wait:")}
    for task, d in live["robot_durations"].items():  # physics: not faster than planned
        assert live["planned_robot_durations"][task] - 0.1 < d < \
            live["planned_robot_durations"][task] + 5.0
        start, end = records[1]["realised"]["timeline"][task]  # the cycle that happened
        assert end - start == pytest.approx(d)
    _second_plan_used_the_learned_model(records, state0)


def _second_plan_used_the_learned_model(records: list[dict], state0: bytes) -> None:
    """Cycle 1 planned again in this process from the model stored after cycle 0 gives cycle
    1's plan; from the prior it does not."""
    from rapidds.bridge.cell import LinkTeammate
    from rapidds.loop.model import HumanModel
    from rapidds.loop.run import AdaptiveRun
    from rapidds.worlds.registry import make_world

    world = make_world("painting")
    cfg = RunConfig(world="painting", human="live", cycles=2, population=8, generations=4,
                    samples=8, particles=2, candidates=4)
    expected = {}
    for name, prior in (("learned", HumanModel.from_bytes(state0)), ("prior", None)):
        run = AdaptiveRun(cfg, world=world, teammate=LinkTeammate(), prior=prior)
        run.next_cycle = 1
        plan = run.plan()
        expected[name] = (plan.best.schedule.human, plan.best.schedule.robot,
                          plan.best.makespan_mean)
    rec = records[1]
    learned = expected["learned"]
    assert ([str(x) for x in learned[0]], [str(x) for x in learned[1]]) == \
        (rec["human"], rec["robot"])
    assert learned[2] == pytest.approx(rec["expected"]["makespan"], rel=1e-9)
    assert expected["prior"][2] != pytest.approx(rec["expected"]["makespan"], rel=1e-6)
