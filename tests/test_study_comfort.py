"""`rapidds study analyze` relates the learned gamma to the stated comfort. The stores here are
PLANTED, the way tests/test_study_cli.py plants a study: records written directly with comfort
answers and gamma beliefs chosen by the test (no person and no planner produced them), so the
analysis can be checked against a relation the test knows is there, or knows is not."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from record_helpers import typed_record

from rapidds.experiments.study.analyze import analyze_study
from rapidds.experiments.study.design import StudyDesign
from rapidds.experiments.study.store import StudyStore, study_path
from rapidds.loop.config import RunConfig

ROUNDS = 3


def _planted(out: Path, *, related: bool, learn: bool = True, seed: int = 0,
             simulated_run: bool = False) -> None:
    """16 participants x 2 systems; each person has a planted comfort level, answers about it
    (+ noise) every round, and, when ``related``, the run's gamma belief grows with it."""
    rng = np.random.default_rng(seed)
    design = StudyDesign(participants=16, systems=("full", "none"), rounds=ROUNDS,
                         factors={"g": ("a",)}, require_balance=False, comfort=True)
    run = RunConfig(world="fetch", variant="default", gamma_learn=learn)
    out.mkdir(parents=True)
    with StudyStore.create(study_path(out), design, run) as st:
        for k, p in enumerate(st.participants()):
            level = rng.uniform(1.5, 6.5)  # how close this person finds the robot comes
            for system in p.systems:
                recs = []
                for c in range(ROUNDS):
                    answer = int(np.clip(round(level + rng.normal(0, 0.5)), 1, 7))
                    said: dict[str, object] = {"answer": answer, "too_close": []}
                    if simulated_run and k == 0:  # the response model answered, not a person
                        said = {**said, "answer": 1, "simulated": True}
                    belief = None
                    if learn:
                        g = 12.0 * np.exp((0.6 * (level - 4) if related else 0.0)
                                          + rng.normal(0, 0.3)) * (1 + c)
                        belief = {"mean": g, "q10": g / 2, "q90": g * 2}
                    recs.append(typed_record(cycle=c, spatial=0.3, makespan=20.0,
                                             comfort=said, gamma_belief=belief).to_json())
                st.record_trial(st.run_id(p.id, system),
                                st.config_for(p.id, system).model_dump(), recs)


def test_a_planted_relation_is_found_and_an_absent_one_is_not(tmp_path: Path) -> None:
    _planted(tmp_path / "yes", related=True)
    res = analyze_study(tmp_path / "yes").summary["comfort"]
    assert res["participants"] == 16 and len(res["runs"]) == 32
    assert all(r["rounds"] == ROUNDS for r in res["runs"])
    sp = res["spearman"]
    assert sp["rho"] > 0.6 and sp["p"] < 0.001 and 0 < sp["ci95"][0] < sp["rho"] < sp["ci95"][1]
    report = (tmp_path / "yes" / "report.md").read_text()
    assert "## Comfort and the learned gamma" in report and "Spearman's rho" in report
    _planted(tmp_path / "no", related=False, seed=1)
    sp = analyze_study(tmp_path / "no").summary["comfort"]["spearman"]
    assert sp["ci95"][0] < 0 < sp["ci95"][1]
    # the same store analysed twice gives the same interval (seeded bootstrap)
    assert analyze_study(tmp_path / "no").summary["comfort"]["spearman"] == sp


def test_the_final_round_belief_and_only_a_persons_answers_count(tmp_path: Path) -> None:
    _planted(tmp_path / "s", related=True, simulated_run=True)
    res = analyze_study(tmp_path / "s").summary["comfort"]
    runs = {(r["participant"], r["system"]): r for r in res["runs"]}
    # P01's answers came from the response model: left out, never filled in
    assert ("P01", "full") not in runs and ("P01", "none") not in runs
    assert len(runs) == 30
    with StudyStore.open_readonly(study_path(tmp_path / "s")) as st:
        rid = st.run_id("P02", "full")
        recs = st.records(rid)
    row = runs[("P02", "full")]
    assert row["gamma"] == recs[-1]["gamma_belief"]["mean"]  # after the last round
    assert row["comfort"] == np.mean([r["comfort"]["answer"] for r in recs])


def test_without_a_learned_gamma_there_is_no_correlation_but_a_statement(tmp_path: Path) -> None:
    _planted(tmp_path / "n", related=True, learn=False)
    res = analyze_study(tmp_path / "n").summary["comfort"]
    assert "spearman" not in res and "do not learn gamma" in res["skipped"]
    assert len(res["runs"]) == 32  # the answers are still reported
