"""The multi-cycle loop with the bundled fetch policy and small search settings."""

from __future__ import annotations

import json
import os
import subprocess

import numpy as np
import pytest
from cli_helpers import cli_cmd, kill_run, resume_and_compare
from conftest import SMALL_SEARCH as SMALL
from record_helpers import stored

from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.loop.observation import Observation
from rapidds.schedule import Wait


@pytest.fixture(scope="module")
def policy(fetch_policy):
    return fetch_policy


def test_full_adaptation_learns_a_slow_teammate(policy):
    run = AdaptiveRun(RunConfig(human="slow-middle", adapt="full", cycles=16, **SMALL), policy)
    records = run.run()
    assert [r.cycle for r in records] == list(range(16))
    truth = run.teammate.true_mean_durations()
    temporal = run.model.temporal
    counts = {t: sum(t in r.observed for r in records) for t in truth}
    learned = [t for t, n in counts.items() if n >= 3]
    assert len(learned) >= 2, counts  # exploration made the person do several tasks
    mean = dict(zip(run.problem.ids, temporal.mean(), strict=True))
    for t in learned:
        assert abs(mean[t] - truth[t]) / truth[t] < 0.10, (t, mean[t], truth[t], counts)
    # the spatial model puts high cost on the route this person takes for a bottom object
    bottom = [t for t in ("t2", "t3") if counts[t] >= 2]
    assert bottom, counts
    prior = AdaptiveRun(RunConfig(human="slow-middle", **SMALL), policy).model.spatial
    lane = {"t2": (0.7, 3.8), "t3": (9.3, 3.8)}  # where an outside walker passes the blocks
    for t in bottom:
        pts = np.array([[5.0, 3.8], lane[t]])  # the central corridor, the edge lane
        learned = run.model.spatial[t].point_cost(pts)
        before = prior[t].point_cost(pts)
        assert learned[0] - learned[1] > before[0] - before[1] + 0.2, (t, learned, before)
        assert learned[0] > 0.6, (t, learned)


@pytest.mark.parametrize("human", ["fast-middle", "slow-middle"])
def test_oracle_is_the_floor(policy, human):
    # Teammates whose truth differs from the population prior in time (slow) or space (middle);
    # for the others the prior already leads to the oracle's plan and the two tie.
    costs = {}
    for adapt in ("oracle", "none"):
        vals = []
        for seed in (0, 1):
            cfg = RunConfig(human=human, adapt=adapt, cycles=4, lam=0.0, seed=seed, **SMALL)
            vals += [r.realised.cost for r in AdaptiveRun(cfg, policy).run()]
        costs[adapt] = float(np.mean(vals))
    assert costs["oracle"] < costs["none"], costs


def test_same_seed_same_records(policy, tmp_path):
    cfg = RunConfig(human="fast-outside", cycles=2, **SMALL)
    a = [stored(r) for r in AdaptiveRun(cfg, policy).run()]
    b = [stored(r) for r in AdaptiveRun(cfg, policy).run()]
    assert a == b



@pytest.mark.slow
def test_resume_after_kill_matches_uninterrupted_run(tmp_path):
    args = ["run", "--human", "slow-middle", "--cycles", "5", "--seed", "3",
            "--population", "12", "--generations", "10", "--samples", "16",
            "--particles", "2", "--candidates", "4", "--json"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    full = subprocess.run(cli_cmd(*args, "--out", str(tmp_path / "a")), capture_output=True,
                          text=True, env=env, timeout=300)
    assert full.returncode == 0, full.stderr
    lines = [json.loads(x) for x in full.stdout.splitlines()]
    assert [r["cycle"] for r in lines] == list(range(5))

    kill_at = int(np.random.default_rng().integers(1, 4))  # after 1, 2 or 3 stored cycles
    db = tmp_path / "b" / "run.sqlite"
    kept = kill_run(cli_cmd(*args, "--out", str(tmp_path / "b")), db,
                    "fetch-slow-middle-full-s3", kill_at, env)
    assert kept is not None and kept < 4, "the run finished before it could be killed"

    again = subprocess.run(cli_cmd(*args, "--out", str(tmp_path / "b")), capture_output=True,
                           text=True, env=env, timeout=60)
    assert again.returncode == 2 and "--resume" in again.stderr  # nothing overwritten silently
    ra, rb, ma, mb = resume_and_compare(cli_cmd(*args, "--out", str(tmp_path / "b"), "--resume"),
                                        tmp_path / "a" / "run.sqlite", db, env)
    assert [stored(r) for r in ra] == [stored(r) for r in rb]
    assert ma.temporal.to_dict() == mb.temporal.to_dict()
    assert ma.spatial.to_dict() == mb.spatial.to_dict()


def test_exact_baseline_plans_with_cp_sat_and_learns_nothing(policy):
    run = AdaptiveRun(RunConfig(human="slow-middle", adapt="exact", cycles=2, **SMALL), policy)
    prior = run.model.temporal.to_dict()
    records = run.run()
    assert all(r.search["solver"] == "cp-sat" and r.search["optimal"] for r in records)
    assert all(r.plan.lam == 0.0 for r in records)
    assert not any(isinstance(x, Wait) for r in records for x in r.plan.human + r.plan.robot)
    assert run.model.temporal.to_dict() == prior  # nothing learned


@pytest.mark.parametrize(("adapt", "learns_time", "learns_space"), [
    ("full", True, True), ("spatial", False, True), ("temporal", True, False),
    ("none", False, False), ("oracle", False, False),
])
def test_each_level_updates_exactly_the_models_it_names(policy, adapt, learns_time, learns_space):
    run = AdaptiveRun(RunConfig(human="slow-middle", adapt=adapt, cycles=1, **SMALL), policy)
    time0, space0 = run.model.temporal.to_dict(), run.model.spatial.to_dict()
    run.run()
    assert (run.model.temporal.to_dict() != time0) is learns_time
    assert (run.model.spatial.to_dict() != space0) is learns_space
    assert sum(run.model.history.count(t, a) for t in run.problem.ids
               for a in ("human", "robot")) == 4  # what happened is recorded at every level


def test_a_cycle_in_steps_equals_a_whole_step(policy):
    cfg = RunConfig(human="fast-middle", cycles=2, seed=5, **SMALL)
    whole = AdaptiveRun(cfg, policy)
    want = [stored(r) for r in whole.run()]

    # a caller that shows the plan, waits for the person, then learns: here the "person" is
    # the same simulated teammate, observed outside the run and handed in
    stepped = AdaptiveRun(cfg, policy)
    got = []
    while not stepped.finished:
        plan = stepped.plan()
        seen = stepped.teammate.execute(plan.cycle, plan.best.schedule.tasks("human"), plan.rng)
        dep = stepped.execute(plan, Observation(human=seen))
        stepped.learn(plan, dep)
        got.append(stored(stepped.record(plan, dep)))
    assert got == want

    stale = stepped.plan if not stepped.finished else None
    assert stale is None  # a finished run plans no more
    with pytest.raises(Exception, match="is finished"):
        stepped.plan()


def test_a_plan_belongs_to_its_cycle(policy):
    run = AdaptiveRun(RunConfig(human="fast-middle", cycles=3, **SMALL), policy)
    plan = run.plan()
    run.step()  # the run moved on to cycle 1 without this plan
    with pytest.raises(Exception, match="plan is for cycle 0"):
        run.execute(plan)


def test_resume_redraws_missing_charts_and_names_changed_settings(tmp_path):
    args = ["run", "--cycles", "2", "--population", "8", "--generations", "3", "--samples", "8",
            "--particles", "2", "--candidates", "2", "--out", str(tmp_path)]
    first = subprocess.run(cli_cmd(*args), capture_output=True, text=True, timeout=300)
    assert first.returncode == 0, first.stderr
    chart = tmp_path / "gantt" / "fetch-fast-middle-full-s0-cycle-01.png"
    chart.unlink()  # as if the run had been killed between storing cycle 1 and drawing it
    again = subprocess.run(cli_cmd(*args, "--resume"), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert "already finished (2 cycles)" in again.stderr
    assert chart.is_file()
    other = subprocess.run(cli_cmd(*args[:-2], "--population", "9", "--out", str(tmp_path),
                                "--resume"), capture_output=True, text=True, timeout=300)
    assert other.returncode == 2
    assert "population=8 (asked 9)" in other.stderr and "Traceback" not in other.stderr


def test_plan_cost_scores_the_executed_plan_under_the_truth(policy):
    """The plan cost (paper Fig. 5) is the plan under the teammate's true model: for the
    oracle, whose planning model is that truth, it repeats the planner's own expectation (the
    same C_j and spatial cost; the makespan up to its 32 samples against 256); for a planner
    on the population prior facing a middle walker, the motions' true spatial cost is not the
    believed one."""
    risky = 0
    for adapt in ("oracle", "none"):
        run = AdaptiveRun(RunConfig(human="slow-middle", adapt=adapt, cycles=2, lam=0.0,
                                    **SMALL), policy)
        for rec in run.run():
            pc, exp = rec.plan_cost, rec.expected
            assert pc is not None
            assert pc.cost == pytest.approx(pc.makespan + rec.plan.gamma * pc.spatial)
            if adapt == "oracle":
                assert pc.spatial == pytest.approx(exp.spatial, abs=1e-9)
                assert pc.makespan == pytest.approx(exp.makespan, abs=0.5)
            elif rec.plan.routes.get("t3") == "middle" and "t2" in rec.plan.human:
                risky += 1
                assert pc.spatial > exp.spatial + 0.2, (pc, exp)
    assert risky >= 1  # the prior sent the robot down the corridor beside the person
