"""ROS 2 on the wire without ROS (``--wire rmw-zenoh``): keys, type hashes, attachments and
liveliness tokens against the values rmw_zenoh and ROS 2 publish, and a subscriber and a
publisher built the way rmw_zenoh's design document describes (docs/design.md: key expression,
attachment layout) talking to the hub. The reference values are literals here, copied from
where they were published, not computed by rapidds."""

from __future__ import annotations

import json
import socket
import struct
import time
from typing import Any

import numpy as np
import pytest
from cli_helpers import run_main

from rapidds.bridge import rmw_zenoh, ros2
from rapidds.bridge.link import Link
from rapidds.bridge.wire import RmwZenohWire

# REP-2011 hashes as ROS 2 prints them: std_msgs/String in rmw_zenoh's docs/design.md; JointState
# and JointTrajectory in `ros2 topic info --verbose` of a ROS 2 system (a ros2_control issue);
# Float64 and Empty as several independent ROS 2 client libraries pin them.
PUBLISHED = {
    "std_msgs/msg/String":
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "sensor_msgs/msg/JointState":
        "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "trajectory_msgs/msg/JointTrajectory":
        "RIHS01_179b33eba59d676f6d967ac71fe35e7ca2f64b2f3928f4a018cec115e213796e",
    "std_msgs/msg/Float64":
        "RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a",
    "std_msgs/msg/Empty":
        "RIHS01_20b625256f32d5dbc0d04fee44f43c41e51c70d3502f84b4a08e7a9c26a96312",
}
STRING_HASH = PUBLISHED["std_msgs/msg/String"]
JOINTS_HASH = PUBLISHED["sensor_msgs/msg/JointState"]


@pytest.mark.parametrize("msgtype", sorted(PUBLISHED))
def test_type_hashes_match_the_published_values(msgtype: str) -> None:
    assert rmw_zenoh.type_hash(msgtype) == PUBLISHED[msgtype]


def test_keys_and_tokens_match_the_design_documents_examples() -> None:
    assert rmw_zenoh.data_key(0, "/chatter", "std_msgs/msg/String") == \
        f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert rmw_zenoh.data_key(0, "/robot1/chatter", "std_msgs/msg/String") == \
        f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    listener = rmw_zenoh.NodeName(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "listener")
    talker = rmw_zenoh.NodeName(2, "8b20917502ee955ac4476e0266340d5c", 0, "talker")
    assert rmw_zenoh.node_token(listener) == \
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    assert rmw_zenoh.entity_token(listener, 10, "MS", "/chatter", "std_msgs/msg/String") == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
        f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,")
    assert rmw_zenoh.entity_token(talker, 10, "MP", "/chatter", "std_msgs/msg/String",
                                  depth=7) == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,")
    assert rmw_zenoh.dds_type_name("sensor_msgs/msg/JointState") == \
        "sensor_msgs::msg::dds_::JointState_"
    with pytest.raises(ValueError, match="not a ROS 2 type name"):
        rmw_zenoh.dds_type_name("JointState")


def _design_attachment(seq: int, stamp: int, gid: bytes) -> bytes:
    """The layout of docs/design.md: int64 LE, int64 LE, one length byte (16), 16 GID bytes."""
    return struct.pack("<qqB", seq, stamp, len(gid)) + gid


def test_the_attachment_is_laid_out_as_the_design_says() -> None:
    gid = bytes(range(7, 23))
    att = rmw_zenoh.Attachment(42, 1_700_000_000_123_456_789, gid)
    assert rmw_zenoh.attachment_bytes(att) == _design_attachment(42, 1_700_000_000_123_456_789,
                                                                 gid)
    assert rmw_zenoh.parse_attachment(_design_attachment(-1, 5, gid)) == \
        rmw_zenoh.Attachment(-1, 5, gid)
    for bad in (None, b"", _design_attachment(1, 2, gid)[:-1], b"\x00" * 40,
                struct.pack("<qqB", 1, 2, 15) + gid):
        assert rmw_zenoh.parse_attachment(bad) is None


def test_the_domain_is_ros_domain_id() -> None:
    assert rmw_zenoh.domain_id({}) == 0
    assert rmw_zenoh.domain_id({"ROS_DOMAIN_ID": "42"}) == 42
    for bad in ("x", "-1", "233", "1e3"):
        with pytest.raises(rmw_zenoh.WireError, match="ROS_DOMAIN_ID"):
            rmw_zenoh.domain_id({"ROS_DOMAIN_ID": bad})


def _endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _ros2_session(ep: str) -> Any:
    """A session as rmw_zenoh opens one: a peer connecting to the router (here: the hub)."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    conf.insert_json5("connect/endpoints", json.dumps([ep]))
    return zenoh.open(conf)


def test_a_ros2_node_on_rmw_zenoh_and_the_hub_see_each_other(caplog: Any) -> None:
    ep = _endpoint()
    start = time.time_ns()
    topics = {ros2.JOINT_STATE_TOPIC: "sensor_msgs/msg/JointState",
              ros2.EVENTS_TOPIC: "std_msgs/msg/String"}
    with Link(topics, listen=ep, wire=RmwZenohWire("rapidds_hub", domain=0)) as hub:
        ros = _ros2_session(ep)
        try:
            got: list[Any] = []
            ros.declare_subscriber(f"0/rapidds/plan/std_msgs::msg::dds_::String_/{STRING_HASH}",
                                   got.append)
            deadline = time.monotonic() + 30
            while len(got) < 3 and time.monotonic() < deadline:
                hub.publish(ros2.PLAN_TOPIC, ros2.string_message({"cycle": len(got)}))
                time.sleep(0.1)
            assert len(got) >= 3
            atts = [struct.unpack("<qqB", s.attachment.to_bytes()[:17]) for s in got]
            gids = {s.attachment.to_bytes()[17:] for s in got}
            assert all(len(s.attachment.to_bytes()) == 33 for s in got)
            seqs = [a[0] for a in atts]
            assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs) and seqs[0] >= 1
            assert all(start <= a[1] <= time.time_ns() and a[2] == 16 for a in atts)
            assert len(gids) == 1 and len(next(iter(gids))) == 16  # one publisher
            msg = ros2.deserialize(got[0].payload.to_bytes(), "std_msgs/msg/String")
            assert "cycle" in json.loads(msg.data)

            hub_zid = str(next(iter(ros.info.routers_zid())))
            tokens = {str(r.ok.key_expr) for r in ros.liveliness().get("@ros2_lv/0/**")
                      if r.ok is not None}
            head = f"@ros2_lv/0/{hub_zid}/0"
            assert tokens >= {
                f"{head}/0/NN/%/%/rapidds_hub",
                f"{head}/1/MS/%/%/rapidds_hub/%rapidds%robot%joint_states/"
                f"sensor_msgs::msg::dds_::JointState_/{JOINTS_HASH}/::,10:,:,:,,",
                f"{head}/2/MS/%/%/rapidds_hub/%rapidds%events/std_msgs::msg::dds_::String_/"
                f"{STRING_HASH}/::,10:,:,:,,",
                f"{head}/3/MP/%/%/rapidds_hub/%rapidds%plan/std_msgs::msg::dds_::String_/"
                f"{STRING_HASH}/::,10:,:,:,,"}, tokens

            # the hub reads a ROS 2 publisher's joint states; one without the attachment is
            # dropped, as rmw_zenoh drops it
            key = f"0/rapidds/robot/joint_states/sensor_msgs::msg::dds_::JointState_/{JOINTS_HASH}"
            bare = ros2.serialize(ros2.joint_state(["j1"], np.array([7.0])))
            good = ros2.serialize(ros2.joint_state(["j1"], np.array([0.25])))
            for _ in range(100):
                ros.put(key, bare)
                ros.put(key, good, attachment=_design_attachment(1, time.time_ns(),
                                                                 bytes(16)))
                rec = hub.receive(0.2)
                if rec is not None:
                    break
            assert rec is not None and rec.topic == ros2.JOINT_STATE_TOPIC
            time.sleep(0.3)
            positions = {float(r.msg.position[0]) for r in [rec, *hub.drain()]}
            assert positions == {0.25}
            assert "without rmw_zenoh's attachment" in caplog.text
        finally:
            ros.close()


def test_the_cli_refuses_an_unknown_wire_or_domain(capsys: Any,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    code, _, err = run_main(capsys, "sim-robot", "painting", "--wire", "dds")
    assert code == 2 and err.strip() == ("rapidds: error: unknown --wire 'dds'; one of "
                                         "ros2dds, rmw-zenoh")
    monkeypatch.setenv("ROS_DOMAIN_ID", "300")
    code, _, err = run_main(capsys, "sim-human", "painting", "--human", "left-slow", "--wire",
                            "rmw-zenoh")
    assert code == 2 and "ROS_DOMAIN_ID='300'" in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_a_cell_on_rmw_zenohs_wire_runs_end_to_end_with_a_ros2_listener(tmp_path: Any) -> None:
    """The hub and both reference nodes on ``--wire rmw-zenoh`` run one painting cycle; a ROS 2
    style subscriber on the trajectory's rmw_zenoh key (the type hash ROS 2 prints) receives
    every trajectory the hub sends, each with its attachment."""
    import os
    import subprocess

    from cli_helpers import cli_cmd

    ep, out = _endpoint(), tmp_path / "run"
    env = {**os.environ, "RAPIDDS_LOG": "info", "ROS_DOMAIN_ID": "7"}
    wire = ["--wire", "rmw-zenoh"]
    trajectories: list[Any] = []
    hub_cmd = cli_cmd("deploy", "painting", "--listen", ep, *wire, "--cycles", "1", "--out",
                      str(out), "--json", "--time-scale", "4", "--startup-timeout", "90",
                      "--population", "8", "--generations", "4", "--samples", "8",
                      "--particles", "2", "--candidates", "4")
    with open(tmp_path / "hub.out", "wb") as o, open(tmp_path / "hub.err", "wb") as e:
        hub = subprocess.Popen(hub_cmd, stdout=o, stderr=e, env=env)
    nodes: list[subprocess.Popen[bytes]] = []
    ros = _ros2_session(ep)  # a peer, retrying until the hub listens
    try:
        ros.declare_subscriber(
            "7/rapidds/robot/trajectory/trajectory_msgs::msg::dds_::JointTrajectory_/"
            "RIHS01_179b33eba59d676f6d967ac71fe35e7ca2f64b2f3928f4a018cec115e213796e",
            trajectories.append)
        deadline = time.monotonic() + 120
        while not list(ros.info.routers_zid()):  # the listener is on before the cell starts
            assert time.monotonic() < deadline and hub.poll() is None
            time.sleep(0.2)
        for name, args in (("robot", ["sim-robot", "painting"]),
                           ("person", ["sim-human", "painting", "--human", "left-slow"])):
            with open(tmp_path / f"{name}.log", "wb") as log:
                nodes.append(subprocess.Popen(cli_cmd(*args, "--connect", ep, *wire),
                                              stdout=log, stderr=subprocess.STDOUT, env=env))
        hub.wait(400)
    finally:
        ros.close()
        for p in (*nodes, hub):
            if p.poll() is None:
                p.terminate()
        for p in (*nodes, hub):
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
    assert hub.returncode == 0, (tmp_path / "hub.err").read_text()[-3000:]
    (record,) = [json.loads(x) for x in (tmp_path / "hub.out").read_text().splitlines()]
    robot_tasks = [t for t in record["robot"] if not t.startswith("wait:")]
    assert set(record["live"]["robot_durations"]) == set(robot_tasks)
    assert len(trajectories) == len(robot_tasks)  # the listener joined before the first
    for s in trajectories:
        seq, stamp, size = struct.unpack("<qqB", s.attachment.to_bytes()[:17])
        assert size == 16 and seq >= 1 and stamp > 0
        msg = ros2.deserialize(s.payload.to_bytes(), "trajectory_msgs/msg/JointTrajectory")
        assert len(msg.points) >= 2 and list(msg.joint_names)
