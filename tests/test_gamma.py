"""Learning each person's gamma: the belief, the simulated comfort, the loop, the CLI."""

from __future__ import annotations

import json
import math
import os
import shlex
import subprocess
import sys

import numpy as np
import pytest
from cli_helpers import cli_cmd, kill_run, resume_and_compare, run_main
from conftest import SMALL_SEARCH as SMALL
from record_helpers import stored

from rapidds.cli import main
from rapidds.experiments.report import gamma_markdown, gamma_rows
from rapidds.human.gamma import GammaBelief, GammaEvidence, parse_gamma_prior
from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.loop.comfort import SimulatedComfort
from rapidds.record import CycleRecord
from rapidds.worlds.registry import make_world


def _ev(answer: int | None, peak: float, signals: int = 0, exposure: float = 0.0):
    return GammaEvidence(answer, tuple(float(k) for k in range(signals)), (1.0,) * signals,
                         peak, exposure)


def test_prior_is_centred_on_its_median_and_empty_evidence_changes_nothing():
    b = GammaBelief(3.0, 4.0, 1.75)
    assert b.mean() == 3.0 and float(np.exp(b.weights @ b.grid)) == pytest.approx(3.0, rel=1e-12)
    assert b.quantile(0.5) == pytest.approx(3.0, rel=1e-3)
    assert b.quantile(0.84) == pytest.approx(12.0, rel=0.03)  # one log-sd up: a factor 4
    before = b.log_post.copy()
    b.observe(_ev(None, 0.0))
    assert np.array_equal(b.log_post, before) and b.evidence == 0
    assert b.planning("cautious") > b.planning("mean")


def test_answers_and_signals_move_the_belief_the_right_way():
    up, down, sig = (GammaBelief(1.75, 4.0, 1.75) for _ in range(3))
    up.observe(_ev(7, 0.5))      # "much too close" at a moderate approach: a nervous person
    down.observe(_ev(1, 0.9))    # "not at all" with the robot right beside them: a relaxed one
    sig.observe(_ev(None, 0.9, signals=4, exposure=2.0))
    assert up.mean() > 1.75 * 2 and down.mean() < 1.75 / 2 and sig.mean() > 1.75 * 2
    # a far robot and a calm answer say little: the belief stays near the prior
    far = GammaBelief(1.75, 4.0, 1.75)
    far.observe(_ev(1, 0.01))
    assert abs(math.log(far.mean() / 1.75)) < abs(math.log(down.mean() / 1.75))


def test_belief_round_trips_and_learns_a_truth_from_its_own_likelihood():
    rng = np.random.default_rng(5)
    truth, b = 6.0, GammaBelief(1.75, 4.0, 1.75)
    for _ in range(12):
        peak = float(rng.uniform(0.2, 1.0))
        p = np.array([b.answer_likelihood(a, peak)[np.argmin(abs(b.grid - math.log(truth)))]
                      for a in range(1, 8)])
        b.observe(_ev(int(rng.choice(np.arange(1, 8), p=p / p.sum())), peak))
    assert abs(math.log(b.mean() / truth)) < math.log(1.5), b.summary()
    again = GammaBelief.from_dict(json.loads(json.dumps(b.to_dict())))
    assert np.array_equal(again.log_post, b.log_post) and again.summary() == b.summary()


@pytest.mark.parametrize("spec", ["", "x", "0", "-1:4", "2:1", "2:abc", "2:4:5", "nan", "inf"])
def test_malformed_prior_is_refused(spec):
    with pytest.raises(ValueError):
        parse_gamma_prior(spec)


def test_comfort_answer_outside_the_scale_is_refused():
    for answer in (0, 8, 9):
        with pytest.raises(ValueError, match="1-7"):
            GammaEvidence(answer, (), (), 0.5, 1.0)


@pytest.fixture(scope="module")
def policy(fetch_policy):
    return fetch_policy


def test_no_evidence_keeps_the_prior_and_plans_as_the_fixed_prior_gamma(policy):
    world = make_world("fetch")
    person = world.teammate("slow-middle")  # injected, with no comfort_report: says nothing
    learn = AdaptiveRun(RunConfig(human="slow-middle", cycles=3, gamma_learn=True,
                                  gamma_prior="3.5:2", **SMALL), policy, teammate=person)
    records = learn.run()
    assert learn.model.gamma is not None and learn.model.gamma.evidence == 0
    assert [r.plan.gamma for r in records] == [3.5] * 3
    assert all(r.gamma_belief is not None and r.gamma_belief["mean"] == 3.5
               and r.has_comfort and r.comfort is None for r in records)
    fixed = AdaptiveRun(RunConfig(human="slow-middle", cycles=3, gamma=3.5, **SMALL), policy,
                        teammate=person).run()
    assert fixed[0].gamma_belief is None and not fixed[0].has_comfort
    assert "gamma_belief" not in fixed[0].to_json() and "comfort" not in fixed[0].to_json()
    assert [stored(r, "gamma_belief", "comfort") for r in records] == [stored(r) for r in fixed]


def test_simulated_person_learns_and_answers_by_their_own_gamma(policy):
    run = AdaptiveRun(RunConfig(human="fast-middle", cycles=5, gamma_learn=True, comfort=8.0,
                                **SMALL), policy)
    records = [r.to_json() for r in run.run()]
    assert records[0]["gamma"] == pytest.approx(1.75)  # the first plan is the prior's
    assert all(r["comfort"]["simulated"] and r["comfort"]["true_gamma"] == 8.0 for r in records)
    assert [r["gamma"] for r in records[1:]] == [
        pytest.approx(r["gamma_belief"]["mean"]) for r in records[:-1]]
    assert abs(math.log(records[-1]["gamma_belief"]["mean"] / 8.0)) < math.log(2.0), records[-1]
    rows = gamma_rows([CycleRecord.from_json(r) for r in records])
    assert [r["planned"] for r in rows] == [r["gamma"] for r in records]
    assert [r["answer"] for r in rows] == [r["comfort"]["answer"] for r in records]
    table = gamma_markdown(rows).splitlines()
    assert len(table) == 2 + len(records) and table[-1].endswith("| 8 |")
    # one cycle with the robot close (gamma 0), felt by a relaxed and a nervous simulated person
    dep = AdaptiveRun(RunConfig(human="fast-middle", cycles=1, gamma=0.0, **SMALL),
                      policy).step().deployment
    calm, nervous = (SimulatedComfort(g, 1.75).respond(run.world, dep, 1.0,
                                                      np.random.default_rng(0))
                     for g in (0.1, 50.0))
    assert calm[0] < nervous[0] and len(calm[1]) <= len(nervous[1]), (calm, nervous)



@pytest.mark.slow
def test_resumed_learning_run_matches_uninterrupted_run(tmp_path):
    args = ["run", "--human", "fast-outside", "--cycles", "5", "--seed", "4", "--gamma", "learn",
            "--teammate-gamma", "0.4", "--population", "12", "--generations", "10", "--samples",
            "16", "--particles", "2", "--candidates", "4", "--json"]
    rid = "fetch-fast-outside-comfort0.4-full-glearn-s4"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    full = subprocess.run(cli_cmd(*args, "--out", str(tmp_path / "a")), capture_output=True,
                          text=True, env=env, timeout=300)
    assert full.returncode == 0, full.stderr
    db = tmp_path / "b" / "run.sqlite"
    kill_at = int(np.random.default_rng().integers(1, 4))
    kept = kill_run(cli_cmd(*args, "--out", str(tmp_path / "b")), db, rid, kill_at, env)
    assert kept is not None and kept < 4, "the run finished before it could be killed"
    ra, rb, ma, mb = resume_and_compare(cli_cmd(*args, "--out", str(tmp_path / "b"), "--resume"),
                                        tmp_path / "a" / "run.sqlite", db, env)
    assert len(ra) == 5 and [stored(r) for r in ra] == [stored(r) for r in rb]
    assert all("gamma_belief" in r for r in ra)
    assert ma.gamma is not None and mb.gamma is not None
    assert ma.gamma.to_dict() == mb.gamma.to_dict()
    assert (tmp_path / "b" / f"{rid}-gamma.png").stat().st_size > 0


BAD = [
    ("run --gamma learn --gamma-prior 1.75:x", "a gamma prior is G or G:SPREAD"),
    ("run --gamma learn --gamma-prior 0", "a gamma prior needs G > 0"),
    ("run --gamma-prior 2", "needs --gamma learn"),
    ("run --gamma lots", "--gamma is a number >= 0 or 'learn'"),
    ("run --gamma learn --gamma-plan bold", "--gamma-plan: Input should be 'mean' or"),
    ("run --teammate-gamma 0", "--teammate-gamma: Input should be greater than 0"),
    ("gamma --answer 9@0.5", "a comfort answer is an integer 1-7"),
    ("gamma --answer 5@2", "closeness PEAK is in [0, 1]"),
    ("gamma --answer five", "an answer is A@PEAK"),
    ("gamma --prior 1:1 --answer 5@0.5", "a gamma prior needs G > 0"),
]


@pytest.mark.parametrize(("command", "answer"), BAD)
def test_bad_gamma_input_gets_one_line_and_exit_2(command, answer, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["rapidds", *shlex.split(command)])
    with pytest.raises(SystemExit) as exit_:
        main()
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert exit_.value.code == 2, err
    assert len(lines) == 1 and lines[0].startswith("rapidds: error: ") and answer in lines[0], err


def test_gamma_command_prints_the_posterior_after_each_answer(capsys):
    code, out, err = run_main(capsys, "gamma", "--prior", "2:4", "--answer", "7@0.6",
                              "--answer", "7@0.9", "--signals", "3@2", "--json")
    assert code == 0, err
    rows = [json.loads(x) for x in out.splitlines()]
    assert [r["step"] for r in rows] == [0, 1, 2, 3] and rows[0]["mean"] == 2.0
    assert [r["evidence"] for r in rows] == [0, 1, 2, 3]
    assert rows[1]["given"]["answer"] == 7 and len(rows[3]["given"]["too_close"]) == 3
    # "much too close" every time: a person more nervous than the prior, ever more surely
    assert all(r["mean"] > 2 * rows[0]["mean"] for r in rows[1:])
    assert rows[0]["sd_log"] > rows[1]["sd_log"] > rows[2]["sd_log"] > rows[3]["sd_log"]
