"""Reading a cycle recorded in a real cell: the tracker's frames become the world's body points
through the mapping's rigid transform, paths are resampled at dt over each task, and bad input
is dropped one line at a time while the rest is kept."""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_main

from rapidds.bridge import ros2
from rapidds.bridge.bag import BagMessage, write_bag
from rapidds.bridge.export import tf_message
from rapidds.bridge.recorded import (
    TrackingMapping,
    default_mapping,
    human_executions,
    load_mapping,
    read_cycle,
)
from rapidds.errors import ConfigError
from rapidds.worlds.base import body_point_names, joint_names
from rapidds.worlds.registry import make_world

S = 1_000_000_000


def _event(task: str, kind: str, at: int, agent: str = "human") -> BagMessage:
    return BagMessage(ros2.EVENTS_TOPIC, "std_msgs/msg/String", at,
                      ros2.event_message(ros2.Event(task, agent, kind)))  # type: ignore[arg-type]


def _raw_event(text: str, at: int) -> BagMessage:
    msg = ros2.typestore().types["std_msgs/msg/String"](data=text)
    return BagMessage(ros2.EVENTS_TOPIC, "std_msgs/msg/String", at, msg)


def _hand(t: float) -> np.ndarray:
    """A body point's true path in the world frame, smooth in time (s)."""
    return np.array([0.1 * t, 0.2 - 0.05 * t, 0.1 + 0.02 * math.sin(t)])


# tracker frame = world frame turned 90 degrees about z and shifted
_TURN = {"translation": [0.5, -0.2, 0.1], "rotation": [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)]}


def _to_tracker(p: np.ndarray) -> np.ndarray:
    """Inverse of _TURN: world -> tracker (R^T (p - t), R a +90 degree turn about z)."""
    q = p - np.array(_TURN["translation"])
    return np.array([q[1], -q[0], q[2]])


def _mapping() -> TrackingMapping:
    return TrackingMapping(points={"/mocap/lw": "l_wrist", "/mocap/rw": "r_wrist",
                                  "/mocap/arms/0": "l_elbow", "/mocap/arms/1": "r_elbow"},
                           transform=_TURN)


def _tracking(at: int, t: float) -> list[BagMessage]:
    """The four body points at time t (s) as a PointStamped, a PoseStamped and a PoseArray."""
    ty = ros2.typestore().types
    pts = [_to_tracker(_hand(t) + off) for off in (0.0, 0.1, 0.2, 0.3)]
    head = ros2.header(at, "mocap")

    def pose(p: np.ndarray) -> object:
        return ty["geometry_msgs/msg/Pose"](
            position=ty["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
            orientation=ty["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))

    return [
        BagMessage("/mocap/lw", "geometry_msgs/msg/PointStamped", at,
                   ros2.point_stamped(pts[0], at, "mocap")),
        BagMessage("/mocap/rw", "geometry_msgs/msg/PoseStamped", at,
                   ty["geometry_msgs/msg/PoseStamped"](header=head, pose=pose(pts[1]))),
        BagMessage("/mocap/arms", "geometry_msgs/msg/PoseArray", at,
                   ty["geometry_msgs/msg/PoseArray"](header=head, poses=[pose(pts[2]),
                                                                         pose(pts[3])])),
    ]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_tracked_points_become_body_points_in_the_world_frame(tmp_path: Path,
                                                               storage: str) -> None:
    world = make_world("painting")
    dt, start, duration = world.dt, 2 * S, 1.0
    msgs = [_event("prep_vise", "start", start), _event("prep_vise", "end", start + S)]
    for k in range(-2, 60):  # the tracker runs at 50 Hz from before the task to after it
        at = start + k * S // 50
        msgs += _tracking(at, at / S)
    bag = write_bag(tmp_path / ("b.mcap" if storage == "mcap" else "b"),
                    sorted(msgs, key=lambda m: m.time_ns), storage)  # type: ignore[arg-type]
    got = human_executions(read_cycle(bag, world, _mapping()), world)
    ex = got["prep_vise"]
    assert ex.duration == pytest.approx(duration, abs=1e-9)
    rows = math.ceil(duration / dt - 1e-9) + 1
    times = 2.0 + np.minimum(np.arange(rows) * dt, duration)
    truth = np.stack([np.stack([_hand(t) + off for off in (0.0, 0.1, 0.2, 0.3)])
                      for t in times])
    assert ex.trajectory.shape == (rows, 4, 3)
    # linear interpolation of 50 Hz samples of a smooth path: errors of the order of
    # (dt_sample^2 / 8) * curvature, below 1e-5 m here
    np.testing.assert_allclose(ex.trajectory, truth, atol=1e-5)


def test_bad_messages_are_dropped_one_line_each(tmp_path: Path,
                                                caplog: pytest.LogCaptureFixture) -> None:
    world = make_world("painting")
    names = body_point_names(world)
    rest = np.asarray(world.human_rest(), float)
    msgs = [
        _raw_event("{not json", 1 * S),
        _event("no_such_task", "start", 1 * S),
        _event("brush", "end", 1 * S),  # an end before its start
        _event("prep_vise", "start", 2 * S),
        _event("prep_vise", "start", 2 * S + 1),  # a second start
        _event("secure_piece", "start", 3 * S),  # never ends
        _event("prep_vise", "end", 4 * S),
    ]
    for k in range(0, 31):
        at = 1 * S + k * S // 10
        msgs.append(BagMessage("/tf", "tf2_msgs/msg/TFMessage", at,
                               tf_message(names, rest + 0.01 * k, at)))
    late = 2 * S  # stamped before the sample received just before it: out of order
    msgs.append(BagMessage("/tf", "tf2_msgs/msg/TFMessage", 3 * S + 1,
                           tf_message(names, rest + 9.0, late)))
    msgs.append(BagMessage("/tf", "tf2_msgs/msg/TFMessage", 3 * S + 2,
                           tf_message(("someone_else",), rest[:1], 3 * S + 2)))
    bag = write_bag(tmp_path / "bad.mcap", sorted(msgs, key=lambda m: m.time_ns))
    with caplog.at_level(logging.WARNING, logger="rapidds.bridge"):
        cycle = read_cycle(bag, world)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == cycle.dropped
    for needle in ("not JSON", "unknown task 'no_such_task'", "end of task 'brush'",
                   "second start of task 'prep_vise'", "'secure_piece' started but never",
                   "before its previous sample", "'someone_else' is not in the mapping"):
        assert sum(needle in line for line in lines) >= 1, (needle, lines)
    assert all("\n" not in line for line in lines)
    got = human_executions(cycle, world)
    assert list(got) == ["prep_vise"] and got["prep_vise"].duration == pytest.approx(2.0)
    assert np.abs(got["prep_vise"].trajectory).max() < 5  # the out-of-order sample was dropped


def test_mappings_are_checked(tmp_path: Path) -> None:
    world = make_world("painting")
    assert set(default_mapping(world).points.values()) == set(body_point_names(world))
    assert default_mapping(make_world("fetch")).points == {"body": "body"}
    assert joint_names(make_world("fetch")) == ("x", "y")
    assert len(joint_names(world)) == 7
    bad = {"bad.yaml": "points: [unclosed", "list.yaml": "- a\n- b\n",
           "unknown.yaml": "points: {l_wrist: l_wrist, r_wrist: r_wrist, l_elbow: l_elbow, "
                           "r_elbow: r_elbow, x: knee}\n",
           "missing.yaml": "points: {l_wrist: l_wrist}\n",
           "zero.yaml": "points: {a: b}\ntransform: {rotation: [0, 0, 0, 0]}\n",
           "extra.yaml": "points: {a: b}\nscale: 2\n"}
    for name, text in bad.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(ConfigError) as err:
            load_mapping(tmp_path / name).check(world)
        assert "\n" not in str(err.value)
    with pytest.raises(ConfigError):
        load_mapping(tmp_path / "absent.yaml")


def test_observe_refuses_what_it_cannot_use(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    bag = write_bag(tmp_path / "empty.mcap", [_event("prep_vise", "start", S)])
    (tmp_path / "run.yaml").write_text("world: painting\ncycles: 2\n")
    (tmp_path / "bad.yaml").write_text("points: {l_wrist: nose}\n")
    cases = [
        [str(tmp_path / "r1"), "--bag", str(bag)],  # no run and no --config
        [str(tmp_path / "r2"), "--bag", str(bag), "--config", str(tmp_path / "run.yaml")],
        [str(tmp_path / "r3"), "--bag", str(tmp_path / "nope.mcap"), "--config",
         str(tmp_path / "run.yaml")],
        [str(tmp_path / "r4"), "--bag", str(bag), "--config", str(tmp_path / "run.yaml"),
         "--mapping", str(tmp_path / "bad.yaml")],
    ]
    for args in cases:
        code, _, err = run_main(capsys, "observe", *args)
        errors = [x for x in err.splitlines() if x.startswith("rapidds: error:")]
        assert code == 2 and len(errors) == 1, err
        assert not Path(args[0]).exists()  # nothing written for an unusable bag


def _line(a: np.ndarray, b: np.ndarray, duration: float, t: float) -> np.ndarray:
    return a + (b - a) * min(max(t / duration, 0.0), 1.0)


def test_robot_demonstrations_from_bags_train_a_policy(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """Joint states at 100 Hz (the world's joints in another order, plus one more) cut into
    tasks by the robot's events, sampled at dt and held at the end to the horizon."""
    from rapidds.bridge.recorded import robot_demonstrations
    from rapidds.motion.policy import DiffusionPolicy

    world = make_world("fetch")
    names = [*reversed(joint_names(world)), "gripper"]
    moves = {"t0": (1 * S, 3.0, np.array([1.0, 2.0]), np.array([4.0, 1.0])),
             "t1": (5 * S, 2.0, np.array([4.0, 1.0]), np.array([2.0, 6.0]))}
    msgs = []
    for task, (start, dur, *_) in moves.items():
        msgs += [_event(task, "start", start, "robot"),
                 _event(task, "end", start + round(dur * S), "robot")]
    for k in range(0, 701):  # 100 Hz from 0 to 7 s
        at = k * S // 100
        task = "t0" if at < 4.5 * S else "t1"
        start, dur, a, b = moves[task]
        x, y = _line(a, b, dur, (at - start) / S)
        msgs.append(BagMessage(ros2.JOINT_STATE_TOPIC, "sensor_msgs/msg/JointState", at,
                               ros2.joint_state(names, np.array([y, x, 0.5]), stamp_ns=at)))
    (tmp_path / "bags").mkdir()
    write_bag(tmp_path / "bags" / "demo.mcap", msgs)
    demos = robot_demonstrations(tmp_path / "bags", world)
    robot_tasks = tuple(t.id for t in world.problem().tasks if "robot" in t.allowed)
    assert demos.task_names == robot_tasks
    assert demos.trajectories.shape == (2, world.horizon, 2)
    for row, k in zip(demos.trajectories, demos.task_index, strict=True):
        start, dur, a, b = moves[robot_tasks[k]]
        want = np.stack([_line(a, b, dur, i * world.dt) for i in range(world.horizon)])
        np.testing.assert_allclose(row, want, atol=1e-5)  # float32 demonstrations
    code, _, err = run_main(capsys, "train-policy", "--world", "fetch", "--demos",
                            str(tmp_path / "bags"), "--steps", "3", "--out", str(tmp_path / "p"))
    assert code == 0, err
    policy = DiffusionPolicy.load(tmp_path / "p", device="cpu")
    assert tuple(policy.config.task_names) == robot_tasks
    assert policy.config.horizon == world.horizon
