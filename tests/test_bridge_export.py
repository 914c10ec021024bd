"""An export a controller can replay: every exported trajectory of fetch and painting, decoded
by mcap-ros2-support (not the library that wrote it) and differenced, stays within the robot
profile's limits; each is cut to its task; the joint states are one stream with increasing
stamps on the run's wall clock (or ``--epoch``), never 1970."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_helpers import run_main
from test_bridge_bags import read_ros2

from rapidds.bridge import ros2
from rapidds.bridge.profiles import robot_profile, task_rows
from rapidds.loop.config import RunConfig
from rapidds.motion.timing import limit_excess
from rapidds.store import RunStore, cycle_paths
from rapidds.worlds.registry import make_world

SMALL = {"cycles": 2, "population": 4, "generations": 2, "samples": 8, "particles": 2,
         "candidates": 2}
_NS = 1_000_000_000


def _run(out: Path, world: str) -> Path:
    import torch

    from rapidds.loop.run import AdaptiveRun

    torch.set_num_threads(1)
    with RunStore(out / "run.sqlite") as store:
        AdaptiveRun(RunConfig(world=world, **SMALL), store=store).run()
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return {w: _run(tmp_path_factory.mktemp(w), w) for w in ("fetch", "painting")}


def _seconds(d: Any) -> float:
    return d.sec + d.nanosec * 1e-9


def _export(capsys: Any, run_dir: Path, out: Path, *args: str) -> dict[str, list[Any]]:
    code, _, err = run_main(capsys, "export", str(run_dir), "--out", str(out), *args)
    assert code == 0, err
    by_topic: dict[str, list[Any]] = {}
    for ch, msg in read_ros2(out):
        by_topic.setdefault(ch.topic, []).append((msg, ch))
    return {t: [m for m, _ in v] for t, v in by_topic.items()}


@pytest.mark.parametrize(("world_name", "profile_name"), [
    ("fetch", "reference"), ("painting", "reference"), ("painting", "franka-panda"),
    ("painting", "franka-fr3")])
def test_exported_trajectories_stay_within_the_profiles_limits(
        runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str],
        world_name: str, profile_name: str) -> None:
    run_dir = runs[world_name]
    msgs = _export(capsys, run_dir, tmp_path / "x.mcap", "--robot", profile_name)
    world, profile = make_world(world_name), robot_profile(profile_name)
    limits = profile.limits(world)
    offset = profile.offset(world)
    trajs = msgs[ros2.TRAJECTORY_TOPIC]
    store = RunStore.open_readonly(run_dir / "run.sqlite")
    (rid,) = store.run_ids()
    records = store.cycle_records(rid)
    assert len(trajs) == sum(len(r.plan.tasks("robot")) for r in records) > 0
    # the same trajectories, stamped 0 ("now"), on the controller's topic at each task's start
    assert len(msgs[profile.trajectory_topic]) == len(trajs)
    assert all(ros2.stamp_ns(m.header) == 0 for m in msgs[profile.trajectory_topic])
    for traj in trajs:
        assert list(traj.joint_names) == list(profile.joint_names(world))
        t = np.array([_seconds(p.time_from_start) for p in traj.points])
        q = np.array([p.positions for p in traj.points]) - offset  # the world's convention
        v = np.array([p.velocities for p in traj.points])
        a = np.array([p.accelerations for p in traj.points])
        assert v.shape == a.shape == q.shape  # velocities and accelerations in every point
        excess = limit_excess(t, q, limits, v, a)
        assert max(excess.values()) <= 1.0 + 1e-6, excess
        np.testing.assert_allclose(v[[0, -1]], 0.0, atol=1e-9)  # from rest, to rest
    # cut to the task: the rows up to the task's completion, not the whole horizon
    for rec in records:
        for task, path in cycle_paths(store.arrays(rid, rec.cycle))["robot"].items():
            assert len(task_rows(world, task, path)) < len(path)


@pytest.mark.parametrize("world_name", ["fetch", "painting"])
def test_joint_states_are_one_stream_on_the_runs_clock(
        runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str],
        world_name: str) -> None:
    run_dir = runs[world_name]
    store = RunStore.open_readonly(run_dir / "run.sqlite")
    (rid,) = store.run_ids()
    created = round(store.run_created(rid) * _NS)
    msgs = _export(capsys, run_dir, tmp_path / "s.mcap")
    states = msgs[ros2.JOINT_STATE_TOPIC]
    stamps = np.array([ros2.stamp_ns(s.header) for s in states])
    assert (np.diff(stamps) > 0).all()  # one stream: no two states share or reverse a stamp
    assert stamps[0] >= created > 1_600_000_000 * _NS  # the run's wall clock, not 1970
    q = np.array([s.position for s in states])
    if world_name == "painting":
        # the arm's states follow its parameterized trajectories: consecutive states within
        # the velocity limit (one stream, not two interleaved). Fetch's are its paths at their
        # own row timing, as its planner timed them (module docstring of rapidds.bridge.export)
        world = make_world(world_name)
        speed = np.abs(np.diff(q, axis=0)) / (np.diff(stamps)[:, None] / _NS)
        assert (speed <= world.robot_limits.velocity * (1 + 1e-6)).all()
    events = [json.loads(m.data) for m in msgs[ros2.EVENTS_TOPIC]]
    assert {e["agent"] for e in events} == {"human", "robot"}
    # --epoch moves the bag's clock: the first plan goes out at it
    epoch = "2026-11-27T06:00:00Z"
    moved = _export(capsys, run_dir, tmp_path / "e.mcap", "--epoch", epoch)
    plans = moved[ros2.PLAN_TOPIC]
    first = min(ros2.stamp_ns(s.header) for s in moved[ros2.JOINT_STATE_TOPIC])
    at = round(datetime(2026, 11, 27, 6, tzinfo=UTC).timestamp() * _NS)
    assert ros2.stamp_ns(moved[ros2.TRAJECTORY_TOPIC][0].header) >= at
    assert first >= at and len(plans) == 2


@pytest.mark.parametrize(("args", "says"), [
    (["--robot", "ur5"], "unknown robot profile 'ur5'"),
    (["--epoch", "yesterday"], "--epoch 'yesterday'"),
    (["--epoch", "2026-11-27T06:00:00"], "no time zone"),
])
def test_export_refuses_bad_profiles_and_epochs(
        runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str],
        args: list[str], says: str) -> None:
    code, _, err = run_main(capsys, "export", str(runs["painting"]), "--out",
                            str(tmp_path / "bad.mcap"), *args)
    assert code == 2 and err.count("\n") == 1 and says in err, err
    assert not (tmp_path / "bad.mcap").exists()


def test_an_arm_profile_on_the_point_robot_is_one_line(
        runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run_main(capsys, "export", str(runs["fetch"]), "--out",
                            str(tmp_path / "f.mcap"), "--robot", "franka-fr3")
    assert code == 2 and err.count("\n") == 1 and "maps 7 joints" in err, err
    assert not (tmp_path / "f.mcap").exists()
