"""The ablation study on a real Dask LocalCluster with 2 workers: a run killed midway and
resumed, a killed worker, the stored records against the same trials computed without Dask,
the figures and tables, and the report's statistics."""

from __future__ import annotations

import csv
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import PLAIN

from rapidds.errors import RapiddsError, RuntimeFault, StateError
from rapidds.experiments.ablation import (
    LOCAL_WORKER_ENV,
    AblationConfig,
    ablation_store,
    dask_client,
    run_ablation,
    run_trial,
)
from rapidds.experiments.report import (
    AblationData,
    check_claims,
    load_ablation,
    paired_bootstrap,
    summarise,
    table_markdown,
    table_rows,
    verdict,
    write_report,
)
from rapidds.store import RunStore

HUMANS = ("fast-middle", "slow-outside")
LEVELS = ("full", "none")
SEARCH = dict(population=8, generations=4, samples=8, patience=2, particles=2, candidates=2)
STUDY = AblationConfig(humans=HUMANS, levels=LEVELS, trials=2, cycles=4, **SEARCH)
ARGS = ["--trials", "2", "--cycles", "4", "--humans", ",".join(HUMANS), "--adapt",
        ",".join(LEVELS), "--workers", "2",
        *[x for k, v in SEARCH.items() for x in (f"--{k}", str(v))]]
RUN_IDS = {f"fetch-{h}-{lv}-s{i}" for h in HUMANS for lv in LEVELS for i in (0, 1)}


def _cli(*args: str) -> list[str]:
    """A plain interpreter: the test kills the run's whole session (``killpg``), which a fork
    server's child (tests/forkserver.py) is not in."""
    return [*PLAIN, *args]


def _strip(records: list[dict]) -> list[dict]:
    """Records without the wall-clock ``seconds`` (and the ``run_id`` the store adds)."""
    return [{k: v for k, v in r.items() if k not in ("seconds", "run_id")} for r in records]


def _records(out: Path) -> dict[str, list[dict]]:
    with RunStore.open_readonly(out / "study.sqlite") as st:
        return {rid: _strip(st.records(rid)) for rid in st.run_ids()}


def _finished(out: Path, cycles: int = 4) -> int:
    path = out / "study.sqlite"
    if not path.exists():
        return 0
    with RunStore.open_readonly(path) as st:
        return sum(st.last_cycle(r) == cycles - 1 for r in st.run_ids())


@pytest.fixture(scope="module")
def serial() -> dict[str, list[dict]]:
    """The same trials computed one after another in this process, without Dask: what every
    study, interrupted or not, must store."""
    import torch

    torch.set_num_threads(1)
    return {cfg.run_id: _strip(json.loads(json.dumps(run_trial(cfg.model_dump())["records"])))
            for cfg in STUDY.trials_in_order()}


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """The CLI on a 2-worker LocalCluster, SIGKILLed (with its scheduler and workers) once the
    first trial is stored, then rerun with the same --out to the end."""
    out = tmp_path_factory.mktemp("ablation") / "study"
    proc = subprocess.Popen(_cli("ablation", "--out", str(out), *ARGS), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 240
        while _finished(out) < 1:
            assert proc.poll() is None, "the study ended before it could be killed"
            assert time.monotonic() < deadline, "no trial stored in time"
            time.sleep(0.1)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the whole run: client, scheduler and workers
        proc.wait()
    with RunStore.open_readonly(out / "study.sqlite") as st:
        before = {rid: st.records(rid) for rid in st.run_ids()}
    res = subprocess.run(_cli("ablation", "--out", str(out), "--json", *ARGS),
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    return out, before, json.loads(res.stdout), res.stderr


@pytest.mark.slow
def test_killed_run_resumes_to_the_same_records(study, serial):
    out, before, _, err = study
    assert 1 <= len(before) < 8, len(before)  # killed midway, every stored trial whole
    assert all(len(v) == 4 for v in before.values())
    assert f"{len(before)} of 8 trials already stored" in err
    assert f"{8 - len(before)} trials run, {len(before)} already stored" in err
    assert _records(out) == serial
    # stored trials were skipped, not redone
    with RunStore.open_readonly(out / "study.sqlite") as st:
        for rid, recs in before.items():
            assert st.records(rid) == recs


def test_study_stores_records_and_writes_figures_and_tables(study):
    out, _, summary, _ = study
    recs = _records(out)
    assert set(recs) == RUN_IDS
    with RunStore.open_readonly(out / "study.sqlite") as st:
        for rid in RUN_IDS:
            cfg = st.run_config(rid)
            assert cfg is not None and cfg["cycles"] == 4 and cfg["candidates"] == 2
            assert [r["cycle"] for r in recs[rid]] == [0, 1, 2, 3]
            assert st.arrays(rid, 0) == {}  # records only: workers ship no trajectories
    # lambda drops to 0 at the second half of every trial
    assert [r["lambda"] for r in recs["fetch-fast-middle-full-s0"]] == [15.0, 15.0, 0.0, 0.0]
    # trial i has the same seed at every level (common random numbers): before anything is
    # learned, full and none plan and deploy cycle 0 identically
    for h in HUMANS:
        a, b = recs[f"fetch-{h}-full-s1"][0], recs[f"fetch-{h}-none-s1"][0]
        assert (a["human"], a["robot"], a["realised"]) == (b["human"], b["robot"], b["realised"])
    assert recs["fetch-fast-middle-full-s0"][0] != recs["fetch-fast-middle-full-s1"][0]

    assert (out / "ablation.png").read_bytes()[:4] == b"\x89PNG"
    assert (out / "ablation.pdf").read_bytes()[:4] == b"%PDF"
    rows = list(csv.DictReader((out / "table.csv").open()))
    assert [(r["archetype"], r["level"]) for r in rows] == [(h, lv) for h in HUMANS
                                                            for lv in LEVELS]
    md = (out / "table.md").read_text()
    assert md.count("\n| ") == 4 and "median cost, last 4" in md
    report = (out / "report.md").read_text()
    assert "ablation.png" in report and "paper: 3" in report and "paper: 2" in report
    sessions = [json.loads(x) for x in (out / "sessions.jsonl").read_text().splitlines()]
    assert sessions[-1]["ran"] + sessions[-1]["skipped"] == 8

    # --json: per archetype and level, per-cycle median and quartiles of the stored costs
    assert set(summary) == {*HUMANS, "claims", "plan_cost", "claims_plan_cost"}
    for h in HUMANS:
        for lv in LEVELS:
            cell = summary[h][lv]
            costs = np.array([[r["realised"]["cost"] for r in recs[f"fetch-{h}-{lv}-s{i}"]]
                              for i in (0, 1)])
            np.testing.assert_allclose(cell["median"], np.median(costs, axis=0), atol=1e-4)
            np.testing.assert_allclose(cell["q1"], np.percentile(costs, 25, axis=0), atol=1e-4)
            np.testing.assert_allclose(cell["q3"], np.percentile(costs, 75, axis=0), atol=1e-4)
            plans = np.array([[r["plan_cost"]["cost"] for r in recs[f"fetch-{h}-{lv}-s{i}"]]
                              for i in (0, 1)])
            np.testing.assert_allclose(summary["plan_cost"][h][lv]["median"],
                                       np.median(plans, axis=0), atol=1e-4)
        assert summary["claims"]["per_archetype"][h]["versus"]["none"]["pairs"] == 2
        assert summary["claims_plan_cost"]["per_archetype"][h]["versus"]["none"]["pairs"] == 2
    for row in rows:
        score = np.median([np.mean([r["realised"]["cost"] for r in recs[
            f"fetch-{row['archetype']}-{row['level']}-s{i}"][-4:]]) for i in (0, 1)])
        assert float(row["median"]) == pytest.approx(score, abs=1e-5)
        plan = np.median([np.mean([r["plan_cost"]["cost"] for r in recs[
            f"fetch-{row['archetype']}-{row['level']}-s{i}"][-4:]]) for i in (0, 1)])
        assert float(row["plan_median"]) == pytest.approx(plan, abs=1e-5)
    assert (out / "ablation-plan.png").read_bytes()[:4] == b"\x89PNG"
    assert "plan cost" in md and "claims, plan cost" in report


@pytest.mark.slow
def test_killed_worker_loses_only_its_trial(serial, tmp_path):
    """A worker SIGKILLed mid-trial (on a cluster reached by address, as --scheduler does): Dask
    reruns its trial elsewhere, the study finishes and stores every trial once."""
    import dask
    from distributed import LocalCluster

    with dask.config.set(LOCAL_WORKER_ENV), \
            LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                         dashboard_address=":0", silence_logs=logging.ERROR) as cluster:
        killed: list[int] = []
        with ablation_store(tmp_path / "w") as store, \
                dask_client(scheduler=cluster.scheduler_address) as client:

            def kill_one_worker(result: dict, stored: int, total: int) -> None:
                if not killed:
                    pids = client.run(os.getpid)
                    victim = next(p for p in pids.values() if p != result["pid"])
                    os.kill(victim, signal.SIGKILL)  # busy with the next trial right now
                    killed.append(victim)

            outcome = run_ablation(STUDY, store, client, on_trial=kill_one_worker)
            alive = set(client.run(os.getpid).values())
        assert killed and killed[0] not in alive
        assert outcome.ran == 8 and outcome.skipped == 0
    assert _records(tmp_path / "w") == serial


def test_report_redraws_from_the_store_alone(study, tmp_path, capsys):
    from rapidds.cli import main

    out = tmp_path / "copy"
    out.mkdir()
    shutil.copy(study[0] / "study.sqlite", out / "study.sqlite")
    assert _run(main, ["report", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == study[2]
    assert (out / "ablation.png").stat().st_size > 1000
    assert (out / "table.csv").read_text() == (study[0] / "table.csv").read_text()
    data = load_ablation(out)
    assert data.metric("fast-middle", "full").shape == (2, 4) and not data.incomplete


def _run(main, args: list[str]) -> int:
    old = sys.argv
    sys.argv = ["rapidds", *args]
    try:
        main()
    except SystemExit as exc:
        return int(exc.code or 0)
    finally:
        sys.argv = old
    return 0


def _fault(config: dict) -> dict:
    raise RuntimeFault(f"the cycle cannot progress at t = 9.00 s ({config['human']})")


def test_a_failed_trial_is_kept_with_its_reason_and_the_others_run_on(study, tmp_path):
    """One trial raising a runtime fault on its worker (as the mutual hold of issue 34 did):
    kept as failed with its reason, the other trials stored, the report counts it; storing the
    trial later (a rerun that succeeds) clears it."""
    from distributed import Client

    from rapidds.experiments.ablation import StudyOutcome, store_results

    first, *rest = STUDY.trials_in_order()
    with RunStore.open_readonly(study[0] / "study.sqlite") as st:
        done = {c.run_id: [{k: v for k, v in r.items() if k != "run_id"}
                           for r in st.records(c.run_id)] for c in [first, *rest]}
    out = tmp_path / "f"
    outcome = StudyOutcome(total=len(rest) + 1, skipped=0)
    with ablation_store(out) as store, Client(processes=False, n_workers=1,
                                              threads_per_worker=1, dashboard_address=":0") as c:
        futures = {c.submit(_fault, first.model_dump(), pure=False): first}
        futures.update({c.submit(lambda cfg: {"run_id": cfg.run_id,
                                              "config": cfg.model_dump(),
                                              "records": done[cfg.run_id], "seconds": 1.0},
                                 cfg, pure=False): cfg for cfg in rest})
        store_results(c, futures, store, outcome, None, time.perf_counter())
        assert outcome.ran == len(rest) and [r for r, _ in outcome.failed] == [first.run_id]
        assert set(store.failures()) == {first.run_id}
        assert store.failures()[first.run_id]["config"] == first.model_dump()
    data = load_ablation(out)
    assert data.failed == {first.run_id: "the cycle cannot progress at t = 9.00 s "
                                         f"({first.human})"}
    write_report(data)
    assert "1 trial(s) failed and were left out" in (out / "report.md").read_text()
    assert first.run_id in (out / "report.md").read_text()
    with ablation_store(out) as store:
        assert store.record_trial(first.run_id, first.model_dump(), done[first.run_id])
        assert store.failures() == {}
    assert load_ablation(out).failed == {}


def test_bad_input_is_one_line_and_exit_2(study, tmp_path, capsys):
    from rapidds.cli import main

    assert _run(main, ["ablation", "--out", str(tmp_path / "a"), "--adapt", "full,bogus"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--adapt: unknown value 'bogus'" in err
    assert _run(main, ["report", str(tmp_path / "empty")]) == 2
    assert "holds no study" in capsys.readouterr().err
    # a folder holds one study: other cycles are refused before any cluster starts
    copy = tmp_path / "copy"
    copy.mkdir()
    shutil.copy(study[0] / "study.sqlite", copy / "study.sqlite")
    args = list(ARGS)
    args[args.index("--cycles") + 1] = "6"
    assert _run(main, ["ablation", "--out", str(copy), *args]) == 2
    assert "other settings: cycles=4 (asked 6)" in capsys.readouterr().err
    with ablation_store(tmp_path / "locked"), pytest.raises(RapiddsError, match="another"), \
            ablation_store(tmp_path / "locked"):
        pass


def test_a_study_plans_with_one_network(study, tmp_path, capsys):
    """Every stored trial keeps the fingerprint of the network it planned with; ``--policy``
    reaches the workers, and a folder's trials planned with another network are refused (one
    line, exit 2) before anything runs or is written."""
    import torch

    from rapidds.cli import main
    from rapidds.loop.run import load_policy
    from rapidds.worlds.registry import make_world

    bundled = load_policy(make_world("fetch"), device="cpu")
    other = load_policy(make_world("fetch"), device="cpu")
    with torch.no_grad():
        next(other.model.parameters()).mul_(1.01)
    other.save(tmp_path / "other")
    copy = tmp_path / "copy"
    copy.mkdir()
    shutil.copy(study[0] / "study.sqlite", copy / "study.sqlite")
    with RunStore(copy / "study.sqlite") as st:
        assert st.run_ids()
        for rid in st.run_ids():  # each run kept the bundled network's fingerprint
            with pytest.raises(StateError, match=f"fingerprint {bundled.fingerprint()}, "):
                st.claim_policy(rid, "none")
    before = _records(copy)
    assert _run(main, ["ablation", "--out", str(copy), *ARGS, "--policy",
                       str(tmp_path / "other")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "planned with another network" in err
    assert bundled.fingerprint() in err and _records(copy) == before
    # a new folder with that network: its one trial plans with it on a worker
    one = ["--trials", "1", "--cycles", "1", "--humans", HUMANS[0], "--adapt", "none",
           "--workers", "1", *[x for k, v in SEARCH.items() for x in (f"--{k}", str(v))]]
    assert _run(main, ["ablation", "--out", str(tmp_path / "new"), *one, "--json",
                       "--policy", str(tmp_path / "other")]) == 0
    capsys.readouterr()
    with RunStore(tmp_path / "new" / "study.sqlite") as st:
        (rid,) = st.run_ids()
        assert other.fingerprint() != bundled.fingerprint()
        with pytest.raises(StateError, match=f"fingerprint {other.fingerprint()}, "):
            st.claim_policy(rid, "none")


def _synthetic(scores: dict[str, dict[str, list[float]]], cycles: int = 4) -> AblationData:
    """A study whose trial scores are given: every cycle of trial i costs scores[h][lv][i]."""
    trials = {h: {lv: {s: np.tile([v, 0.0, 0.0, 1.0, v], (cycles, 1))  # one column per METRICS
                       for s, v in enumerate(vals)} for lv, vals in cell.items()}
              for h, cell in scores.items()}
    return AblationData(Path("."), cycles, {}, trials)


def test_claims_check_counts_strict_wins_and_ties():
    rng = np.random.default_rng(0)
    base = 10 + rng.normal(0, 0.3, 20)
    data = _synthetic({
        # full clearly better than spatial only and none, the same as temporal only
        "fast-outside": {"full": list(base), "spatial": list(base + 2), "temporal": list(base),
                         "none": list(base + 2)},
        # full clearly worse than temporal only: not "at least as good"
        "slow-middle": {"full": list(base + 1), "spatial": list(base + 3),
                        "temporal": list(base), "none": list(base + 1)},
    })
    c = check_claims(data)
    fo, sm = c["per_archetype"]["fast-outside"], c["per_archetype"]["slow-middle"]
    assert fo["versus"]["spatial"]["verdict"] == "better"
    assert fo["versus"]["temporal"]["verdict"] == "tie" and fo["full_at_least_as_good"]
    assert sm["versus"]["temporal"]["verdict"] == "worse" and not sm["full_at_least_as_good"]
    assert sm["versus"]["none"]["verdict"] == "tie"
    assert c["full_better_than"]["spatial"] == {"strictly_better": 2, "lower_median": 2,
                                                "archetypes": 2, "paper": 3}
    assert c["full_better_than"]["temporal"]["strictly_better"] == 0
    assert check_claims(data) == c  # seeded: the same report every time
    # the plan cost (here equal to the realised one) is checked on the same resampled trials
    p = check_claims(data, measure="plan_cost")
    assert p["measure"] == "plan_cost" and p["per_archetype"] == c["per_archetype"]


def test_a_study_stored_before_plan_costs_still_reports():
    """Old stores have no plan cost: the report keeps to the realised cost."""
    data = _synthetic({"fast-middle": {"full": [1.0, 2.0], "none": [1.5, 2.5]}})
    for runs in data.trials["fast-middle"].values():
        for a in runs.values():
            a[:, -1] = np.nan
    assert not data.has_plan_cost
    summary = summarise(data)
    assert "claims_plan_cost" not in summary and "plan_cost" not in summary
    rows = table_rows(data)
    assert "plan_median" not in rows[0] and "plan cost" not in table_markdown(rows, 4)


def test_paired_bootstrap_uses_the_pairing():
    rng = np.random.default_rng(1)
    luck = rng.normal(0, 5, 30)  # large shared trial-to-trial variation (common seeds)
    d, lo, hi = paired_bootstrap(luck + 1.0, luck + 1.5, np.random.default_rng(0))
    assert d == pytest.approx(-0.5) and hi < 0 and verdict(lo, hi) == "better"
    assert verdict(-1.0, 1.0) == "tie" and verdict(0.1, 1.0) == "worse"
