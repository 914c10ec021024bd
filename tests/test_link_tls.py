"""The authenticated link (``--zenoh-config``): Zenoh's mutual TLS and access control with the
shipped example configs (examples/zenoh-cell) and certificates made here. A node with the cell's
certificate talks; a peer without one (no certificate, another CA's, plain TCP) gets no session,
so it can neither publish nor read; a node publishing or subscribing on a key its certificate
may not is filtered by the hub. A bad config file is one line and exit code 2."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_helpers import run_main
from tls_helpers import cell_folder, make_certs

from rapidds.bridge import ros2
from rapidds.bridge.link import Link, Received
from rapidds.bridge.live import STOP_TOPIC, tracking_topic
from rapidds.bridge.zenoh_config import (
    LinkConfigError,
    checked_link_config,
    load_link_config,
)

STRING = "std_msgs/msg/String"
POINT = "geometry_msgs/msg/PointStamped"
JOINTS = "sensor_msgs/msg/JointState"


def _endpoint(proto: str = "tls") -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"{proto}/127.0.0.1:{s.getsockname()[1]}"


def _until(link: Link, topic: str, send: Any, timeout: float = 30.0) -> list[Received]:
    """Call ``send`` every 0.2 s until ``link`` receives on ``topic``: what it received."""
    got: list[Received] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        send()
        rec = link.receive(0.2)
        while rec is not None:
            got.append(rec)
            if rec.topic == topic:
                time.sleep(0.3)  # anything sent before the marker has arrived by now
                return got + link.drain()
            rec = link.receive(0.0)
    raise AssertionError(f"nothing on {topic} after {timeout} s")


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return cell_folder(tmp_path_factory.mktemp("tls"))


def test_a_node_publishes_and_reads_only_the_keys_its_certificate_may(cell: Path) -> None:
    ep = _endpoint()
    point = tracking_topic("l_wrist")
    hub_topics = {ros2.JOINT_STATE_TOPIC: JOINTS, STOP_TOPIC: STRING, point: POINT,
                  ros2.PLAN_TOPIC: STRING}
    with Link(hub_topics, listen=ep, config=checked_link_config(cell / "hub.json5", "hub", ep)) \
            as hub, \
            Link({ros2.PLAN_TOPIC: STRING, ros2.TRAJECTORY_TOPIC: "trajectory_msgs/msg/"
                  "JointTrajectory"}, connect=ep,
                 config=load_link_config(cell / "tracker.json5", "node")) as tracker, \
            Link({}, connect=ep, config=load_link_config(cell / "robot.json5", "node")) as robot:
        joints = ros2.joint_state(["j1"], np.array([0.5]), np.array([0.0]), stamp_ns=1)
        got = _until(hub, ros2.JOINT_STATE_TOPIC, lambda: robot.publish(
            ros2.JOINT_STATE_TOPIC, joints))
        assert got[0].msg.position.tolist() == [0.5]  # the robot may publish its joint states

        def forge() -> None:  # the tracker's certificate may publish body points only
            tracker.publish(ros2.JOINT_STATE_TOPIC, ros2.joint_state(
                ["j1"], np.array([9.0]), np.array([0.0]), 2))
            tracker.publish(STOP_TOPIC, ros2.string_message({"cycle": 0, "reason": "forged"}))
            tracker.publish(ros2.PLAN_TOPIC, ros2.string_message({"forged": True}))
            tracker.publish(point, ros2.point_stamped((0.1, 0.2, 0.3), 5))

        got = _until(hub, point, forge)
        assert {r.topic for r in got} == {point}, [r.topic for r in got]
        # the robot's certificate may not publish a stop either
        got = _until(hub, ros2.JOINT_STATE_TOPIC, lambda: (
            robot.publish(STOP_TOPIC, ros2.string_message({"cycle": 0, "reason": "forged"})),
            robot.publish(ros2.JOINT_STATE_TOPIC, joints)))
        assert {r.topic for r in got} == {ros2.JOINT_STATE_TOPIC}

        # reading: the tracker gets the plan, never the robot's trajectory (its own forged
        # plans reached its own subscriber inside its process, not the hub: dropped here)
        tracker.drain()
        trajectory = ros2.joint_trajectory(["j1"], np.array([[0.0], [0.1]]), 0.1)
        got = _until(tracker, ros2.PLAN_TOPIC, lambda: (
            hub.publish(ros2.TRAJECTORY_TOPIC, trajectory),
            hub.publish(ros2.PLAN_TOPIC, ros2.string_message({"cycle": 0}))))
        assert {r.topic for r in got} == {ros2.PLAN_TOPIC}
        assert json.loads(got[0].msg.data) == {"cycle": 0}


def _raw_client(ep: str, tls: dict[str, Any] | None, timeout_ms: int = 2000) -> Any:
    """An attacker's session: Zenoh itself, no rapidds checks, giving up after ``timeout_ms``."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([ep]))
    conf.insert_json5("connect/timeout_ms", str(timeout_ms))
    conf.insert_json5("connect/exit_on_failure", "true")
    if tls:
        conf.insert_json5("transport/link/tls", json.dumps(tls))
    return zenoh.open(conf)


def test_a_peer_without_the_cells_certificate_gets_no_session(cell: Path,
                                                               tmp_path: Path) -> None:
    import zenoh

    ep = _endpoint()
    make_certs(tmp_path / "other", ("robot",))  # CN=robot, but another CA signed it
    ca = str(cell / "certs" / "ca.pem")
    attempts = {
        "no certificate": {"root_ca_certificate": ca},
        "another CA's certificate": {
            "root_ca_certificate": ca, "enable_mtls": True,
            "connect_certificate": str(tmp_path / "other" / "robot.pem"),
            "connect_private_key": str(tmp_path / "other" / "robot.key")}}
    with Link({}, listen=ep, config=checked_link_config(cell / "hub.json5", "hub", ep)):
        for what, tls in attempts.items():
            with pytest.raises(zenoh.ZError, match="Unable to connect"):
                _raw_client(ep, tls).close()
            print(what, "refused")
        with pytest.raises(zenoh.ZError, match="Unable to connect"):  # plain TCP to the port
            _raw_client(ep.replace("tls/", "tcp/"), None).close()
        # the cell's own robot certificate, through Zenoh alone, does get a session
        good = _raw_client(ep, {"root_ca_certificate": ca, "enable_mtls": True,
                                "connect_certificate": str(cell / "certs" / "robot.pem"),
                                "connect_private_key": str(cell / "certs" / "robot.key")},
                           timeout_ms=30000)
        assert list(good.info.routers_zid())
        good.close()


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize(("text", "role", "error"), [
    ("{transport: {link: {tls: {enable_mtls: 'yes'}}}}", "hub", "expected a boolean"),
    ("{frobnicate: 1}", "hub", "unknown field `frobnicate`"),
    ("{mode: 'peer'}", "hub", "sets 'mode'; rapidds sets"),
    ("{listen: {endpoints: ['tcp/0.0.0.0:7447']}}", "hub", "sets 'listen'"),
    ("not json5", "node", "--zenoh-config"),
    ("{transport: {link: {tls: {root_ca_certificate: 'certs/ca.pem', enable_mtls: true}}}}",
     "hub", "a hub needs transport/link/tls/listen_certificate"),
    ("{transport: {link: {tls: {root_ca_certificate: 'certs/ca.pem', connect_certificate: "
     "'certs/robot.pem', connect_private_key: 'certs/robot.key'}}}}", "node",
     "enable_mtls must be true"),
    ("{transport: {link: {tls: {root_ca_certificate: 'certs/nope.pem', connect_certificate: "
     "'certs/robot.pem', connect_private_key: 'certs/robot.key', enable_mtls: true}}}}", "node",
     "root_ca_certificate .*nope.pem: No such file"),
    ("{transport: {link: {tls: {root_ca_certificate: 'certs/ca.pem', connect_certificate: "
     "'certs/robot.key', connect_private_key: 'certs/robot.key', enable_mtls: true}}}}", "node",
     "holds no PEM CERTIFICATE"),
    ("{access_control: {enabled: true, rules: [{id: 'r', messages: ['put'], permission: "
     "'allow', key_exprs: ['a//b']}]}}", "hub",
     "Invalid Key Expr `a//b`: empty chunks are forbidden[^/]*$"),
    ("{access_control: {enabled: true, rules: [{id: 'r', messages: ['put'], permission: "
     "'allow', key_exprs: ['a']}], subjects: [{id: 's'}], policies: [{rules: ['q'], "
     "subjects: ['s']}]}}", "hub", "a policy names rule 'q'"),
    ("{access_control: {enabled: true, rules: [{id: 'r', messages: ['put'], permission: "
     "'allow', key_exprs: ['a']}], subjects: [{id: 's', cert_common_names: ['robot']}], "
     "policies: [{rules: ['r'], subjects: ['s']}]}}", "hub", "names certificate common names"),
])
def test_a_bad_config_file_is_one_clear_line(cell: Path, text: str, role: str,
                                             error: str) -> None:
    path = _write(cell / "bad.json5", text)
    with pytest.raises(LinkConfigError, match=error) as info:
        load_link_config(path, role)  # type: ignore[arg-type]
    assert "\n" not in str(info.value)


def test_the_endpoint_matches_the_config(cell: Path) -> None:
    with pytest.raises(LinkConfigError, match="must be tls/HOST:PORT"):
        checked_link_config(cell / "hub.json5", "hub", "tcp/127.0.0.1:7447")
    with pytest.raises(LinkConfigError, match="needs certificates"):
        checked_link_config(None, "node", "tls/127.0.0.1:7447")
    assert checked_link_config(None, "node", "tcp/127.0.0.1:7447") is None


def test_the_cli_answers_a_bad_config_with_exit_2(cell: Path, capsys: Any) -> None:
    big = _write(cell / "big.json5", "{}" + " " * (1 << 20))
    for args, error in (
            (["sim-human", "painting", "--human", "left-slow", "--zenoh-config",
              str(cell / "missing.json5")], "No such file"),
            (["sim-robot", "painting", "--zenoh-config", str(big)], "larger than 1024 KiB"),
            (["sim-robot", "painting", "--connect", "tls/127.0.0.1:7447"], "needs certificates"),
            (["deploy", "painting", "--out", str(cell / "run"), "--zenoh-config",
              str(cell / "hub.json5")], "must be tls/HOST:PORT")):
        code, _, err = run_main(capsys, *args)
        assert code == 2, err
        assert len(err.strip().splitlines()) == 1 and error in err, err
    assert not (cell / "run").exists()  # nothing written for a refused link


@pytest.mark.slow
def test_a_tls_and_acl_cell_runs_its_three_processes_end_to_end(cell: Path,
                                                                tmp_path: Path) -> None:
    """The hub, the MuJoCo robot and the simulated person, each with its example config and
    certificate, run one painting cycle over mutual TLS under the hub's access control."""
    import os
    import subprocess

    from cli_helpers import cli_cmd

    from rapidds.store import RunStore

    ep, out = _endpoint(), tmp_path / "run"
    env = {**os.environ, "RAPIDDS_LOG": "info"}
    nodes = []
    for name, args in (("robot", ["sim-robot", "painting"]),
                       ("tracker", ["sim-human", "painting", "--human", "left-slow"])):
        with open(tmp_path / f"{name}.log", "wb") as log:
            nodes.append(subprocess.Popen(
                cli_cmd(*args, "--connect", ep, "--zenoh-config", str(cell / f"{name}.json5")),
                stdout=log, stderr=subprocess.STDOUT, env=env))
    try:
        hub = subprocess.run(cli_cmd(
            "deploy", "painting", "--listen", ep, "--zenoh-config", str(cell / "hub.json5"),
            "--cycles", "1", "--out", str(out), "--json", "--time-scale", "4",
            "--startup-timeout", "90", "--population", "8", "--generations", "4",
            "--samples", "8", "--particles", "2", "--candidates", "4"),
            capture_output=True, text=True, timeout=400, env=env)
    finally:
        for p in nodes:
            p.terminate()
        for p in nodes:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
    assert hub.returncode == 0, hub.stderr[-3000:]
    assert "dropped" not in hub.stderr, hub.stderr[-3000:]  # the ACL let every contract key by
    (record,) = [json.loads(x) for x in hub.stdout.splitlines()]
    assert record["cycle"] == 0
    assert set(record["observed"]) == {t for t in record["human"] if not t.startswith("wait:")}
    assert all(2.5 < d < 10.0 for d in record["observed"].values())  # left-slow's durations
    assert set(record["live"]["robot_durations"]) == {
        t for t in record["robot"] if not t.startswith("wait:")}
    with RunStore.open_readonly(out / "run.sqlite") as st:
        assert [r["cycle"] for r in st.records(st.run_ids()[0])] == [0]


def test_a_hubs_file_is_no_nodes_and_the_reverse(cell: Path) -> None:
    with pytest.raises(LinkConfigError, match="a node needs transport/link/tls/connect_cert"):
        load_link_config(cell / "hub.json5", "node")
    with pytest.raises(LinkConfigError, match="a hub needs transport/link/tls/listen_cert"):
        load_link_config(cell / "robot.json5", "hub")
    hub = load_link_config(cell / "hub.json5", "hub")
    assert hub.secure and hub.acl
    assert hub.tls_files["listen_certificate"] == str((cell / "certs" / "hub.pem").resolve())


def _alive(hub: Link, name: str) -> list[str]:
    """The nodes whose tokens the hub heard join, until ``name`` is among them (then 1 s more,
    so that a token sent before it has come too)."""
    from rapidds.bridge.link import ALIVE_PREFIX

    seen: list[str] = []
    deadline = time.monotonic() + 30
    while name not in seen:
        assert time.monotonic() < deadline, seen
        rec = hub.receive(0.2)
        if rec is not None and rec.msg is True:
            seen.append(rec.topic.removeprefix(ALIVE_PREFIX).split("/")[0])
    time.sleep(1.0)
    return seen + [r.topic.removeprefix(ALIVE_PREFIX).split("/")[0] for r in hub.drain()
                   if r.msg is True]


def test_a_node_announces_only_its_own_liveliness(cell: Path) -> None:
    """The hub hears the robot's liveliness token through the access control; the tracker's
    certificate cannot pass itself off as the robot."""
    ep = _endpoint()
    hub_config = checked_link_config(cell / "hub.json5", "hub", ep)
    tracker = load_link_config(cell / "tracker.json5", "node")
    robot = load_link_config(cell / "robot.json5", "node")
    with Link({}, listen=ep, watch=True, config=hub_config) as hub, \
            Link({}, connect=ep, alive="robot", config=robot):
        assert _alive(hub, "robot") == ["robot"]
        with Link({}, connect=ep, alive="robot", config=tracker), \
                Link({}, connect=ep, alive="person", config=tracker):
            assert _alive(hub, "person") == ["person"]  # no second "robot"
