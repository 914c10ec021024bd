"""Inputs a lab already has: a ROS4HRI skeleton on TF (frames relative to their parents),
ROS 1 bags, task boundaries from the cell's own signals, franka_ros2 joint names and
end-effector demonstrations in CSV. Expected values are computed here independently: TF chains
composed with 4 x 4 matrices built from axis-angle by hand, forward kinematics by MuJoCo."""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from cli_helpers import run_main

from rapidds.bridge import ros2
from rapidds.bridge.bag import BagMessage, write_bag
from rapidds.bridge.recorded import TrackingMapping, load_mapping, read_cycle
from rapidds.errors import ConfigError, RapiddsError
from rapidds.store import RunStore, cycle_paths
from rapidds.worlds.registry import make_world

S = 1_000_000_000
LATENCY = 4_000_000  # receive time - stamp, ns
SMALL = {"world": "painting", "cycles": 2, "population": 4, "generations": 2, "samples": 8,
         "particles": 2, "candidates": 2}
T = ros2.typestore().types


# -- transforms by hand ---------------------------------------------------------------------

def _axis_angle(axis: tuple[float, float, float], angle: float) -> np.ndarray:
    """Rotation matrix by Rodrigues' formula."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _quat(axis: tuple[float, float, float], angle: float) -> tuple[float, ...]:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    return (*(a * math.sin(angle / 2)), math.cos(angle / 2))


Link = tuple[str, str, bool, Callable[[float], tuple[tuple[float, ...], tuple[float, ...],
                                                    float]]]


def _skeleton(body: str, phase: float = 0.0) -> list[Link]:
    """(parent, child, static, t -> (translation, axis, angle)) of a ROS4HRI-like skeleton:
    a camera fixed in the room, the body moving in the camera's view, shoulders and elbows
    turning, wrists fixed to the elbows (robot_state_publisher puts fixed joints on
    /tf_static)."""
    def arm(side: float) -> list[Link]:
        s = "l" if side > 0 else "r"
        return [
            (f"torso_{body}", f"{s}_shoulder_{body}", False,
             lambda t: ((0.0, 0.18 * side, 0.0), (1.0, 0.0, 0.0),
                        0.4 * side * math.sin(t + phase))),
            (f"{s}_shoulder_{body}", f"{s}_elbow_{body}", False,
             lambda t: ((0.0, 0.0, -0.3), (0.0, 1.0, 0.0),
                        0.5 + 0.3 * math.sin(1.3 * t + side))),
            (f"{s}_elbow_{body}", f"{s}_wrist_{body}", True,
             lambda t: ((0.0, 0.0, -0.25), (0.0, 0.0, 1.0), 0.0)),
        ]
    return [
        ("room", "camera", True, lambda t: ((1.0, -0.5, 1.8), (0.3, 0.2, 0.9), 0.7)),
        ("camera", f"body_{body}", False,
         lambda t: ((0.2 + 0.1 * t + phase, 0.3, 1.5 - 0.05 * t), (0.0, 0.0, 1.0), 0.3 * t)),
        (f"body_{body}", f"torso_{body}", True, lambda t: ((0.0, 0.0, 0.6), (0.0, 0.0, 1.0), 0)),
        (f"torso_{body}", f"head_{body}", True, lambda t: ((0.0, 0.0, 0.3), (0.0, 0.0, 1.0), 0)),
        *arm(1.0), *arm(-1.0),
    ]


def _truth(links: list[Link], frame: str, root: str, t: float) -> np.ndarray:
    """The origin of ``frame`` in ``root`` at time t: 4 x 4 matrices multiplied root-first."""
    parent = {child: (p, f) for p, child, _, f in links}
    chain = []
    while frame != root:
        p, f = parent[frame]
        trans, axis, angle = f(t)
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = _axis_angle(axis, angle), trans  # type: ignore[arg-type]
        chain.append(m)
        frame = p
    total = np.eye(4)
    for m in reversed(chain):
        total = total @ m
    return total[:3, 3]


def _tf(links: list[Link], stamp: int, static: bool) -> Any:
    out = []
    for parent, child, is_static, f in links:
        if is_static != static:
            continue
        (x, y, z), axis, angle = f(stamp / S)
        qx, qy, qz, qw = _quat(axis, angle)
        out.append(T["geometry_msgs/msg/TransformStamped"](
            header=ros2.header(stamp, parent), child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                rotation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))))
    return T["tf2_msgs/msg/TFMessage"](transforms=out)


def _bool(value: bool) -> Any:
    return T["std_msgs/msg/Bool"](data=value)


# the mapping: ROS4HRI frames of the first tracked body, composed to "room", then into the
# painting world (turned 90 degrees about z and shifted so that the arms move inside the
# world's workspace, as a person at the cell's table does: the plausibility check drops
# samples outside it)
_TURN = {"translation": [-0.3, -1.2, -2.95], "rotation": [0.0, 0.0, math.sqrt(0.5),
                                                          math.sqrt(0.5)]}
_TASKS = {"prep_vise": (1.0, 3.0), "secure_piece": (3.5, 5.2), "brush": (5.8, 8.0)}
_POINTS = {"l_wrist_{body}": "l_wrist", "r_wrist_{body}": "r_wrist",
           "l_elbow_{body}": "l_elbow", "r_elbow_{body}": "r_elbow"}


def _mapping_yaml(ordered: bool = True) -> dict[str, Any]:
    """The pedal's presses start and end the person's tasks: in the order given, or (not
    ``ordered``) in the cycle's plan's order."""
    return {"points": _POINTS, "root_frame": "room", "transform": _TURN,
            "boundaries": {"order": {"human": list(_TASKS)} if ordered else {},
                           "rules": [{"topic": "/pedal", "agent": "human", "event": "toggle",
                                      "when": {"data": True}}]}}


def _world_point(p_room: np.ndarray) -> np.ndarray:
    return _axis_angle((0, 0, 1), math.pi / 2) @ p_room + np.array(_TURN["translation"])


def _ros4hri_messages() -> list[BagMessage]:
    """Two bodies (b1x7 from 0.5 s, zz9 from 2 s) at 30 Hz, and a pedal (std_msgs/Bool)
    pressed (true) at each task's start and end, released (false) in between."""
    first, second = _skeleton("b1x7"), _skeleton("zz9", phase=0.4)
    msgs = [BagMessage("/tf_static", "tf2_msgs/msg/TFMessage", 0, _tf(first, 0, True))]
    for k in range(0, 256):
        stamp = S // 2 + k * S // 30
        msgs.append(BagMessage("/tf", "tf2_msgs/msg/TFMessage", stamp + LATENCY,
                               _tf(first, stamp, False)))
        if stamp >= 2 * S:
            if stamp == S // 2 + 45 * S // 30:
                msgs.append(BagMessage("/tf_static", "tf2_msgs/msg/TFMessage", stamp,
                                       _tf(second[1:], stamp, True)))
            msgs.append(BagMessage("/tf", "tf2_msgs/msg/TFMessage", stamp + LATENCY,
                                   _tf(second[1:], stamp, False)))
    for start, end in _TASKS.values():
        for at in (start, end):
            msgs.append(BagMessage("/pedal", "std_msgs/msg/Bool", round(at * S), _bool(True)))
            msgs.append(BagMessage("/pedal", "std_msgs/msg/Bool", round((at + 0.1) * S),
                                   _bool(False)))
    return sorted(msgs, key=lambda m: m.time_ns)


def to_ros1(msg: Any, store: Any) -> Any:
    """The same message in a ROS 1 type store (a header gets seq 0)."""
    cls = store.types[msg.__msgtype__]
    fields = {}
    for name in cls.__dataclass_fields__:
        if name == "__msgtype__":
            continue
        if name == "seq":
            fields[name] = 0
            continue
        v = getattr(msg, name)
        if hasattr(v, "__msgtype__"):
            v = to_ros1(v, store)
        elif isinstance(v, list):
            v = [to_ros1(x, store) if hasattr(x, "__msgtype__") else x for x in v]
        fields[name] = v
    return cls(**fields)


def write_ros1(path: Path, msgs: list[BagMessage]) -> Path:
    """A ROS 1 bag, as franka_ros's rosbag record writes one (ROS 1 types, with definitions)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                      "tf2_msgs/msg/TFMessage"))
    conns: dict[tuple[str, str], Any] = {}
    with Writer(path) as writer:
        for m in msgs:
            key = (m.topic, m.msgtype)
            if key not in conns:
                conns[key] = writer.add_connection(m.topic, m.msgtype, typestore=store)
            writer.write(conns[key], m.time_ns,
                         store.serialize_ros1(to_ros1(m.msg, store), m.msgtype))
    return path


# -- tests ----------------------------------------------------------------------------------

def test_tf_lookup_interpolates_as_tf2_and_refuses_to_extrapolate() -> None:
    """Between two stamps: translation linear, rotation spherical (about one axis: the angle
    linear); outside the stamps: invalid; a static link holds at every time."""
    from rapidds.bridge.tf import TfBuffer

    buf = TfBuffer()
    buf.add("world", "base", 0, (0.0, 0.0, 1.0), _quat((0, 0, 1), 0.0), static=True)
    buf.add("base", "arm", 1 * S, (1.0, 0.0, 0.0), _quat((0, 0, 1), 0.2))
    buf.add("base", "arm", 3 * S, (2.0, 2.0, 0.0), _quat((0, 0, 1), 1.0))
    buf.add("arm", "hand", 0, (0.5, 0.0, 0.0), _quat((0, 0, 1), 0.0), static=True)
    p, ok = buf.positions("hand", "world", np.array([2 * S, 1 * S, 3 * S + 1, S // 2]))
    assert ok.tolist() == [True, True, False, False]
    angle = 0.6  # halfway between 0.2 and 1.0
    want = np.array([1.5, 1.0, 1.0]) + _axis_angle((0, 0, 1), angle) @ np.array([0.5, 0, 0])
    np.testing.assert_allclose(p[0], want, atol=1e-12)
    np.testing.assert_allclose(p[1], [1.0 + 0.5 * math.cos(0.2), 0.5 * math.sin(0.2), 1.0],
                               atol=1e-12)
    assert buf.chain("hand", "room") == (["hand", "arm", "base"], "world")  # world: no parent


@pytest.mark.parametrize("storage", ["mcap", "ros1"])
def test_a_ros4hri_skeleton_on_tf_is_composed_and_observed(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], storage: str) -> None:
    """The first tracked body's wrists and elbows, composed through their chains (camera,
    body, torso, shoulder, elbow; wrists on /tf_static) and the mapping's transform, reach
    observe's stored paths within 1 mm of the chain multiplied out by hand; task boundaries
    come from a pedal by the mapping's rule (the order of the tasks given in the mapping, or,
    for the ROS 1 bag, the plan's); the bag is rosbag2 MCAP or ROS 1."""
    from rapidds.schedule import task_items

    msgs = _ros4hri_messages()
    bag = (write_bag(tmp_path / "hri.mcap", msgs) if storage == "mcap"
           else write_ros1(tmp_path / "hri.bag", msgs))
    (tmp_path / "map.yaml").write_text(yaml.safe_dump(_mapping_yaml(storage == "mcap")))
    (tmp_path / "run.yaml").write_text(yaml.safe_dump(SMALL))
    code, stdout, err = run_main(capsys, "observe", str(tmp_path / "real"), "--bag", str(bag),
                                 "--mapping", str(tmp_path / "map.yaml"), "--config",
                                 str(tmp_path / "run.yaml"), "--json")
    assert code == 0, err
    assert "bodies b1x7, zz9 tracked; the first, 'b1x7', is learned, the others dropped" in err
    assert "not in the mapping" not in err  # the skeleton's other frames are not noise
    rec = json.loads(stdout)
    order = list(_TASKS) if storage == "mcap" else task_items(rec["human"])
    spans = dict(zip(order, _TASKS.values(), strict=False))  # the k-th pedal run: k-th task
    assert set(rec["observed"]) == set(task_items(rec["human"])) and rec["observed"]
    links = _skeleton("b1x7")
    world = make_world("painting")
    with RunStore.open_readonly(tmp_path / "real" / "run.sqlite") as store:
        (rid,) = store.run_ids()
        human = cycle_paths(store.arrays(rid, 0))["human"]
    assert set(human) == set(rec["observed"])
    for task, path in human.items():
        start, end = spans[task]
        assert rec["observed"][task] == pytest.approx(end - start, abs=1e-6)
        times = start + np.minimum(np.arange(len(path)) * world.dt, end - start)
        path = np.asarray(path).reshape(len(times), 4, 3)
        for k, name in enumerate(("l_wrist", "r_wrist", "l_elbow", "r_elbow")):
            want = np.stack([_world_point(_truth(links, f"{name}_b1x7", "room",
                                                 t - LATENCY / S)) for t in times])
            assert np.abs(path[:, k] - want).max() < 1e-3, (task, name)


def test_an_incomplete_chain_is_said_once_and_not_learned(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A wrist whose elbow hangs from a frame nobody publishes: one line, no samples; a body
    id the mapping names is taken over the first tracked."""
    links = [link for link in _skeleton("b1x7") if link[1] != "l_shoulder_b1x7"]
    msgs = [BagMessage("/tf_static", "tf2_msgs/msg/TFMessage", 0, _tf(links, 0, True))]
    msgs += [BagMessage("/tf", "tf2_msgs/msg/TFMessage", k * S // 10,
                        _tf(links, k * S // 10, False)) for k in range(20)]
    bag = write_bag(tmp_path / "broken.mcap", msgs)
    world = make_world("painting")
    mapping = TrackingMapping(points=_POINTS, root_frame="room", body_id="b1x7",
                              transform=_TURN)
    with caplog.at_level(logging.WARNING, logger="rapidds.bridge"):
        cycle = read_cycle(bag, world, mapping)
    lines = [r.getMessage() for r in caplog.records]
    broken = [line for line in lines if "does not reach the root frame 'room'" in line]
    assert len(broken) == 2 and all("l_shoulder_b1x7" in line for line in broken), lines
    assert sorted(cycle.points) == ["r_elbow", "r_wrist"]
    r_wrist = cycle.points["r_wrist"][1]
    np.testing.assert_allclose(r_wrist[3],
                               _world_point(_truth(links, "r_wrist_b1x7", "room", 0.3)),
                               atol=1e-9)


def test_boundary_rules_are_declared_and_checked(tmp_path: Path,
                                                 caplog: pytest.LogCaptureFixture) -> None:
    world = make_world("painting")
    base: dict[str, Any] = {"points": {n: n for n in ("l_wrist", "r_wrist", "l_elbow",
                                                      "r_elbow")}}
    bad = [
        {"rules": [{"topic": "/pedal", "agent": "human", "event": "end"}]},  # never starts
        {"rules": [{"topic": "/pedal", "agent": "human", "event": "start"}]},  # never ends
        {"rules": [{"topic": "/pedal", "agent": "dog", "event": "end"}]},
        {"rules": [{"topic": "/pedal", "agent": "human", "event": "press"}]},
        {"rules": []},
        {"rules": [{"topic": "/p", "agent": "robot", "event": "start"}],
         "order": {"robot": ["no_such_task"]}},
        {"rules": [{"topic": "/p", "agent": "robot", "event": "end", "when": {"data": [1]}}]},
    ]
    for k, boundaries in enumerate(bad):
        (tmp_path / f"{k}.yaml").write_text(yaml.safe_dump({**base, "boundaries": boundaries}))
        with pytest.raises(ConfigError) as err:
            load_mapping(tmp_path / f"{k}.yaml").check(world)
        assert "\n" not in str(err.value) and "boundaries" in str(err.value), err.value
    # signals that do not fit are dropped one line each; the rest make tasks
    rules = {"order": {"robot": ["mix_l", "mix_r"]},
             "rules": [{"topic": "/arm/joint_trajectory", "agent": "robot", "event": "start"},
                       {"topic": "traj_complete", "agent": "robot", "event": "end",
                        "when": {"data": True}}]}
    mapping = TrackingMapping(**base, boundaries=rules)
    traj = ros2.joint_trajectory(["a"], np.zeros((2, 1)), 0.1)
    msgs = [BagMessage("/traj_complete", "std_msgs/msg/Bool", 1 * S, _bool(True)),  # none open
            BagMessage("/arm/joint_trajectory", "trajectory_msgs/msg/JointTrajectory", 2 * S,
                       traj),
            BagMessage("/arm/joint_trajectory", "trajectory_msgs/msg/JointTrajectory", 3 * S,
                       traj),  # while mix_l runs
            BagMessage("/traj_complete", "std_msgs/msg/Bool", 4 * S, _bool(False)),
            BagMessage("/traj_complete", "std_msgs/msg/Bool", 5 * S, _bool(True)),
            BagMessage("/arm/joint_trajectory", "trajectory_msgs/msg/JointTrajectory", 6 * S,
                       traj),
            BagMessage("/traj_complete", "std_msgs/msg/Bool", 7 * S, _bool(True)),
            BagMessage("/arm/joint_trajectory", "trajectory_msgs/msg/JointTrajectory", 8 * S,
                       traj)]  # past the order
    bag = write_bag(tmp_path / "signals.mcap", msgs)
    with caplog.at_level(logging.WARNING, logger="rapidds.bridge"):
        cycle = read_cycle(bag, world, mapping)
    assert cycle.tasks == {"mix_l": ("robot", 2 * S, 5 * S), "mix_r": ("robot", 6 * S, 7 * S)}
    lines = [r.getMessage() for r in caplog.records]
    for needle in ("ends no open robot task", "while 'mix_l' runs", "past the 2 of"):
        assert sum(needle in line for line in lines) == 1, (needle, lines)
    # without an order the signals wait for the plan's; demonstrations have no plan
    from rapidds.bridge.recorded import bind_plan, robot_demonstrations

    waiting = TrackingMapping(**base, boundaries={"rules": rules["rules"]})
    unbound = read_cycle(bag, world, waiting)
    assert unbound.tasks == {} and len(unbound.signals) == len(msgs)
    bound = bind_plan(unbound, world, waiting, {"robot": ("mix_l", "mix_r"), "human": ()})
    assert bound.tasks == cycle.tasks
    with pytest.raises(ConfigError, match=r"boundaries\.order\.robot"):
        robot_demonstrations(bag, world, waiting)


# -- robot demonstrations -------------------------------------------------------------------

_MOVES = {"mix_l": (1.0, 2.0), "mix_r": (4.0, 2.5)}  # start s, duration s


def _world_joints(task: str, t: float) -> np.ndarray:
    """The arm's joints (world convention) at time t s of a task: rest to a pose and back."""
    world = make_world("painting")
    rest = np.asarray(world.robot_rest(), float)
    goal = rest + (np.array([0.3, 0.2, -0.2, 0.3, 0.1, 0.4, 0.2]) if task == "mix_l"
                   else np.array([-0.3, 0.1, 0.2, 0.2, -0.1, 0.3, -0.2]))
    start, dur = _MOVES[task]
    s = min(max((t - start) / dur, 0.0), 1.0)
    return rest + (goal - rest) * 0.5 * (1 - math.cos(2 * math.pi * s))


def _franka_messages(prefix: str, topic: str) -> list[BagMessage]:
    """franka_ros(2)-style: joint states (prefix_joint1..7 and two fingers, the driver's
    joint 6 = the world's + pi/2) at 100 Hz, a trajectory arriving at each task's start and
    std_msgs/Bool traj_complete (false while moving, true at the end)."""
    names = [*(f"{prefix}_joint{k}" for k in range(1, 8)), f"{prefix}_finger_joint1",
             f"{prefix}_finger_joint2"]
    offset = np.array([0, 0, 0, 0, 0, math.pi / 2, 0])
    msgs = []
    for k in range(0, 801):
        at = k * S // 100
        task = "mix_l" if at < 3.5 * S else "mix_r"
        q = _world_joints(task, at / S) + offset
        msgs.append(BagMessage(topic, "sensor_msgs/msg/JointState", at,
                               ros2.joint_state(names, np.r_[q, 0.04, 0.04], stamp_ns=at)))
        if k % 50 == 0:
            msgs.append(BagMessage("/traj_complete", "std_msgs/msg/Bool", at + 1, _bool(False)))
    traj = ros2.joint_trajectory(names[:7], np.zeros((2, 7)), 0.1)
    for start, dur in _MOVES.values():
        msgs.append(BagMessage(f"/{prefix}_arm_controller/joint_trajectory",
                               "trajectory_msgs/msg/JointTrajectory", round(start * S), traj))
        msgs.append(BagMessage("/traj_complete", "std_msgs/msg/Bool",
                               round((start + dur) * S), _bool(True)))
    return sorted(msgs, key=lambda m: m.time_ns)


def _boundaries_yaml(path: Path, prefix: str) -> Path:
    doc = {"points": {n: n for n in ("l_wrist", "r_wrist", "l_elbow", "r_elbow")},
           "boundaries": {"order": {"robot": list(_MOVES)}, "rules": [
               {"topic": f"/{prefix}_arm_controller/joint_trajectory", "agent": "robot",
                "event": "start"},
               {"topic": "/traj_complete", "agent": "robot", "event": "end",
                "when": {"data": True}}]}}
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize(("prefix", "storage"), [("fr3", "mcap"), ("panda", "ros1")])
def test_franka_joint_states_train_through_the_robot_profile(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], prefix: str, storage: str) -> None:
    """A franka_ros2 bag (fr3 names, fingers, MCAP) and a franka_ros one (panda names, ROS 1):
    the profile whose names the joint states carry is found, its joint-6 offset undone, the
    tasks cut by the trajectory's arrival and traj_complete, and train-policy trains."""
    from rapidds.bridge.recorded import robot_demonstrations
    from rapidds.motion.policy import DiffusionPolicy

    world = make_world("painting")
    topic = "/joint_states" if prefix == "fr3" else "/franka_state_controller/joint_states"
    msgs = _franka_messages(prefix, topic)
    bag = (write_bag(tmp_path / "demo.mcap", msgs) if storage == "mcap"
           else write_ros1(tmp_path / "demo.bag", msgs))
    mapping = _boundaries_yaml(tmp_path / "map.yaml", prefix)
    demos = robot_demonstrations(bag, world, load_mapping(mapping))
    tasks = tuple(t.id for t in world.problem().tasks if "robot" in t.allowed)
    assert demos.task_names == tasks and len(demos) == 2
    for row, k in zip(demos.trajectories, demos.task_index, strict=True):
        start, _ = _MOVES[tasks[k]]
        want = np.stack([_world_joints(tasks[k], start + i * world.dt)
                         for i in range(world.horizon)])
        np.testing.assert_allclose(row, want, atol=2e-3)  # 100 Hz samples, linear between
    code, _, err = run_main(capsys, "train-policy", "--world", "painting", "--demos", str(bag),
                            "--mapping", str(mapping), "--steps", "2", "--out",
                            str(tmp_path / "p"))
    assert code == 0, err
    assert err.count("warning") <= 2, err  # no line per message
    assert tuple(DiffusionPolicy.load(tmp_path / "p", device="cpu").config.task_names) == tasks
    # named explicitly, a profile that does not fit says so in one line and trains nothing
    other = "franka-panda" if prefix == "fr3" else "franka-fr3"
    code, _, err = run_main(capsys, "train-policy", "--world", "painting", "--demos", str(bag),
                            "--mapping", str(mapping), "--robot", other, "--steps", "2",
                            "--out", str(tmp_path / "q"))
    assert code == 2 and err.count("rapidds: error:") == 1, err
    assert "fr3_joint1" in err if prefix == "fr3" else "panda_joint1" in err
    assert "warning" not in err, err


def _mujoco_tool(q: np.ndarray) -> np.ndarray:
    """The tool tip (the model's end_effector site) in the arm's base frame (link0), by
    MuJoCo's own forward kinematics."""
    import mujoco

    from rapidds.worlds.painting.scene import load_model

    model = load_model()
    data = mujoco.MjData(model)
    data.qpos[:7] = q
    mujoco.mj_kinematics(model, data)
    site = data.site("end_effector").xpos
    base = data.body("panda0_link0")
    return np.asarray(base.xmat).reshape(3, 3).T @ (site - base.xpos)


def test_end_effector_demonstrations_in_csv_become_joint_paths(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The paper's lab's format: base-frame tool poses with one-hot labels, 20 Hz. The joint
    paths the world's IK gives put the tool (MuJoCo's forward kinematics) within 5 mm of
    every recorded pose that falls on a row; train-policy trains on them."""
    from rapidds.bridge.poses import pose_demonstrations

    world = make_world("painting")
    lines = ["t,x,y,z,qx,qy,qz,qw,mix_l,mix_r,brush"]
    recorded = {}
    for task, dur in (("mix_l", 0.9), ("mix_r", 0.6)):
        start = _MOVES[task][0]
        rows = []
        for k in range(round(dur * 20) + 1):
            p = _mujoco_tool(_world_joints(task, start + k / 20))
            rows.append(p)
            label = "1,0,0" if task == "mix_l" else "0,1,0"
            lines.append(f"{start + k / 20:.4f},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f},"
                         f"1,0,0,0,{label}")
        recorded[task] = np.array(rows)
        lines.append(f"{start + dur + 0.5:.4f},0,0,0,0,0,0,1,0,0,0")  # unlabelled: a gap
    csv = tmp_path / "demos.csv"
    csv.write_text("\n".join(lines) + "\n")
    demos = pose_demonstrations(csv, world)
    assert len(demos) == 2 and demos.trajectories.shape[1:] == (world.horizon, 7)
    for row, k in zip(demos.trajectories, demos.task_index, strict=True):
        task = demos.task_names[k]
        want = recorded[task][::3]  # rows every dt = 0.15 s = 3 recorded rows
        got = np.stack([_mujoco_tool(q) for q in row[:len(want)]])
        assert np.linalg.norm(got - want, axis=1).max() < 5e-3, task
        np.testing.assert_allclose(row[len(want):], np.repeat(row[len(want) - 1:len(want)],
                                                              len(row) - len(want), 0))
    code, _, err = run_main(capsys, "train-policy", "--world", "painting", "--demos", str(csv),
                            "--steps", "2", "--out", str(tmp_path / "p"))
    assert code == 0, err


def test_wrong_demonstration_files_are_named(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    csv = tmp_path / "d.csv"
    csv.write_text("x,y,z,qx,qy,qz,qw,mix_l\n0.4,0,0.3,1,0,0,0,1\n")
    text = tmp_path / "d.txt"
    text.write_text("hello\n")
    bad_label = tmp_path / "label.csv"
    bad_label.write_text("x,y,z,qx,qy,qz,qw,dance\n0.4,0,0.3,1,0,0,0,1\n")
    no_quat = tmp_path / "noquat.csv"
    no_quat.write_text("x,y,z,mix_l\n0.4,0,0.3,1\n")
    two_hot = tmp_path / "twohot.csv"
    two_hot.write_text("x,y,z,qx,qy,qz,qw,mix_l,mix_r\n0.4,0,0.3,1,0,0,0,1,1\n")
    cases = [
        (["--demos", str(csv)], "is a CSV"),
        (["--demos", str(text)], "not a demonstrations .npz"),
        (["--demos", str(tmp_path / "x.bag")], "is a bag"),
        (["--world", "painting", "--demos", str(bad_label)], "'dance' is not a robot task"),
        (["--world", "painting", "--demos", str(no_quat)], "no column 'qx'"),
        (["--world", "painting", "--demos", str(two_hot)], "row 2 is not one-hot"),
        (["--world", "painting", "--demos", str(text)], "is not demonstrations painting reads"),
    ]
    for args, needle in cases:
        code, _, err = run_main(capsys, "train-policy", *args, "--steps", "1", "--out",
                                str(tmp_path / "p"))
        assert code == 2 and err.count("rapidds: error:") == 1 and needle in err, (args, err)


def test_a_ros1_bag_that_is_no_bag_is_said_in_one_line(tmp_path: Path) -> None:
    from rapidds.bridge.bag import read_bag

    fake = tmp_path / "x.bag"
    fake.write_text("not a bag")
    with pytest.raises(RapiddsError, match="not a readable ROS 1 bag"):
        list(read_bag(fake))


def test_the_mappings_body_id_picks_another_tracked_body(tmp_path: Path) -> None:
    """body_id zz9 (tracked from 2 s on): its wrist, not the first body's, is learned."""
    bag = write_bag(tmp_path / "hri.mcap", _ros4hri_messages())
    world = make_world("painting")
    mapping = TrackingMapping(**{**_mapping_yaml(), "body_id": "zz9"})
    times, points = read_cycle(bag, world, mapping).points["l_wrist"]
    assert times[0] == 2 * S + LATENCY
    links = _skeleton("zz9", phase=0.4)
    want = np.stack([_world_point(_truth(links, "l_wrist_zz9", "room", (t - LATENCY) / S))
                     for t in times])
    np.testing.assert_allclose(points, want, atol=1e-9)


def test_unstamped_and_broken_transforms(tmp_path: Path,
                                         caplog: pytest.LogCaptureFixture) -> None:
    """A tracker that stamps its transforms 0 is read at their receive times (tf2 would read
    time 0 as "latest"); a transform with a NaN or a zero quaternion is dropped in one line."""
    from rapidds.bridge.export import tf_message

    world = make_world("painting")
    names = ("l_wrist", "r_wrist", "l_elbow", "r_elbow")
    rest = np.asarray(world.human_rest(), float)
    msgs = [BagMessage("/tf", "tf2_msgs/msg/TFMessage", k * S // 10,
                       tf_message(names, rest + 0.01 * k, 0)) for k in range(10)]
    bad = tf_message(names[:1], rest[:1] + np.nan, 0)
    msgs.append(BagMessage("/tf", "tf2_msgs/msg/TFMessage", S + 1, bad))
    with caplog.at_level(logging.WARNING, logger="rapidds.bridge"):
        cycle = read_cycle(write_bag(tmp_path / "zero.mcap", msgs), world)
    times, points = cycle.points["l_wrist"]
    assert times.tolist() == [k * S // 10 for k in range(10)]
    np.testing.assert_allclose(points, rest[0] + 0.01 * np.arange(10)[:, None], atol=1e-12)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "not finite or with a zero quaternion" in lines[0], lines


def test_points_stamped_in_a_tf_frame_are_transformed_as_tf2_would(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """PointStamped messages in a moving camera's frame (its transform at 10 Hz, the points at
    30 Hz between them): each point is taken into the root frame through the camera's
    transform interpolated at the point's stamp. The camera moves and turns at constant rates,
    so linear translation and slerp are exact and the answer is known to 1e-9; a point in a
    frame whose chain stops short of the root is said once and not learned."""
    def camera(t: float) -> tuple[tuple[float, float, float], float]:
        return (0.5 + 0.2 * t, -0.3, 0.6 - 0.1 * t), 0.4 * t  # translation, angle about z

    msgs, t0 = [], 100 * S  # stamps on a wall clock (a stamp of 0 means "unstamped")
    for k in range(31):  # the camera's transform every 0.1 s from 0 to 3 s
        trans, angle = camera(k / 10)
        msgs.append(BagMessage("/tf", "tf2_msgs/msg/TFMessage", t0 + k * S // 10 + LATENCY,
                               _tf([("room", "camera", False,
                                     lambda t, tr=trans, a=angle: (tr, (0.0, 0.0, 1.0), a))],
                                   t0 + k * S // 10, False)))
    msgs.append(BagMessage("/tf", "tf2_msgs/msg/TFMessage", t0,
                           _tf([("nowhere", "lost", False, lambda t: ((0, 0, 0), (0, 0, 1), 0))],
                               t0, False)))
    local = {"/hri/lw": (0.1, 0.2, 0.3), "/hri/rw": (-0.1, 0.2, 0.3),
             "/hri/le": (0.1, 0.0, 0.5), "/hri/re": (0.0, 0.0, 0.0)}
    for k in range(1, 85):  # 30 Hz, inside the camera's stamps
        stamp = t0 + k * S // 30
        for topic, p in local.items():
            frame = "lost" if topic == "/hri/re" else "camera"
            msgs.append(BagMessage(topic, "geometry_msgs/msg/PointStamped", stamp + LATENCY,
                                   ros2.point_stamped(p, stamp, frame)))
    bag = write_bag(tmp_path / "cam.mcap", sorted(msgs, key=lambda m: m.time_ns))
    mapping = TrackingMapping(points={"/hri/lw": "l_wrist", "/hri/rw": "r_wrist",
                                      "/hri/le": "l_elbow", "/hri/re": "r_elbow"},
                              root_frame="room")
    with caplog.at_level(logging.WARNING, logger="rapidds.bridge"):
        cycle = read_cycle(bag, make_world("painting"), mapping)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "frame 'lost'" in lines[0] and "not learned" in lines[0], lines
    assert "r_elbow" not in cycle.points
    for topic, name in (("/hri/lw", "l_wrist"), ("/hri/rw", "r_wrist"), ("/hri/le", "l_elbow")):
        times, points = cycle.points[name]
        assert len(times) == 84
        want = []
        for t in (times - LATENCY - t0) / S:
            trans, angle = camera(t)
            want.append(_axis_angle((0, 0, 1), angle) @ np.array(local[topic]) + trans)
        np.testing.assert_allclose(points, np.array(want), atol=1e-9)
