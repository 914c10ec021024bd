"""``rapidds study design / simulate / analyze``: files written, designs never mixed, bad input
one line and exit 2, a tiny simulated study on Dask analysed, and the analysis finding an effect
planted in a store (and not one that is absent)."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_main as _main
from record_helpers import stored, typed_record

from rapidds.experiments.study.analyze import analyze_study, round_table
from rapidds.experiments.study.design import StudyDesign
from rapidds.experiments.study.simulate import simulated_participant
from rapidds.experiments.study.store import StudyStore, study_path
from rapidds.experiments.study.systems import adapts
from rapidds.worlds.registry import make_world

TINY = ["--population", "6", "--generations", "2", "--samples", "8", "--particles", "1",
        "--candidates", "2"]


def _one_line(code: int, err: str, needle: str) -> None:
    assert code == 2, err
    assert "Traceback" not in err and err.count("\n") == 1, err
    assert needle in err, err


def test_design_writes_csv_and_store_and_never_mixes_designs(tmp_path, capsys):
    out = tmp_path / "s"
    code, stdout, err = _main(capsys, "study", "design", "--participants", "16", "--out",
                              str(out), "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["participants"] == 16 and summary["world"] == "painting"
    assert summary["variant"] == "unconstrained" and summary["gamma"] == 12.0
    assert StudyDesign.from_csv(out / "design.csv") == StudyDesign(participants=16)
    with StudyStore.open_readonly(out / "study.sqlite") as st:
        assert st.design == StudyDesign(participants=16)
        assert st.items.ids[-1] == "robot_in_the_way"
    before = (out / "study.sqlite").read_bytes()
    code, _, err = _main(capsys, "study", "design", "--participants", "16", "--out", str(out))
    assert code == 0, err  # the same design again
    code, _, err = _main(capsys, "study", "design", "--participants", "32", "--out", str(out))
    _one_line(code, err, "already holds a different study design")
    code, _, err = _main(capsys, "study", "design", "--participants", "16", "--gamma", "25",
                         "--out", str(out))
    _one_line(code, err, "already holds a different study (run differs)")
    assert (out / "study.sqlite").read_bytes() == before


@pytest.mark.parametrize(("args", "needle"), [
    (["--participants", "15"], "multiple of 16"),
    (["--systems", "full,magic"], "unknown"),
    (["--systems", "full,full"], "named twice"),
    (["nowhere"], "unknown world 'nowhere'"),
    (["--variant", "sideways"], "no variant 'sideways'"),
    (["--rounds", "0"], "rounds"),
    (["--items", "missing.yaml"], "missing.yaml: no such file"),
    (["--gamma", "-1"], "--gamma"),
    (["--learn-gamma"], "--learn-gamma needs --comfort-item"),
    (["--execution", "sideways"], "--execution: must be one of planned, reactive"),
    (["--deviate", "1.5"], "--deviate: Input should be less than or equal to 1"),
    (["--deviate", "-0.1"], "--deviate: Input should be greater than or equal to 0"),
])
def test_design_bad_input_is_one_line(tmp_path, capsys, args, needle):
    code, _, err = _main(capsys, "study", "design", "--out", str(tmp_path / "s"), *args)
    _one_line(code, err, needle)
    assert not (tmp_path / "s" / "study.sqlite").exists()


def test_a_fetch_design_primes_fetchs_groups_and_keeps_its_own_task_bound(tmp_path, capsys):
    out = tmp_path / "f"
    code, _, err = _main(capsys, "study", "design", "fetch", "--participants", "16",
                         "--max-task-seconds", "45", "--out", str(out), "--json")
    assert code == 0, err
    with StudyStore.open_readonly(study_path(out)) as st:
        groups = {p.group for p in st.participants()}
        assert groups == set(make_world("fetch").teammate_names)  # fast-middle ..., no left-fast
        assert st.design.factors == {"speed": ("fast", "slow"), "route": ("middle", "outside")}
        assert st.design.max_task_s == 45.0
    code, _, err = _main(capsys, "study", "design", "fetch", "--participants", "16",
                         "--out", str(out))
    _one_line(code, err, "already holds a different study design")  # another bound


def test_a_design_with_the_comfort_item_learns_gamma_when_asked(tmp_path, capsys):
    out = tmp_path / "c"
    code, _, err = _main(capsys, "study", "design", "--participants", "16", "--comfort-item",
                         "--learn-gamma", "--out", str(out))
    assert code == 0, err
    with StudyStore.open_readonly(study_path(out)) as st:
        assert st.design.comfort and st.base_config.gamma_learn
        assert st.config_for("P01", "full").gamma_learn  # every run of the study learns
    code, _, err = _main(capsys, "study", "design", "--participants", "16", "--comfort-item",
                         "--out", str(tmp_path / "d"))
    assert code == 0, err
    with StudyStore.open_readonly(study_path(tmp_path / "d")) as st:
        assert st.design.comfort and not st.base_config.gamma_learn


def test_a_design_stores_the_execution_inside_the_round(tmp_path, capsys):
    """--execution/--reacts/--deviate are run settings of the study: stored with the design,
    so every run of it (served or simulated) has them; the default is the paper's planned robot,
    and a store written without them reads as planned."""
    out = tmp_path / "r"
    code, stdout, err = _main(capsys, "study", "design", "--participants", "16", "--execution",
                              "reactive", "--reacts", "--deviate", "0.25", "--out", str(out),
                              "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    assert (summary["execution"], summary["reacts"], summary["deviate"]) == ("reactive", True,
                                                                           0.25)
    with StudyStore.open_readonly(study_path(out)) as st:
        cfg = st.config_for("P03", "none")
        assert (cfg.execution.kind, cfg.reacts, cfg.deviate) == ("reactive", True, 0.25)
        assert "-reactive-reacts-dev0.25-" in cfg.run_id
    code, _, err = _main(capsys, "study", "design", "--participants", "16", "--out", str(out))
    _one_line(code, err, "already holds a different study (run differs)")  # planned != reactive
    code, stdout, err = _main(capsys, "study", "design", "--participants", "16", "--out",
                              str(tmp_path / "p"), "--json")
    assert code == 0, err
    assert json.loads(stdout)["execution"] == "planned"
    path = study_path(tmp_path / "p")
    with sqlite3.connect(path) as con:  # a store from before these settings existed
        run = json.loads(con.execute("SELECT value FROM meta WHERE key='run'").fetchone()[0])
        assert run["execution"] == "planned"
        old = {k: v for k, v in run.items() if k not in ("execution", "reacts", "deviate")}
        con.execute("UPDATE meta SET value=? WHERE key='run'", (json.dumps(old),))
    with StudyStore.open_readonly(path) as st:
        assert st.config_for("P01", "full").execution.kind == "planned"


def test_design_with_own_items_and_foreign_store(tmp_path, capsys):
    items = tmp_path / "items.yaml"
    items.write_text("items:\n  - {id: calm, text: I felt calm.}\n")
    out = tmp_path / "s"
    code, _, err = _main(capsys, "study", "design", "--participants", "16", "--items",
                         str(items), "--out", str(out))
    assert code == 0, err
    with StudyStore.open_readonly(study_path(out)) as st:
        assert st.items.ids == ("calm",)
    other = tmp_path / "o"
    other.mkdir()
    db = sqlite3.connect(other / "study.sqlite")
    db.execute("CREATE TABLE t (x)")
    db.commit()
    db.close()
    code, _, err = _main(capsys, "study", "design", "--out", str(other))
    _one_line(code, err, "not a rapidds study store")
    code, _, err = _main(capsys, "study", "analyze", str(other))
    _one_line(code, err, "not a rapidds study store")
    code, _, err = _main(capsys, "study", "analyze", str(tmp_path / "nothing"))
    _one_line(code, err, "no such study store")


def test_the_study_package_loads_its_statistics_only_when_asked():
    """The CLI reads the study's systems from the package itself (no copy), so importing it
    must not load pingouin; asking for a statistic does."""
    code = ("import sys, rapidds.cli.study, rapidds.experiments.study as s\n"
            "print('pingouin' in sys.modules, end=' ')\ns.rm_anova_2x2\n"
            "print('pingouin' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True)
    assert out.stdout.split() == ["False", "True"]


def test_simulated_participants_are_individuals_of_their_group():
    world = make_world("painting")
    a = simulated_participant(world, "P01", {"hand": "left", "speed": "fast"}, 0, 1)
    again = simulated_participant(world, "P01", {"hand": "left", "speed": "fast"}, 0, 1)
    b = simulated_participant(world, "P02", {"hand": "left", "speed": "fast"}, 0, 2)
    slow = simulated_participant(world, "P03", {"hand": "right", "speed": "slow"}, 0, 3)
    assert a.means == again.means and a.habit_seed == again.habit_seed  # same seed, same person
    assert a.means != b.means and a.habit_seed != b.habit_seed  # each their own
    assert a.hand == "left" and slow.hand == "right"
    assert 3.0 <= a.means["brush"] <= 3.8 and 6.2 <= slow.means["brush"] <= 7.0
    assert not np.allclose(a.nominal_path("secure_piece"), b.nominal_path("secure_piece"))
    with pytest.raises(Exception, match="priming factor"):
        simulated_participant(world, "P04", {"hand": "left"}, 0, 4)


@pytest.mark.slow
def test_tiny_simulated_study_on_dask_resumes_and_is_analysed(tmp_path, capsys):
    out = tmp_path / "sim"
    args = ["study", "simulate", "--participants", "2", "--systems", "full,none", "--rounds",
            "2", "--allow-unbalanced", "--workers", "1", "--out", str(out), "--json", *TINY]
    code, stdout, err = _main(capsys, *args)
    assert code == 0, err
    first = json.loads(stdout)
    assert first["simulated"]["ran"] == 4 and first["runs_finished"] == 4
    with StudyStore.open_readonly(study_path(out)) as st:
        rounds = round_table(st)
        assert len(rounds) == 2 * 2 * 2
        assert (rounds["temporal_cost"] > 0).all() and (rounds["spatial_cost"] >= 0).all()
        # simulated people answer nothing: the next step of everyone is the first survey
        assert st.survey_frame().empty and st.rankings() == {}
        assert {s.kind for s in st.progress().values()} == {"survey"}
        # each system at its adaptation level: "none" keeps the population prior, "full" learns
        full = st.records(st.run_id("P01", "full"))
        none = st.records(st.run_id("P01", "none"))
        assert none[0]["belief"] == none[1]["belief"]
        assert full[0]["belief"] != none[0]["belief"]
        assert "executed" not in full[0]  # the paper's planned robot: no in-cycle record
    code, stdout, err = _main(capsys, *args)  # resume: nothing left to run
    assert code == 0, err
    assert json.loads(stdout)["simulated"]["ran"] == 0
    # its runs keep their network's fingerprint; another network is refused, nothing written
    import torch

    from rapidds.loop.run import load_policy

    with StudyStore.open_readonly(study_path(out)) as st:
        world = make_world(st.base_config.world, st.base_config.variant)
    bundled, other = (load_policy(world, device="cpu") for _ in range(2))
    with torch.no_grad():
        next(other.model.parameters()).mul_(1.01)
    other.save(tmp_path / "other")
    before = study_path(out).read_bytes()
    code, _, err = _main(capsys, *args, "--policy", str(tmp_path / "other"))
    assert code == 2 and err.count("\n") == 1, err
    assert "planned with another network" in err and bundled.fingerprint() in err
    assert study_path(out).read_bytes() == before
    code, stdout, err = _main(capsys, "study", "analyze", str(out), "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    assert "2 rounds < 4" in summary["objective"]["skipped"]
    assert "simulated participants rank nothing" in summary["ranking"]["skipped"]
    assert "simulated participants answer nothing" in summary["survey"]["skipped"]
    assert (out / "report.md").read_text().startswith("# User study analysis")


def test_a_simulated_study_under_reactive_execution_runs_on_the_executor(tmp_path, capsys):
    """The study's stored execution settings reach the simulated participants' runs: every
    round is a reactive cycle (the executor's record of it), the people react and deviate."""
    out = tmp_path / "re"
    code, stdout, err = _main(capsys, "study", "simulate", "--participants", "2", "--systems",
                              "full,none", "--rounds", "1", "--allow-unbalanced", "--workers",
                              "1", "--execution", "reactive", "--reacts", "--deviate", "1",
                              "--out", str(out), "--json", *TINY)
    assert code == 0, err
    assert json.loads(stdout)["execution"] == "reactive"
    with StudyStore.open_readonly(study_path(out)) as st:
        runs = st.study_runs()
        assert len(runs) == 4
        for rid in runs["run_id"]:
            assert "-reactive-reacts-dev1-" in rid
            (rec,) = st.records(rid)
            assert {"executed", "pauses", "replans", "protective"} <= set(rec)
            assert rec["protective"] is not None
            assert rec["deviation"] is not None  # --deviate 1: every round deviates


def _planted_store(out: Path, spatial_effect: float, seed: int = 0) -> None:
    """A 16-participant study whose rounds carry a planted spatial-cost drop for the spatially
    adaptive systems (test data for the analysis, written through the store's API), with
    rankings and survey answers as if typed in."""
    from rapidds.loop.config import RunConfig

    rng = np.random.default_rng(seed)
    design = StudyDesign(participants=16, rounds=5, seed=seed)
    run = RunConfig(world="painting", variant="unconstrained")
    with StudyStore.create(study_path(out), design, run) as st:
        for p in st.participants():
            for system in p.systems:
                spatial = adapts(system, "spatial")
                recs = []
                for k in range(design.rounds):
                    drop = spatial_effect * (k > 0) if spatial else 0.0
                    recs.append(typed_record(
                        cycle=k, spatial=0.3 - drop + rng.normal(0, 0.02),
                        makespan=20.0 + rng.normal(0, 0.5)).to_json())
                st.record_trial(st.run_id(p.id, system),
                                st.config_for(p.id, system).model_dump(), recs)
                answers = {i: int(rng.integers(1, 8)) for i in st.items.ids}
                if spatial:
                    answers["robot_in_the_way"] = int(rng.integers(1, 3))
                else:
                    answers["robot_in_the_way"] = int(rng.integers(5, 8))
                st.submit_survey(p.id, system, answers)
            ranking = sorted(p.systems, key=lambda s: (not adapts(s, "spatial"), rng.random()))
            st.submit_ranking(p.id, ranking)
            st.submit_demographics(p.id, {"age": "22"})


def test_analysis_finds_a_planted_effect_and_not_an_absent_one(tmp_path):
    _planted_store(tmp_path / "yes", spatial_effect=0.1)
    res = analyze_study(tmp_path / "yes")
    claims = res.summary["objective"]["claims"]
    assert claims["spatial_cost_reduction"]["holds"]
    assert claims["spatial_cost_reduction"]["p"] < 0.001
    assert not claims["temporal_cost_reduction"]["holds"]  # nothing planted there
    assert res.summary["ranking"]["p"] < 0.001 and res.summary["ranking"]["r"] > 0.9
    art = {(r["item"], r["effect"]): r for r in res.summary["survey"]["art"]}
    assert art[("robot_in_the_way", "spatial")]["p"] < 0.001
    assert all(r["alignment_ok"] for r in art.values())
    for name in ("report.md", "summary.json", "study_costs.png", "study_rounds.png",
                 "study_ranking.png", "study_survey.png"):
        assert (tmp_path / "yes" / name).stat().st_size > 0
    report = (tmp_path / "yes" / "report.md").read_text()
    assert "n = 16" in report and "signed-rank" in report and "robot_in_the_way" in report
    _planted_store(tmp_path / "no", spatial_effect=0.0, seed=1)
    none = analyze_study(tmp_path / "no").summary["objective"]["claims"]
    assert not none["spatial_cost_reduction"]["holds"]


def test_a_given_prior_plans_exactly_as_the_computed_one(fetch_world, fetch_policy, small):
    """The simulated study hands every run one prior computed per worker: the runs must be the
    ones they would be with their own, and learn into their own copy."""
    from rapidds.loop.config import RunConfig
    from rapidds.loop.model import prior_model
    from rapidds.loop.run import AdaptiveRun

    cfg = RunConfig(world="fetch", human="fast-middle", adapt="full", cycles=2, seed=3,
                    **small).resolved(fetch_world)
    prior = prior_model(fetch_world, cfg)
    before = prior.to_bytes()
    own = AdaptiveRun(cfg, fetch_policy, world=fetch_world).run()
    shared = AdaptiveRun(cfg, fetch_policy, world=fetch_world, prior=prior).run()
    assert [stored(r) for r in own] == [stored(r) for r in shared]
    assert prior.to_bytes() == before  # the run learned into a copy
