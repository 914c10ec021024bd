"""Fail safe, never silent (ISO 10218-2:2025): the live cell's safety function that cannot do
its job stops the robot and says so (exit 3, one line, nothing recorded), tried with a lab's
nodes written from README's wire contract (``contract_nodes``), not with rapidds's node classes:
a robot under franka_ros2's joint names, a body point never tracked, a driver that ignores the
speed scaling, a tracker that falls silent mid-task; and the reference robot holding when the
hub's scaling falls silent. The cell clock runs 2x the wall (``--time-scale 2``)."""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import cli_cmd
from contract_nodes import Driver, Hub, Tracker, float64, joint_trajectory, string
from test_bridge_e2e import _endpoint, _start, _stop

from rapidds.bridge.failsafe import (
    BLIND_LIMIT,
    DRIFT,
    OBEY_TOLERANCE,
    WATCHDOG,
    MonitorGuard,
    ReadyCheck,
    joint_state_fault,
)
from rapidds.bridge.link import Received
from rapidds.bridge.reactive import SpeedMonitor
from rapidds.bridge.ros2 import JOINT_STATE_TOPIC, joint_state, point_stamped
from rapidds.store import RunStore
from rapidds.worlds.base import body_point_names, joint_names
from rapidds.worlds.registry import make_world

SCALE = 2.0
# the smallest search: the plan only has to send the robot's first task (half the e2e's CPU)
SEARCH = ["--population", "2", "--generations", "1", "--samples", "2", "--particles", "1",
          "--candidates", "1"]
FR3 = [f"fr3_joint{i}" for i in range(1, 8)]


def _deploy(tmp_path: Path, ep: str, execution: str) -> tuple[subprocess.Popen[bytes], Path]:
    err = tmp_path / "hub.err"
    with open(tmp_path / "hub.out", "wb") as o, open(err, "wb") as e:
        hub = subprocess.Popen(
            cli_cmd("deploy", "painting", "--listen", ep, "--cycles", "1", "--out",
                    str(tmp_path / "run"), "--json", "--time-scale", str(SCALE), "--execution",
                    execution, "--startup-timeout", "90", *SEARCH), stdout=o, stderr=e,
            env={k: v for k, v in os.environ.items() if k != "RAPIDDS_LOG"})
    return hub, err


def _fault(hub: subprocess.Popen[bytes], err: Path, tmp_path: Path) -> str:
    """The hub exited 3 with one error line, its last, and recorded nothing; that line."""
    code = hub.wait(240)
    text = err.read_text()
    errors = [x for x in text.splitlines() if x.startswith("rapidds: error: ")]
    assert code == 3 and len(errors) == 1 and text.strip().splitlines()[-1] == errors[0], text
    assert (tmp_path / "hub.out").read_text() == ""
    db = tmp_path / "run" / "run.sqlite"
    if db.exists():
        with RunStore.open_readonly(db) as st:
            assert [r for rid in st.run_ids() for r in st.records(rid)] == []
    return errors[0]


def _cell(tmp_path: Path, execution: str, names: list[str], points: dict[str, np.ndarray], *,
          obey: bool = True, mute_on_start: bool = False) -> tuple[str, Driver]:
    """A hub and the lab's nodes until the hub exits; its error line and the driver."""
    world = make_world("painting")
    ep = _endpoint()
    hub, err = _deploy(tmp_path, ep, execution)
    driver = Driver(ep, names, np.asarray(world.robot_rest(), float), obey=obey)
    tracker = Tracker(ep, points)
    if mute_on_start:
        driver.on_start = tracker.mute.set
    try:
        driver.start()
        tracker.start()
        line = _fault(hub, err, tmp_path)
    finally:
        _stop(hub)
        driver.close()
        tracker.close()
    return line, driver


def _person(world, near_arm: bool = False) -> dict[str, np.ndarray]:  # type: ignore[no-untyped-def]
    """The person at rest, or with hands and forearms at the arm's tool at rest."""
    pose = np.asarray(world.human_rest(), float)
    if near_arm:
        tool = world.kinematics.tool(np.asarray(world.robot_rest())[None])[0]
        pose = tool + np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-0.1, -0.2, 0.0],
                                [0.1, -0.2, 0.0]])
    return dict(zip(body_point_names(world), pose, strict=True))


@pytest.mark.slow  # the hub's start and plan: 35-55 s at load 20 on 2 cores
def test_a_robot_under_franka_names_is_one_line_and_exit_3(tmp_path: Path) -> None:
    world = make_world("painting")
    line, _ = _cell(tmp_path, "planned", FR3, _person(world))
    assert line.startswith("rapidds: error: cycle 0 not started, nothing recorded: the robot's "
                           "joint states carry 7 joint(s) (fr3_joint1, "), line
    assert "robot profile 'reference' (--robot) expects 7 (robot:panda0_joint1, " in line


def test_franka_names_with_fingers_are_the_fr3_profiles_robot() -> None:
    from rapidds.bridge.profiles import robot_profile

    fr3 = robot_profile("franka-fr3")
    world = make_world("painting")
    names = [*FR3, "fr3_finger_joint1", "fr3_finger_joint2"]  # as franka_ros2 publishes them
    check = ReadyCheck(fr3.joint_names(world), ("p",), fr3.fingers)
    check.see(Received(JOINT_STATE_TOPIC, joint_state(names, np.zeros(9)), 0))
    check.see(Received("/rapidds/human/p", point_stamped((0.0, 0.0, 0.0), 1), 0))
    assert check.ready and check.result() is None
    wrong = ReadyCheck(fr3.joint_names(world), ("p",), fr3.fingers)
    wrong.see(Received(JOINT_STATE_TOPIC, joint_state(names[:6] + names[7:], np.zeros(8)), 0))
    assert "expects 7 (fr3_joint1, " in wrong.result()


@pytest.mark.slow  # the hub's start and plan: 35-55 s at load 20 on 2 cores
def test_an_untracked_body_point_is_one_line_and_exit_3(tmp_path: Path) -> None:
    world = make_world("painting")
    points = _person(world)
    del points["r_elbow"]
    line, _ = _cell(tmp_path, "planned", list(joint_names(world)), points)
    assert "body point(s) r_elbow not tracked" in line, line
    assert "l_wrist, r_wrist, l_elbow, r_elbow" in line


@pytest.mark.slow  # the hub's start and plan: 35-55 s at load 20 on 2 cores
def test_a_driver_that_ignores_the_scaling_gets_a_protective_stop(tmp_path: Path) -> None:
    """The person stands at the arm: the monitor holds it (scaling 0); a driver that runs its
    planned timing anyway is stopped on /rapidds/stop and the cycle faults."""
    world = make_world("painting")
    line, driver = _cell(tmp_path, "reactive", list(joint_names(world)),
                         _person(world, near_arm=True), obey=False)
    assert "the robot does not obey the speed scaling" in line, line
    assert "while held" in line and "after the scaling went to 0" in line
    assert driver.started.is_set() and 0.0 in driver.scalings
    assert [s["cycle"] for s in driver.stops] == [0]
    assert "speed scaling" in driver.stops[0]["reason"]


@pytest.mark.slow  # the hub's start and plan: 35-55 s at load 20 on 2 cores
def test_a_tracker_that_falls_silent_holds_the_robot_then_faults(tmp_path: Path) -> None:
    world = make_world("painting")
    line, driver = _cell(tmp_path, "reactive", list(joint_names(world)), _person(world),
                         mute_on_start=True)
    assert "could not compute the separation" in line, line
    assert "the person's tracking is" in line
    assert driver.scalings and driver.scalings[-1] == 0.0  # held when the fault came
    assert [s["cycle"] for s in driver.stops] == [0]


def test_the_reference_robot_holds_when_the_scaling_falls_silent(tmp_path: Path) -> None:
    """A hub from the contract drives ``rapidds sim-robot``: scaling 1 for a while, then none;
    the arm holds on its path (its task does not end) and resumes when scaling comes again."""
    world = make_world("painting")
    names = list(joint_names(world))
    rest = np.asarray(world.robot_rest(), float)
    ep = _endpoint()
    hub = Hub(ep)
    robot = _start(["sim-robot", "painting", "--connect", ep], tmp_path / "robot.log")
    try:
        _until(lambda: len(hub.states) > 10, 120, robot)
        time.sleep(0.3)  # its subscriptions reach this hub
        t0 = time.time_ns()
        hub.put("rapidds/plan", string(json.dumps({
            "cycle": 0, "order": {"human": [], "robot": ["reach"]}, "after": {"reach": []},
            "stamp_ns": t0, "time_scale": SCALE, "dt": 0.15})))
        time.sleep(0.2)
        goal = rest + np.array([0.6, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        rows = rest + np.linspace(0.0, 1.0, 21)[:, None] * (goal - rest)  # 3 cell s
        hub.put("rapidds/robot/trajectory", joint_trajectory(names, rows, 0.15))
        _scaling_for(hub, 0.4)  # 0.8 cell s of the 3 at full speed, then silence
        silent = time.monotonic()
        time.sleep(WATCHDOG / SCALE + 0.3)  # the watchdog and the arm's stop
        held_from = time.time_ns()
        time.sleep(1.6)  # the trajectory would have ended by now
        held = [q for ns, q in hub.states if ns >= held_from]
        assert len(held) > 20
        moved = np.abs(np.stack(held) - held[0]).max()
        assert moved < 0.005, moved  # held where it was
        assert 0.05 < held[0][0] - rest[0] < 0.55  # on its path, not at either end
        assert not [e for e in hub.events if e["event"] == "end"]
        assert "no speed scaling" in (tmp_path / "robot.log").read_text()
        assert time.monotonic() - silent > 1.5
        deadline = time.monotonic() + 30
        while not [e for e in hub.events if e["event"] == "end"]:  # scaling again: resumes
            assert time.monotonic() < deadline, hub.events
            _scaling_for(hub, 0.2)
        assert abs(hub.states[-1][1][0] - goal[0]) < 0.02
    finally:
        _stop(robot)
        hub.close()


def _scaling_for(hub: Hub, seconds: float) -> None:
    """Scaling 1 at the monitor's 20 Hz of the cell clock for ``seconds`` wall s."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        hub.put("rapidds/robot/speed_scaling", float64(1.0))
        time.sleep(0.05 / SCALE)


def _until(cond, timeout: float, proc: subprocess.Popen[bytes]) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not cond():
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)


# --- the checks themselves, in-process ---------------------------------------------------

def test_a_joint_state_is_the_profiles_robot_or_a_fault() -> None:
    joints = ("a", "b")
    assert joint_state_fault(["b", "a"], [0.0, 1.0], joints) is None  # any order
    assert "carry 3 joint(s) (a, b, c)" in joint_state_fault(["a", "b", "c"], [0] * 3, joints)
    assert "expects 2 (a, b)" in joint_state_fault(["a"], [0.0], joints)
    assert "with 1 position(s)" in joint_state_fault(["a", "b"], [0.0], joints)
    assert "not finite" in joint_state_fault(["a", "b"], [0.0, np.nan], joints)
    fingers = ("f1", "f2")  # a profile's gripper joints may come along, nothing else
    assert joint_state_fault(["a", "b", "f1", "f2"], [0.0] * 4, joints, fingers) is None
    assert "may carry f1, f2" in joint_state_fault(["a", "b", "c"], [0.0] * 3, joints, fingers)


def test_the_ready_check_waits_then_names_what_is_missing() -> None:
    check = ReadyCheck(("a", "b"), ("p", "q"), window=1.0)
    check.see(Received(JOINT_STATE_TOPIC, joint_state(["a", "b"], np.zeros(2)), 0))
    assert check.robot and not check.ready and check.result() is None  # no tracking yet
    check.see(Received("/rapidds/human/p", point_stamped((0.0, 0.0, 0.0), 1), 0))
    assert check.result() is None  # q may still come
    assert "body point(s) q not tracked" in check.result(time.monotonic() + 1.5)
    check.see(Received("/rapidds/human/q", point_stamped((0.0, 0.0, 0.0), 1), 0))
    assert check.ready and check.result(time.monotonic() + 1.5) is None
    check.see(Received(JOINT_STATE_TOPIC, joint_state(["x", "b"], np.zeros(2)), 0))
    assert "carry 2 joint(s) (x, b)" in check.result()


def _guarded(world):  # type: ignore[no-untyped-def]
    monitor = SpeedMonitor(world, {"t": 0.5}, period=0.05)
    guard = MonitorGuard({"t": np.full(7, 1.0)}, monitor.limits.stopping_time)
    return monitor, guard


def _at_the_arm(world, q: np.ndarray, t: float) -> tuple[np.ndarray, float, float]:  # type: ignore[no-untyped-def]
    """A person standing still on the arm's points (held, wherever the arm goes), sampled at t."""
    return world.robot_points(q[None])[0][:4], 0.0, t


def test_a_robot_moving_under_scaling_0_faults_past_t_s_and_the_tolerance() -> None:
    world = make_world("painting")
    monitor, guard = _guarded(world)
    rest = np.asarray(world.robot_rest(), float)
    settle = monitor.limits.stopping_time + OBEY_TOLERANCE
    faults = []
    for k in range(40):
        t = k * 0.05
        q = rest + 0.6 * t  # 0.6 rad/s on every joint, whatever it is told
        monitor.joint_state(q, t)
        monitor.tick(t, _at_the_arm(world, q, t), "t")
        assert monitor.rate == 0.0
        faults.append(guard.check(t, monitor, "t"))
    first = next(k for k, f in enumerate(faults) if f is not None)
    # held from 0: it may move until T_s + tolerance, then DRIFT more (0.17 s at 0.6 rad/s)
    assert settle + DRIFT / 0.6 < first * 0.05 <= settle + DRIFT / 0.6 + 0.06, first
    assert "moved 0.120 (at 0.600/s) while held, 0.70 s after" in faults[first]


def test_a_held_robot_that_stops_in_time_or_is_pushed_a_little_is_no_fault() -> None:
    world = make_world("painting")
    monitor, guard = _guarded(world)
    rest = np.asarray(world.robot_rest(), float)
    for k in range(60):
        t = k * 0.05
        q = rest + 0.5 * min(t, 0.15) + 0.05 * np.sin(7 * t)  # stops 0.15 s after, leaned on
        monitor.joint_state(q, t)
        monitor.tick(t, _at_the_arm(world, q, t), "t")
        assert monitor.rate == 0.0 and guard.check(t, monitor, "t") is None


def test_a_blind_monitor_holds_then_faults_past_its_limit() -> None:
    world = make_world("painting")
    monitor, guard = _guarded(world)
    rest = np.asarray(world.robot_rest(), float)
    out = []
    for k in range(40):
        t = k * 0.05
        monitor.joint_state(rest, t)
        rate = monitor.tick(t, None, "t")  # the person not tracked
        out.append((rate, guard.check(t, monitor, "t")))
    assert all(rate == 0.0 for rate, _ in out)
    first = next(k for k, (_, f) in enumerate(out) if f is not None)
    assert BLIND_LIMIT < first * 0.05 <= BLIND_LIMIT + 0.06
    assert "not all tracked" in out[first][1]
    assert monitor.trace == [] and "watched none" in guard.unwatched(monitor)
    idle = _guarded(world)
    assert idle[1].unwatched(idle[0]) is None  # no robot task ran: nothing to watch


def test_the_reference_robot_holds_on_a_silent_scaling() -> None:
    from rapidds.bridge.nodes.sim_robot import SimRobot

    class _Quiet:
        def publish(self, topic: str, msg: object) -> None:
            pass

    robot = SimRobot(make_world("painting"), _Quiet())  # type: ignore[arg-type]
    robot._current = "t"
    robot._watchdog()
    assert robot.arm.speed == 1.0  # never scaled in this cycle: a hub that does not monitor
    robot._scaled_at = time.monotonic()
    robot._watchdog()
    assert robot.arm.speed == 1.0
    robot._scaled_at = time.monotonic() - 2 * WATCHDOG
    robot._watchdog()
    assert robot.arm.speed == 0.0
