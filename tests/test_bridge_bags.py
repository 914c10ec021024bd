"""A stored run goes out as an MCAP bag that the other library (mcap-ros2-support) reads back
message for message, and a cycle recorded as a bag comes back in through ``rapidds observe``
and teaches the run what the same cycle taught it in process."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from cli_helpers import run_main

from rapidds.bridge import ros2
from rapidds.bridge.export import CYCLE_GAP_S, cost_topic
from rapidds.bridge.profiles import task_rows
from rapidds.loop.config import RunConfig
from rapidds.loop.model import HumanModel
from rapidds.store import RunStore
from rapidds.worlds.base import joint_names
from rapidds.worlds.registry import make_world

SMALL = {"world": "painting", "cycles": 2, "population": 4, "generations": 2, "samples": 8,
         "particles": 2, "candidates": 2}


@pytest.fixture(scope="module")
def painting_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A two-cycle painting run with a simulated person, stored as ``rapidds run`` stores it."""
    import torch

    from rapidds.loop.run import AdaptiveRun

    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("painting-run")
    with RunStore(out / "run.sqlite") as store:
        AdaptiveRun(RunConfig(**SMALL), store=store).run()
    return out


def _stored(run_dir: Path) -> tuple[str, dict[str, Any], list[dict[str, Any]], Any]:
    store = RunStore.open_readonly(run_dir / "run.sqlite")
    (rid,) = store.run_ids()
    return rid, store.run_config(rid) or {}, store.records(rid), store


def read_ros2(path: Path) -> list[Any]:
    """Every message of an MCAP file decoded by mcap-ros2-support (the library rapidds does
    not write with): (channel, ros_msg) pairs, in log-time order."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(ch, msg) for _, ch, _, msg in reader.iter_decoded_messages(log_time_order=True)]


def _ns(seconds: float) -> int:
    return round(seconds * 1e9)


def test_export_reads_back_with_mcap_ros2(painting_run: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run.mcap"
    code, stdout, err = run_main(capsys, "export", str(painting_run), "--out", str(out), "--json")
    assert code == 0, err
    reported = json.loads(stdout)["messages"]
    rid, cfg, records, store = _stored(painting_run)
    world = make_world(cfg["world"], cfg["variant"])
    msgs = read_ros2(out)
    assert len(msgs) == reported > 0
    assert all(msg is not None for _, msg in msgs)  # every message decodes
    by_topic: dict[str, list[Any]] = {}
    for ch, msg in msgs:
        by_topic.setdefault(ch.topic, []).append(msg)

    # one JointTrajectory per robot task of each cycle, stamped at the task's realised start
    # on the run's recorded wall clock; the path's rows up to the task's end, every third
    # point (parameterized: never earlier than the path's own row times)
    trajs = {ros2.stamp_ns(t.header): t for t in by_topic[ros2.TRAJECTORY_TOPIC]}
    epoch, expected_count = _ns(store.run_created(rid)), 0
    for rec in records:
        arrays = store.arrays(rid, rec["cycle"])
        for task in rec["robot"]:
            traj = trajs[epoch + _ns(rec["realised"]["timeline"][task][0])]
            assert list(traj.joint_names) == list(joint_names(world))
            q = np.array([p.positions for p in traj.points])
            np.testing.assert_array_equal(q[::3], task_rows(world, task,
                                                            arrays[f"robot/{task}"]))
            t = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9
                          for p in traj.points])
            assert (t[::3] >= np.arange(len(q[::3])) * world.dt - 1e-9).all()
            assert all(len(p.velocities) == len(p.accelerations) == 7 for p in traj.points)
            expected_count += 1
        model = HumanModel.from_bytes(store.state(rid, rec["cycle"]))
        for task in model.spatial.tasks:  # the learned cost after this cycle, as float32
            cloud = by_topic[cost_topic(task)][rec["cycle"]]
            data = np.frombuffer(bytes(cloud.data), "<f4").reshape(cloud.width, 4)
            np.testing.assert_allclose(data[:, 3], model.spatial[task].mean, rtol=1e-6,
                                       atol=1e-7)
        epoch += _ns(rec["realised"]["makespan"] + CYCLE_GAP_S)
    assert len(trajs) == expected_count
    plans = [json.loads(p.data) for p in by_topic[ros2.PLAN_TOPIC]]
    assert plans == [ros2.plan_payload(r.cycle, r.plan.human, r.plan.robot, r.realised.timeline)
                     for r in store.cycle_records(rid)]
    # the Foxglove layout in docs/ shows only topics a painting export has
    layout = json.loads((Path(__file__).parents[1] / "docs" / "foxglove-layout.json").read_text())
    shown = {t for c in layout["configById"].values() for t in c.get("topics", {})}
    shown |= {p["value"].split(".")[0] for c in layout["configById"].values()
              for p in c.get("paths", [])}
    shown |= {c["topicPath"].split(".")[0] for c in layout["configById"].values()
              if "topicPath" in c}
    assert shown and shown <= set(by_topic), shown - set(by_topic)
    assert [p["order"]["human"] for p in plans] == [
        [x for x in r["human"] if not x.startswith("wait")] for r in records]


def test_export_one_cycle_and_refusals(painting_run: Path, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "one.mcap"
    assert run_main(capsys, "export", str(painting_run), "--cycle", "1", "--out", str(out))[0] == 0
    plans = [json.loads(msg.data) for ch, msg in read_ros2(out) if ch.topic == ros2.PLAN_TOPIC]
    assert [p["cycle"] for p in plans] == [1]
    for args in (["--cycle", "7", "--out", str(tmp_path / "x.mcap")],  # no such cycle
                 ["--out", str(out)]):  # exists: never overwritten
        code, _, err = run_main(capsys, "export", str(painting_run), *args)
        assert code == 2 and err.startswith("rapidds: error:") and err.count("\n") == 1, err
    code, _, err = run_main(capsys, "export", str(tmp_path / "nothing"), "--out",
                            str(tmp_path / "y.mcap"))
    assert code == 2 and err.count("\n") == 1


def _model_close(a: HumanModel, b: HumanModel, tol: float) -> None:
    np.testing.assert_allclose(a.temporal.mean(), b.temporal.mean(), rtol=0, atol=tol)
    for task, dm in a.temporal.models.items():
        np.testing.assert_allclose(dm.observations, b.temporal.models[task].observations,
                                   rtol=0, atol=tol)
    assert a.spatial.tasks == b.spatial.tasks
    for task in a.spatial.tasks:
        np.testing.assert_allclose(a.spatial[task].mean, b.spatial[task].mean, rtol=0, atol=tol)
        np.testing.assert_allclose(a.spatial[task].var, b.spatial[task].var, rtol=0, atol=tol)
    assert a.history.to_dict() == b.history.to_dict()
    assert sorted(map(str, a.motions)) == sorted(map(str, b.motions))


def test_observe_a_recorded_cycle_learns_what_the_simulated_one_did(
        painting_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Cycle 0 of the simulated run, recorded as a bag (events and the person's body points on
    /tf under the world's default mapping), observed by a fresh run with the same settings:
    the same plan, the same observed durations and the same learned model; then cycle 1 the
    same way, continuing the observed run. Tolerance 1e-7:
    a bag stores times in whole nanoseconds, so a duration read back differs by up to 2 ns,
    and the paths are resampled at those times (differences of ~1e-9 m)."""
    rid, cfg, records, store = _stored(painting_run)
    bag = tmp_path / "cycle0.mcap"
    assert run_main(capsys, "export", str(painting_run), "--cycle", "0", "--out", str(bag))[0] == 0
    (tmp_path / "run.yaml").write_text(yaml.safe_dump(cfg))
    code, stdout, err = run_main(capsys, "observe", str(tmp_path / "real"), "--bag", str(bag),
                                 "--config", str(tmp_path / "run.yaml"), "--json")
    assert code == 0, err
    rec, ref = json.loads(stdout), records[0]
    assert (rec["human"], rec["robot"], rec["routes"]) == (ref["human"], ref["robot"],
                                                           ref["routes"])
    assert rec["observed"].keys() == ref["observed"].keys()
    for task, d in ref["observed"].items():
        assert rec["observed"][task] == pytest.approx(d, abs=1e-7)
    assert rec["realised"]["makespan"] == pytest.approx(ref["realised"]["makespan"], abs=1e-7)
    assert rec["plan_cost"] is None  # a recorded person's truth is unknown
    with RunStore.open_readonly(tmp_path / "real" / "run.sqlite") as mine:
        assert mine.run_ids() == [rid]
        _model_close(HumanModel.from_bytes(mine.state(rid, 0)),
                     HumanModel.from_bytes(store.state(rid, 0)), 1e-7)
        arrays, ref_arrays = mine.arrays(rid, 0), store.arrays(rid, 0)
        assert arrays.keys() == ref_arrays.keys()
        for key, a in ref_arrays.items():
            np.testing.assert_allclose(arrays[key], a, rtol=0, atol=1e-7)

    # the next bag continues the run (its settings from the store): the second plan, made
    # from the model learned from the bag, is the in-process run's second plan
    bag1 = tmp_path / "cycle1.mcap"
    assert run_main(capsys, "export", str(painting_run), "--cycle", "1", "--out", str(bag1))[0] == 0
    code, stdout, err = run_main(capsys, "observe", str(tmp_path / "real"), "--bag", str(bag1),
                                 "--json")
    assert code == 0, err
    rec, ref = json.loads(stdout), records[1]
    assert (rec["cycle"], rec["human"], rec["robot"], rec["routes"]) == (
        1, ref["human"], ref["robot"], ref["routes"])
    assert rec["observed"] == pytest.approx(ref["observed"], abs=1e-7)
    with RunStore.open_readonly(tmp_path / "real" / "run.sqlite") as mine:
        _model_close(HumanModel.from_bytes(mine.state(rid, 1)),
                     HumanModel.from_bytes(store.state(rid, 1)), 1e-7)


def test_observe_takes_the_comfort_answer_and_the_bags_too_close_signals(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A simulated person who learns gamma says how close the robot came; the same cycle as a
    bag, with their "too close" signals on /rapidds/human/too_close and their answer given as
    --comfort, teaches an observing run the same gamma evidence and posterior."""
    from rapidds.bridge.bag import BagMessage, read_bag, write_bag
    from rapidds.loop.run import AdaptiveRun

    g_ref = make_world("painting").problem().objective.gamma
    small = {**SMALL, "cycles": 1, "gamma_learn": True, "comfort": 1000 * g_ref}
    sim = tmp_path / "sim"
    with RunStore(sim / "run.sqlite") as store:
        AdaptiveRun(RunConfig(**small), store=store).run()
    _, cfg, records, _ = _stored(sim)
    ref = records[0]["comfort"]
    assert ref["too_close"], "a person this sensitive signals"
    exported = tmp_path / "cycle0.mcap"
    assert run_main(capsys, "export", str(sim), "--cycle", "0", "--out", str(exported))[0] == 0
    msgs = list(read_bag(exported))
    events = [(m.time_ns, json.loads(m.msg.data)["event"]) for m in msgs
              if m.topic == ros2.EVENTS_TOPIC]
    t0 = min(t for t, e in events if e == "start")
    t1 = max(t for t, e in events if e == "end")
    empty = ros2.typestore().types["std_msgs/msg/Empty"]()
    msgs += [BagMessage(ros2.TOO_CLOSE_TOPIC, "std_msgs/msg/Empty", t0 + round(t * 1e9), empty)
             for t in ref["too_close"]]
    msgs.append(BagMessage(ros2.TOO_CLOSE_TOPIC, "std_msgs/msg/Empty", t1 + 10**9, empty))
    bag = write_bag(tmp_path / "said.mcap", sorted(msgs, key=lambda m: m.time_ns))
    run_yaml = tmp_path / "run.yaml"
    run_yaml.write_text(yaml.safe_dump(cfg))
    code, _, err = run_main(capsys, "observe", str(tmp_path / "r9"), "--bag", str(bag),
                            "--config", str(run_yaml), "--comfort", "9")
    assert code == 2 and err.count("rapidds: error:") == 1 and "--comfort" in err, err
    code, stdout, err = run_main(capsys, "observe", str(tmp_path / "real"), "--bag", str(bag),
                                 "--config", str(run_yaml), "--comfort",
                                 str(ref["answer"]), "--json")
    assert code == 0, err
    rec = json.loads(stdout)
    said = rec["comfort"]  # the signal after the cycle was dropped
    assert said["answer"] == ref["answer"]
    assert said["too_close"] == pytest.approx(ref["too_close"], abs=1e-8)
    assert said["closeness_at"] == pytest.approx(ref["closeness_at"], abs=1e-6)
    for key in ("mean", "q10", "q90", "evidence"):
        assert rec["gamma_belief"][key] == pytest.approx(records[0]["gamma_belief"][key],
                                                         rel=1e-6)
