"""The live link's parts, each on its own: the Zenoh link on localhost, the plan the nodes read,
the hub's gate on bad input, the person's paths rebuilt from tracking, the arm under physics."""

from __future__ import annotations

import json
import logging
import socket
import time
from collections import defaultdict
from collections.abc import Callable

import numpy as np
import pytest
from cli_helpers import run_main

from rapidds.bridge import ros2
from rapidds.bridge.link import Link, LinkError, Received
from rapidds.bridge.live import (
    TRACKING_PREFIX,
    CycleObservation,
    LivePlan,
    live_plan_payload,
    tracking_topic,
)
from rapidds.schedule import Wait
from rapidds.worlds.base import body_point_names, joint_names
from rapidds.worlds.registry import make_world

TRAJ = "trajectory_msgs/msg/JointTrajectory"


@pytest.fixture(scope="module")
def painting():  # type: ignore[no-untyped-def]
    return make_world("painting")


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def wait_for(link: Link, topic: str, timeout: float = 10.0) -> Received:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        rec = link.receive(0.1)
        if rec is not None and rec.topic == topic:
            return rec
    raise AssertionError(f"nothing on {topic} within {timeout} s")


def collect(link: Link, done: Callable[[dict[str, list[Received]]], bool],
            timeout: float = 60.0) -> dict[str, list[Received]]:
    """What ``link`` receives, by topic, until ``done`` says it is all there (the deadline only
    ends a test that would fail anyway: nothing here depends on how fast the machine is)."""
    got: dict[str, list[Received]] = defaultdict(list)
    deadline = time.monotonic() + timeout
    while not done(got) and time.monotonic() < deadline:
        rec = link.receive(0.1)
        if rec is not None:
            got[rec.topic].append(rec)
    return got


def test_a_node_and_the_hub_exchange_cdr_and_malformed_bytes_are_dropped(caplog) -> None:
    ep = free_endpoint()
    topics = {ros2.TRAJECTORY_TOPIC: TRAJ}
    with Link(topics, listen=ep) as hub, Link({}, connect=ep) as node:
        q = np.linspace(-1, 1, 14).reshape(2, 7)
        caplog.set_level(logging.WARNING, logger="rapidds.bridge")
        deadline = time.monotonic() + 10
        rec = None
        while rec is None and time.monotonic() < deadline:  # until the subscription is known
            node.publish_raw(ros2.TRAJECTORY_TOPIC, b"\x00\x01garbage")
            node.publish(ros2.TRAJECTORY_TOPIC, ros2.joint_trajectory(
                [f"j{i}" for i in range(7)], q, 0.15))
            rec = hub.receive(0.3)
        assert rec is not None and rec.topic == ros2.TRAJECTORY_TOPIC
        names, pos, t = ros2.trajectory_positions(rec.msg)
        assert names == [f"j{i}" for i in range(7)]
        np.testing.assert_array_equal(pos, q)
        np.testing.assert_allclose(t, [0.0, 0.15])
    dropped = [r.getMessage() for r in caplog.records if "malformed" in r.getMessage()]
    assert dropped and all("\n" not in m for m in dropped)


def test_bad_endpoints_are_refused_in_one_line() -> None:
    for bad in ("127.0.0.1:7447", "tcp/127.0.0.1", "tcp/127.0.0.1:99999", "tcp/a b:1"):
        with pytest.raises(LinkError, match="bad endpoint"):
            Link({}, listen=bad)


def _plan(problem, **kw):
    payload = live_plan_payload(problem, 3, ["prep_vise", "secure_piece", "brush"],
                                ["mix_l", Wait("secure_piece"), "mix_r"],
                                {"prep_vise": (0.0, 6.0)}, start_ns=10**18, time_scale=4.0,
                                dt=0.15, **kw)
    return payload, LivePlan.parse(ros2.string_message(payload).data)


def test_the_live_plan_names_every_prerequisite(painting) -> None:
    problem = painting.problem()
    payload, plan = _plan(problem)
    assert payload["order"] == {"human": ["prep_vise", "secure_piece", "brush"],
                                "robot": ["mix_l", "mix_r"]}
    # brush: precedence (secure piece, both mixes) and the person's previous task
    assert set(plan.after["brush"]) == {"secure_piece", "mix_l", "mix_r"}
    # mix_r: the robot's previous task and its wait for secure_piece
    assert set(plan.after["mix_r"]) == {"mix_l", "secure_piece"}
    assert plan.after["prep_vise"] == [] and plan.agent["mix_l"] == "robot"
    assert plan.cell_seconds(plan.wall_ns(2.5)) == pytest.approx(2.5)
    for bad in ("{}", "nope", '{"cycle": 1, "order": {"human": [], "robot": []}, "after": '
                '{"x": []}, "stamp_ns": 0, "time_scale": 1, "dt": 0.1}'):
        with pytest.raises(ros2.MessageError):
            LivePlan.parse(bad)


def _event(plan: LivePlan, task: str, agent: str, kind: str, at: float) -> Received:
    return Received(ros2.EVENTS_TOPIC,
                    ros2.event_message(ros2.Event(task, agent, kind)),  # type: ignore[arg-type]
                    plan.wall_ns(at))


def _point(plan: LivePlan, name: str, pos, at: float) -> Received:
    return Received(tracking_topic(name), ros2.point_stamped(pos, plan.wall_ns(at)),
                    plan.wall_ns(at))


def test_the_hub_drops_unknown_tasks_wrong_agents_and_events_out_of_order(painting,
                                                                          caplog) -> None:
    _, plan = _plan(painting.problem())
    obs = CycleObservation(plan, ("a",))
    caplog.set_level(logging.WARNING, logger="rapidds.bridge")
    bad = [_event(plan, "paint_wall", "human", "start", 0.1),   # not in the plan
           _event(plan, "mix_l", "human", "start", 0.1),        # the robot's task
           _event(plan, "prep_vise", "human", "end", 0.2),      # ends before it starts
           Received(ros2.EVENTS_TOPIC, ros2.string_message({"task": 1}), plan.wall_ns(0.3))]
    for rec in bad:
        obs.handle(rec)
    assert obs.start == {} and obs.end == {}
    obs.handle(_event(plan, "prep_vise", "human", "start", 1.0))
    obs.handle(_event(plan, "prep_vise", "human", "start", 1.5))  # a second start
    obs.handle(_event(plan, "prep_vise", "human", "end", 7.0))
    assert obs.durations("human") == {"prep_vise": pytest.approx(6.0)}
    assert len([r for r in caplog.records if r.name == "rapidds.bridge"]) == len(bad) + 1
    # a stamped event is timed by its stamp, not by its arrival (here 4 s later); an end
    # stamped before its start is dropped
    for kind, at in (("start", 7.0), ("end", 6.5), ("end", 9.5)):
        obs.handle(Received(ros2.EVENTS_TOPIC, ros2.event_message(ros2.Event(
            "secure_piece", "human", kind, plan.wall_ns(at))), plan.wall_ns(at + 4.0)))  # type: ignore[arg-type]
    assert obs.durations("human")["secure_piece"] == pytest.approx(2.5)
    assert "stamped before its start" in caplog.records[-1].getMessage()
    obs.handle(_point(plan, "a", (0, 0, 0), 2.0))
    obs.handle(_point(plan, "a", (9, 9, 9), 1.0))  # older than the last sample: dropped
    obs.handle(_point(plan, "zz", (9, 9, 9), 3.0))  # no such body point
    assert "stamped" in caplog.records[-2].getMessage()
    assert len(obs._tracks["a"]) == 1
    # the hub's gate outlives a cycle: a sample from before the last one is no next cycle's first
    after = CycleObservation(plan, ("a",), gate=obs.gate)
    after.handle(_point(plan, "a", (9, 9, 9), 1.5))
    assert "a" not in after._tracks and "stamped" in caplog.records[-1].getMessage()


def test_the_persons_path_is_rebuilt_from_tracking(painting) -> None:
    _, plan = _plan(painting.problem())
    person = painting.teammate("left-slow")
    d, path = person.perform("secure_piece", np.random.default_rng(0))
    names = ("left_hand", "right_hand", "left_elbow", "right_elbow")
    obs = CycleObservation(plan, names)
    start = 2.0
    obs.handle(_event(plan, "prep_vise", "human", "start", 0.0))
    obs.handle(_event(plan, "prep_vise", "human", "end", start))
    obs.handle(_event(plan, "secure_piece", "human", "start", start))
    for k, row in enumerate(path):  # a tracker at the path's own rows
        for name, p in zip(names, row, strict=True):
            obs.handle(_point(plan, name, p, start + min(k * 0.15, d)))
    obs.handle(_event(plan, "secure_piece", "human", "end", start + d))
    # the hub reads on until every body point is tracked up to the person's last end
    assert obs.tracked_past(start + d) and not obs.tracked_past(start + d + 0.01)
    ex = obs.human_executions(0.15)
    assert ex["secure_piece"].duration == pytest.approx(d)
    np.testing.assert_allclose(ex["secure_piece"].trajectory, path, atol=1e-6)
    with pytest.raises(ros2.MessageError, match="no tracking"):  # prep_vise was not tracked
        obs._task_tracks("prep_vise", 1.0, 0.15)


def test_the_arm_tracks_a_painting_motion_under_physics_and_feels_a_hand(painting) -> None:
    from rapidds.bridge.nodes.arm import PhysicsArm

    arm = PhysicsArm(painting.physics_model(), joint_names(painting))
    traj = painting.robot_trajectory("mix_l")
    arm.reset(traj[0])
    times = np.arange(len(traj)) * painting.dt
    arm.follow(traj, times)
    worst = 0.0
    while not arm.settled():
        arm.step(0.01)
        worst = max(worst, arm.tracking_error())
    assert arm.time >= times[-1]
    assert arm.time < times[-1] + arm.settle_max  # came to rest, not timed out
    np.testing.assert_allclose(arm.q, traj[-1], atol=arm.tolerance)
    assert 0.0 < worst < 0.5
    assert arm.touches() == []
    # the person's left hand where the tool is: a touch on the arm is reported
    tool = painting.kinematics.tool(arm.q[None])[0]
    rest = painting.human_rest().copy()
    rest[0] = tool
    painting.place_person(arm.model, arm.data, rest)
    arm.step(0.01)
    touches = arm.touches()
    assert touches and {t.person for t in touches} == {"left_hand"}
    assert all(t.robot.startswith("panda0") for t in touches)


@pytest.mark.parametrize("task", ["mix_l", "brush"])
def test_under_physics_the_arm_does_its_task_when_the_kinematic_robot_does(painting,
                                                                            task) -> None:
    """The physics scene's hand is the one the kinematic world plans for: its fingers no longer
    rest on the table short of the paint (the stretched kitchen-model fingers did)."""
    from rapidds.bridge.nodes.arm import PhysicsArm

    model = painting.physics_model()
    traj = painting.robot_trajectory(task, "direct")
    kin = float(painting.completion_time(task, traj[None])[0])
    q = traj[:int(np.ceil(kin / painting.dt - 1e-9)) + 1]
    arm = PhysicsArm(model, joint_names(painting))
    arm.reset(q[0])
    painting.place_person(model, arm.data, painting.human_rest())
    arm.follow(q, np.arange(len(q)) * painting.dt)
    rows = [arm.q]
    while not arm.settled():
        arm.step(painting.dt)
        rows.append(arm.q)
    done = np.concatenate([rows, np.repeat(rows[-1:], painting.horizon, 0)])[:painting.horizon]
    assert painting.completion_time(task, done[None])[0] == pytest.approx(kin)


def test_tracking_topics_follow_the_contract() -> None:
    assert tracking_topic("left_hand") == TRACKING_PREFIX + "left_hand"
    assert ros2.zenoh_key(tracking_topic("left_hand")) == "rapidds/human/left_hand"


@pytest.mark.parametrize("args, says", [
    (["deploy", "painting", "--bridge", "ros", "--out", "x"], "--bridge"),
    (["deploy", "painting", "--listen", "7447", "--out", "x"], "bad endpoint"),
    (["deploy", "painting", "--time-scale", "0", "--out", "x"], "--time-scale"),
    (["sim-human", "painting", "--human", "nobody"], "unknown human"),
    (["sim-robot", "fetch", "--connect", "tcp/127.0.0.1:1"], "does not declare the physics"),
])
def test_bad_input_is_one_line_and_exit_2(capsys, args, says) -> None:
    code, _, err = run_main(capsys, *args)
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("rapidds: error:") and says in err


def test_sim_robot_runs_a_trajectory_announces_it_and_reports_a_touch(painting) -> None:
    from rapidds.bridge.live import CONTACTS_TOPIC
    from rapidds.bridge.nodes.sim_robot import SimRobot

    ep = free_endpoint()
    string = "std_msgs/msg/String"
    topics = {ros2.EVENTS_TOPIC: string, CONTACTS_TOPIC: string,
              ros2.JOINT_STATE_TOPIC: "sensor_msgs/msg/JointState"}
    with Link(topics, listen=ep) as hub, \
            Link(SimRobot.topics(body_point_names(painting)), connect=ep) as link:
        robot = SimRobot(painting, link)
        while hub.receive(0.05) is None:  # until the hub hears the robot
            robot.tick()
        payload, _ = _plan(painting.problem())
        now = time.time_ns()
        payload["stamp_ns"] = now
        robot.handle(Received(ros2.PLAN_TOPIC, ros2.string_message(payload), now))
        rest = np.asarray(painting.robot_rest())
        bad = ros2.joint_trajectory([f"j{i}" for i in range(7)], np.stack([rest, rest]), 0.15)
        robot.handle(Received(ros2.TRAJECTORY_TOPIC, bad, now))  # unknown joints: dropped
        traj = ros2.joint_trajectory(joint_names(painting), np.stack([rest, rest]), 0.15,
                                     stamp_ns=now)
        robot.handle(Received(ros2.TRAJECTORY_TOPIC, traj, now))
        for _ in range(100):
            robot.tick()
        # the person's left hand on the tool: a touch is reported once
        body = painting.human_rest().copy()
        body[0] = painting.kinematics.tool(rest[None])[0]
        for k, name in enumerate(body_point_names(painting)):
            robot.handle(Received(tracking_topic(name), ros2.point_stamped(body[k], now), now))
        for _ in range(5):
            robot.tick()
        # messages on different keys may arrive in any order: collect until the robot's two
        # events and a touch are in (or a generous deadline passes; the asserts then say what)
        seen = collect(hub, lambda got: len(got[ros2.EVENTS_TOPIC]) >= 2
                       and len(got[CONTACTS_TOPIC]) >= 1)
    events = [ros2.parse_event(r.msg.data) for r in seen[ros2.EVENTS_TOPIC]]
    # the plan's first robot task is mix_l: the first (good) trajectory is it
    assert [(e.task, e.agent, e.event) for e in events] == [("mix_l", "robot", "start"),
                                                            ("mix_l", "robot", "end")]
    # stamped on the simulated clock (time scale 4): the 0.15 s motion settled in the first
    # control period (0.01 s) after its end
    took = (events[1].stamp_ns - events[0].stamp_ns) * 4.0 / 1e9  # type: ignore[operator]
    assert 0.15 - 1e-6 <= took <= 0.16 + 1e-6
    touches = [json.loads(r.msg.data) for r in seen[CONTACTS_TOPIC]]
    assert touches and touches[0]["person"] == "left_hand"


def test_sim_human_waits_for_the_plans_prerequisites_and_is_tracked(painting) -> None:
    from rapidds.bridge.nodes.sim_human import SimHuman

    ep = free_endpoint()
    string = "std_msgs/msg/String"
    names = body_point_names(painting)
    topics = {ros2.EVENTS_TOPIC: string,
              **{tracking_topic(n): "geometry_msgs/msg/PointStamped" for n in names}}
    with Link(topics, listen=ep) as hub, Link(SimHuman.topics(), connect=ep) as link:
        human = SimHuman(painting, painting.teammate("left-slow"), link, seed=3)
        payload = live_plan_payload(painting.problem(), 0, ["prep_vise", "secure_piece", "brush"],
                                    ["mix_l", "mix_r"], {}, start_ns=time.time_ns(),
                                    time_scale=50.0, dt=0.15)
        human.handle(Received(ros2.PLAN_TOPIC, ros2.string_message(payload), 0))

        def run_until(done, limit: float = 10.0) -> None:
            deadline = time.monotonic() + limit
            while not done() and time.monotonic() < deadline:
                time.sleep(human.tick())

        run_until(lambda: "secure_piece" in human._ended)
        for _ in range(20):  # brush waits for both mixes, however long
            time.sleep(human.tick())
        assert human._doing is None and human._next == 2
        for task in ("mix_l", "mix_r"):
            human.handle(Received(ros2.EVENTS_TOPIC, ros2.event_message(
                ros2.Event(task, "robot", "end")), 0))
        run_until(lambda: "brush" in human._ended)
        # the person's own draws from (seed, cycle): the tracker sent every row of each path
        rng = np.random.default_rng([3, 0])
        person = painting.teammate("left-slow")
        drawn = [person.perform(t, rng) for t in ("prep_vise", "secure_piece", "brush")]
        durations, paths = [d for d, _ in drawn], [p for _, p in drawn]
        rows = np.concatenate([p[:, 0] for p in paths])  # the left wrist's rows, in order

        def left(got: dict[str, list[Received]]) -> np.ndarray:
            return np.array([[r.msg.point.x, r.msg.point.y, r.msg.point.z]
                             for r in got[tracking_topic(names[0])]]).reshape(-1, 3)

        def arrived(got: dict[str, list[Received]]) -> bool:  # all six events, every row
            return len(got[ros2.EVENTS_TOPIC]) >= 6 and all(
                np.isclose(left(got), row, atol=1e-12).all(axis=1).any() for row in rows)

        got = collect(hub, arrived)
    events = [ros2.parse_event(r.msg.data) for r in got[ros2.EVENTS_TOPIC]]
    assert [(e.task, e.event) for e in events] == [
        (t, k) for t in ("prep_vise", "secure_piece", "brush") for k in ("start", "end")]
    # the stamps give the person's own durations, whatever the machine's load
    took = [(b.stamp_ns - a.stamp_ns) * 50.0 / 1e9  # type: ignore[operator]
            for a, b in zip(events[::2], events[1::2], strict=True)]
    np.testing.assert_allclose(took, durations, atol=1e-6)
    seen = left(got)
    for row in rows:  # every row of the left wrist's paths was published
        assert np.isclose(seen, row, atol=1e-12).all(axis=1).any()
