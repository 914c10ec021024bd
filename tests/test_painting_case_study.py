"""The painting case study: cycle records read in the paper's terms, the behaviours in whole runs
of the loop, ``rapidds case-study painting``, ``rapidds train-policy --world painting`` against
the shipped checkpoint, and bad input (corrupt scene and checkpoint) through the CLI."""

from __future__ import annotations

import json
import shutil
import sys

import numpy as np
import pytest
from record_helpers import typed_record
from safetensors.torch import load_file

from rapidds.cli import main
from rapidds.errors import CheckpointError
from rapidds.experiments.painting import (
    SETTINGS,
    cell_state,
    expectations,
    run_setting,
    setting_behaviours,
    table_markdown,
    table_rows,
)
from rapidds.record import CycleRecord
from rapidds.schedule import task_items
from rapidds.store import RunStore
from rapidds.worlds.painting import PaintingWorld
from rapidds.worlds.painting.cycles import loop_behaviours, summarize_record


def _record(robot: list[str], human: list[str], timeline: dict[str, list[float]],
            expected: dict[str, list[str]], lam: float = 0.0, cycle: int = 0) -> CycleRecord:
    routes = {t: "avoidant" if t == "mix_l" else "direct" for t in task_items(robot)}
    realised = {j: [h for h in ("prep_vise", "secure_piece")
                    if timeline[j][0] < timeline[h][1] and timeline[h][0] < timeline[j][1]]
                for j in routes}
    return typed_record(cycle=cycle, lam=lam, robot=robot, human=human, routes=routes,
                        expected_overlaps=expected, expected_spatial=0.1, timeline=timeline,
                        realised_overlaps=realised, spatial=0.2, min_separation=0.25,
                        makespan=20.0)


def test_a_record_reads_as_the_paper_speaks_of_it() -> None:
    rec = _record(["mix_r", "mix_l", "brush"], ["prep_vise", "secure_piece"],
                  {"prep_vise": [0.0, 6.0], "secure_piece": [6.0, 11.0], "mix_r": [0.0, 4.8],
                   "mix_l": [4.8, 12.45], "brush": [12.45, 17.1]},
                  {"mix_r": ["prep_vise"], "mix_l": ["prep_vise", "secure_piece"], "brush": []})
    s = summarize_record(rec)
    assert s.plan.first == "mix_r" and s.plan.during == {"mix_l": "avoidant"}
    assert s.during_realised == ("mix_l",) and s.brusher == "robot"
    assert not s.plan.idle and s.waits == ()
    assert s.durations["mix_l"] == pytest.approx(7.65)
    constrained = loop_behaviours([rec], "constrained", 12.0, "mix_l")
    assert [b.shown for b in constrained] == [(), (0,)]  # prior: direct expected; learned: yes

    # a person who waits for the mixes before Prep Vise is idle, wait token or not
    waited = _record(["mix_r", "mix_l", "brush"], ["wait:mix_r", "prep_vise", "secure_piece"],
                     {"prep_vise": [4.8, 10.8], "secure_piece": [10.8, 15.8],
                      "mix_r": [0.0, 4.8], "mix_l": [4.8, 9.6], "brush": [15.8, 20.4]},
                     {"mix_r": [], "mix_l": ["prep_vise"], "brush": []})
    s = summarize_record(waited)
    assert s.plan.idle and s.waits == ("person 4.8 s before prep_vise",) and not s.plan.during
    # a wait token that costs nothing is no wait
    free = _record(["mix_l", "wait:prep_vise", "mix_r", "brush"], ["prep_vise", "secure_piece"],
                   {"prep_vise": [0.0, 4.0], "secure_piece": [4.0, 9.0], "mix_l": [0.0, 4.8],
                    "mix_r": [4.8, 9.6], "brush": [9.6, 14.2]},
                   {"mix_l": ["prep_vise", "secure_piece"], "mix_r": ["secure_piece"],
                    "brush": []})
    assert summarize_record(free).waits == ()


def test_exploration_cycles_test_nothing_but_the_first() -> None:
    base = {"prep_vise": [0.0, 6.0], "secure_piece": [6.0, 11.0], "mix_l": [0.0, 4.8],
            "mix_r": [4.8, 9.6], "brush": [11.0, 15.6]}
    recs = [_record(["mix_l", "mix_r", "brush"], ["prep_vise", "secure_piece"], base,
                    {"mix_l": ["prep_vise"], "mix_r": ["prep_vise", "secure_piece"],
                     "brush": []}, lam=lam, cycle=c)
            for c, lam in enumerate((10.0, 10.0, 0.0, 0.0))]
    found = loop_behaviours(recs, "unconstrained", 12.0, "mix_l", brusher="human")
    assert [(b.belief, b.cycles) for b in found] == [("prior", (0,)), ("learned", (2, 3)),
                                                     ("learned", (2, 3))]
    assert found[1].holds and not found[2].holds  # mix_l first, mix_r direct; robot brushed


def test_expectations_follow_the_teammate_not_a_hand() -> None:
    w = PaintingWorld()
    assert expectations(w, "left-slow") == ("mix_l", "robot")
    assert expectations(w, "right-fast") == ("mix_r", "human")


@pytest.fixture(scope="module")
def world() -> PaintingWorld:
    return PaintingWorld()


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_gamma_85_robot_keeps_still_during_secure_piece_before_learning(world, seed) -> None:
    """The fourth behaviour's first half in whole runs (the tests that every seed of the sweep
    passed; the rates of all behaviours are in docs/reproduction.md)."""
    setting = SETTINGS[3]
    recs = run_setting(setting, "left-slow", seed, cycles=1)  # cycle 0 is that of 7 cycles
    found = {b.belief: b for b in setting_behaviours(world, setting, "left-slow", recs)}
    assert found["prior"].holds, table_markdown(table_rows(world, "left-slow", {setting: recs}))
    first = summarize_record(recs[0])
    assert first.during_realised == () or first.plan.during == {}


@pytest.mark.slow
def test_brush_goes_to_the_faster_person_once_exploration_ends(world) -> None:
    """Temporal adaptation in a whole 7-cycle run (every seed of the sweep shows it): a person
    who brushes faster than the robot gets Brush in every cycle after exploration."""
    setting = SETTINGS[0]
    recs = run_setting(setting, "left-fast", 0, cycles=7)
    brush = setting_behaviours(world, setting, "left-fast", recs)[-1]
    assert brush.name == "Brush with the faster agent (human)" and brush.cycles == (4, 5, 6)
    assert brush.holds, table_markdown(table_rows(world, "left-fast", {setting: recs}))


def test_cell_state_follows_the_stored_cycle(world) -> None:
    q_mix = world.robot_trajectory("mix_l")
    body = np.repeat(world.human_rest()[None], 5, axis=0)
    body[:, 0, 0] += np.arange(5) * 0.01
    rec = _record(["mix_l", "mix_r", "brush"], ["prep_vise", "secure_piece"],
                  {"prep_vise": [0.0, 1.0], "secure_piece": [1.0, 1.6], "mix_l": [1.0, 10.6],
                   "mix_r": [10.6, 20.0], "brush": [20.0, 25.0]}, {})
    arrays = {"robot/mix_l": q_mix, "human/secure_piece": body}
    q, b = cell_state(world, rec, arrays, 1.0 + 3 * world.dt)
    np.testing.assert_array_equal(q, q_mix[3])
    np.testing.assert_allclose(b[0, 0], world.human_rest()[0, 0] + 0.03)
    q, _ = cell_state(world, rec, arrays, 30.0)
    np.testing.assert_array_equal(q, world.robot_rest())


def _cli(argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture,
         ) -> tuple[int, str, str]:
    monkeypatch.setattr(sys, "argv", ["rapidds", *argv])
    with pytest.raises(SystemExit) as exit_:
        main()
    out = capsys.readouterr()
    return int(exit_.value.code or 0), out.out, out.err


@pytest.mark.slow
def test_case_study_writes_table_pictures_and_resumes(tmp_path, monkeypatch, capsys) -> None:
    out = tmp_path / "cs"
    argv = ["case-study", "painting", "--out", str(out), "--cycles", "1", "--settings",
            "unconstrained-g85", "--json", "--no-gif"]
    rc, stdout, err = _cli(argv, monkeypatch, capsys)
    assert rc == 0, err
    data = json.loads(stdout)
    assert [r["cycle"] for r in data["rows"]] == ["0"]
    assert [b["belief"] for b in data["behaviours"]["unconstrained-g85"]] == ["prior", "learned"]
    sub = out / "unconstrained-g85"
    rid = "painting-unconstrained-left-slow-full-s0"
    for name in (f"{rid}-map.png", f"{rid}-map-side.png", f"{rid}-cost.png"):
        assert (sub / name).stat().st_size > 10_000
    md = (out / "table.md").read_text()
    assert md.count("\n") == 3 and "unconstrained-g85" in md
    assert (out / "table.csv").read_text().splitlines()[0].startswith("setting,cycle,lambda")
    # again: nothing to run, the same table
    rc, stdout2, err = _cli(argv, monkeypatch, capsys)
    assert rc == 0 and json.loads(stdout2)["rows"] == data["rows"], err


def test_train_policy_cli_reproduces_the_shipped_training(tmp_path, monkeypatch, capsys,
                                                          world) -> None:
    """The CLI trains on the shipped checkpoint's data (its normaliser is computed from them:
    equal to the bit) with its configuration, and its weights are the library path's."""
    from rapidds.motion.config import DiffusionConfig
    from rapidds.motion.demos import Demonstrations
    from rapidds.motion.train import train_policy

    rc, _, err = _cli(["train-policy", "--world", "painting", "--out", str(tmp_path / "p"),
                       "--steps", "3", "--seed", "0"], monkeypatch, capsys)
    assert rc == 0, err
    bundled = world.bundled_policy()
    assert bundled is not None
    shipped = json.loads((bundled / "config.json").read_text())
    mine = json.loads((tmp_path / "p" / "config.json").read_text())
    assert mine["normalizer"] == shipped["normalizer"]
    assert {**mine["config"], "steps": 5000} == shipped["config"]

    d = world.robot_demonstrations(64, np.random.default_rng(0))
    demos = Demonstrations(d.trajectories.astype(np.float32), d.task_index, d.task_names)
    cfg = DiffusionConfig.from_dict({**world.policy_defaults, "horizon": demos.horizon,
                                     "state_dim": demos.state_dim,
                                     "task_names": list(demos.task_names),
                                     "start_conditioned": False, "steps": 3, "seed": 0})
    policy, _ = train_policy(demos, cfg)
    policy.save(tmp_path / "lib")
    a = load_file(str(tmp_path / "p" / "model.safetensors"))
    b = load_file(str(tmp_path / "lib" / "model.safetensors"))
    assert a.keys() == b.keys() and all(bool((a[k] == b[k]).all()) for k in a)


def test_the_shipped_student_is_its_command_and_samples_like_its_teacher(
        tmp_path, monkeypatch, capsys, world) -> None:
    """The distilled checkpoint (docs/benchmarks.md, "A distilled network") is what its
    documented command writes, by name through --policy, and its samples complete their task
    as the paper's network's nearly all do (an under-trained student's 1-6 % would fail)."""
    from rapidds.loop.context import load_policy
    from rapidds.motion.train import check_teacher
    from rapidds.worlds.base import shipped_policies

    shipped = shipped_policies(world)
    assert list(shipped) == ["paper", "distilled"] and shipped["paper"] == world.bundled_policy()
    (tmp_path / "small.json").write_text(json.dumps({"down_dims": [16, 32]}))
    rc, _, err = _cli(["train-policy", "--world", "painting", "--teacher", str(shipped["paper"]),
                       "--config", str(tmp_path / "small.json"), "--out", str(tmp_path / "s"),
                       "--steps", "3", "--seed", "0", "--device", "cpu"], monkeypatch, capsys)
    assert rc == 0, err
    want = json.loads((shipped["distilled"] / "config.json").read_text())
    mine = json.loads((tmp_path / "s" / "config.json").read_text())
    assert mine["normalizer"] == want["normalizer"]
    assert {**mine["config"], "steps": want["config"]["steps"]} == want["config"]

    student, teacher = load_policy(world, "distilled", "cpu"), load_policy(world, "paper", "cpu")
    check_teacher(teacher, student.config)
    assert sum(p.numel() for p in student.model.parameters()) < 0.2 * sum(
        p.numel() for p in teacher.model.parameters())
    paths = student.sample("mix_l", 64, generator=7)
    assert (world.completion_time("mix_l", paths) < world.penalty).mean() >= 0.9
    with pytest.raises(CheckpointError, match=r"ships no policy of that name \(paper, distil"):
        load_policy(world, "distiled")


def test_corrupt_checkpoint_and_scene_get_one_line(tmp_path, monkeypatch, capsys,
                                                   world) -> None:
    bundled = world.bundled_policy()
    assert bundled is not None
    bad = tmp_path / "policy"
    shutil.copytree(bundled, bad)
    (bad / "model.safetensors").write_bytes(b"not weights")
    rc, _, err = _cli(["run", "painting", "--policy", str(bad), "--cycles", "1"],
                      monkeypatch, capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("rapidds: error: "), err

    from rapidds.worlds.painting import kinematics, scene

    assets = tmp_path / "franka"
    shutil.copytree(scene.franka_assets_dir(), assets)
    (assets / "chain.xml").write_text("<mujoco><worldbody><body")  # cut off
    monkeypatch.setattr(scene, "franka_assets_dir", lambda: assets)
    scene.load_model.cache_clear()
    kinematics.arm_kinematics.cache_clear()
    try:
        rc, _, err = _cli(["run", "painting", "--cycles", "1"], monkeypatch, capsys)
    finally:
        scene.load_model.cache_clear()
        kinematics.arm_kinematics.cache_clear()
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    assert lines[0].startswith("rapidds: error: cannot build the painting scene"), err


def test_case_study_reactive_column_comes_from_stored_reactive_runs(tmp_path, monkeypatch,
                                                                     capsys) -> None:
    out = tmp_path / "cs"
    argv = ["case-study", "painting", "--out", str(out), "--cycles", "1", "--settings",
            "unconstrained-g85", "--json", "--no-gif", "--execution", "planned,reactive"]
    rc, stdout, err = _cli(argv, monkeypatch, capsys)
    assert rc == 0, err
    data = json.loads(stdout)
    (row,) = data["rows"]
    assert "unconstrained-g85-reactive" in data["behaviours"]
    rid = "painting-unconstrained-left-slow-full-s0"
    with RunStore.open_readonly(out / "unconstrained-g85-reactive" / "run.sqlite") as st:
        (rec,) = st.records("painting-unconstrained-left-slow-full-reactive-s0")
    assert row["reactive makespan (s)"] == f"{rec['realised']['makespan']:.2f}"
    assert row["reactive min sep. (m)"] == f"{rec['realised']['min_separation']:.3f}"
    assert row["reactive pauses/replans"] == f"{len(rec['pauses'])}/{len(rec['replans'])}"
    with RunStore.open_readonly(out / "unconstrained-g85" / "run.sqlite") as st:
        (paper,) = st.records(rid)
    assert row["makespan (s)"] == f"{paper['realised']['makespan']:.2f}"  # the paper's beside
    assert "replans" in rec and "replans" not in paper  # only the reactive record has them
    header = (out / "table.csv").read_text().splitlines()[0]
    assert header.endswith("reactive makespan (s),reactive min sep. (m),reactive pauses/replans")
    assert "reactive pauses/replans" in (out / "table.md").read_text()
