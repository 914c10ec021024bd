"""The typed cycle record: every kind of stored record reads back typed and writes back to the
same JSON bytes, old records included; readers moved onto it say what they said before."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import SMALL_SEARCH as SMALL

from rapidds.errors import StateError
from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.loop.run import timeline_of
from rapidds.record import CycleRecord
from rapidds.schedule import Wait
from rapidds.store import RunStore

DATA = Path(__file__).parent / "data"


def _stored(cfg: RunConfig, tmp_path: Path, policy=None) -> tuple[RunStore, list[dict]]:
    store = RunStore(tmp_path / "run.sqlite")
    AdaptiveRun(cfg, policy, store).run()
    return store, store.records(cfg.run_id)


def _round_trips(records: list[dict]) -> list[CycleRecord]:
    typed = [CycleRecord.from_json(r) for r in records]
    for raw, rec in zip(records, typed, strict=True):
        assert json.dumps(rec.to_json()) == json.dumps(raw)  # same keys, order and values
    return typed


def test_a_fetch_runs_records_round_trip_byte_for_byte(fetch_policy, tmp_path):
    cfg = RunConfig(human="slow-middle", cycles=2, seed=7, **SMALL)
    store, raw = _stored(cfg, tmp_path, fetch_policy)
    typed = store.cycle_records(cfg.run_id)
    assert [json.dumps(t.to_json()) for t in typed] == [json.dumps(r) for r in raw]
    for t, r in zip(typed, raw, strict=True):
        assert t.run_id == cfg.run_id and t.cycle == r["cycle"]
        assert t.plan.lam == r["lambda"] and t.realised.cost == r["realised"]["cost"]
        assert t.execution.in_cycle is None and not t.has_comfort and t.changes is None
        assert t.plan_cost is not None and t.plan_cost.cost == r["plan_cost"]["cost"]
        assert sorted(t.tasks("human") + t.tasks("robot")) == sorted(r["realised"]["timeline"])


def test_the_base_commits_stored_records_read_back(fetch_policy):
    old = json.loads((DATA / "records-3412e09-fetch.json").read_text())
    typed = [CycleRecord.from_json(r) for r in old]
    assert [t.to_json() for t in typed] == old  # no seconds, no run_id: optional parts absent
    assert all(t.seconds is None and t.run_id is None and t.execution.in_cycle is None
               for t in typed)


def test_a_record_from_before_plan_costs_keeps_its_absence():
    old = json.loads((DATA / "records-3412e09-fetch.json").read_text())[0]
    del old["plan_cost"]
    rec = CycleRecord.from_json(old)
    assert rec.plan_cost is None and not rec.has_plan_cost
    assert "plan_cost" not in rec.to_json() and rec.to_json() == old


def test_a_reactive_run_with_a_deviating_person_round_trips(fetch_policy, tmp_path):
    cfg = RunConfig(human="slow-middle", cycles=2, seed=3, execution="reactive", reacts=True,
                    deviate=0.6, **SMALL)
    store = RunStore(tmp_path / "run.sqlite")
    run = AdaptiveRun(cfg, fetch_policy, store)
    deployed = []
    run.run(lambda res: deployed.append(res.deployment))
    raw = store.records(cfg.run_id)
    typed = _round_trips(raw)
    for t, r, dep in zip(typed, raw, deployed, strict=True):
        assert t.execution.in_cycle is not None
        assert t.tasks("human") == [x for x in r["executed"]["human"] if ":" not in x]
        assert len(t.execution.in_cycle.replans) == len(r["replans"])
        # the chart redrawn from the record is the deployed cycle's
        tl = timeline_of(run.problem, t)
        assert tl.schedule == dep.timeline.schedule
        assert (tl.start == dep.timeline.start).all() and (tl.finish == dep.timeline.finish).all()


def test_a_gamma_learning_run_round_trips(fetch_policy, tmp_path):
    cfg = RunConfig(human="fast-middle", cycles=2, gamma_learn=True, comfort=8.0, **SMALL)
    _, raw = _stored(cfg, tmp_path, fetch_policy)
    typed = _round_trips(raw)
    assert all(t.has_comfort and t.comfort is not None and t.gamma_belief is not None
               for t in typed)
    assert typed[0].comfort == raw[0]["comfort"]


def test_a_painting_runs_records_round_trip(tmp_path):
    cfg = RunConfig(world="painting", variant="unconstrained", cycles=2, population=8,
                    generations=4, samples=8, particles=2, candidates=4)
    _, raw = _stored(cfg, tmp_path)
    _round_trips(raw)


def test_wait_items_are_structured_and_written_back_as_stored():
    old = json.loads((DATA / "records-3412e09-fetch.json").read_text())[0]
    old["robot"] = ["t3", "wait:t2", "t1"]
    rec = CycleRecord.from_json(old)
    assert rec.plan.robot == ("t3", Wait("t2"), "t1")
    assert rec.plan.tasks("robot") == ["t3", "t1"]
    assert rec.to_json()["robot"] == ["t3", "wait:t2", "t1"]


def test_what_is_not_a_cycle_record_is_a_state_error():
    with pytest.raises(StateError, match="not a cycle record"):
        CycleRecord.from_json({"cycle": 0, "human": []})


def _report_text(out: Path) -> str:
    """The summary (JSON), the table and the claims of a stored study: what
    ``tests/data/ablation-130e392-report.txt`` holds, written by commit 130e392."""
    from rapidds.experiments.report import (
        claims_markdown,
        load_ablation,
        summarise,
        table_markdown,
        table_rows,
    )

    data = load_ablation(out)
    summary = summarise(data)
    return "\n".join([json.dumps(summary, sort_keys=True),
                      table_markdown(table_rows(data), data.cycles),
                      claims_markdown(summary["claims"])]) + "\n"


def test_a_committed_ablation_store_reads_back_and_reports_as_before(tmp_path):
    """A study stored by commit 130e392 (before the typed record; 1 archetype, full and none,
    2 trials of 2 cycles): its records round-trip byte for byte, and the report read through
    the typed records says what 130e392's report said of it."""
    import shutil

    from rapidds.experiments.ablation import STORE_NAME

    shutil.copy(DATA / "ablation-130e392.sqlite", tmp_path / STORE_NAME)
    with RunStore.open_readonly(tmp_path / STORE_NAME) as store:
        raw = store.records()
        assert len(raw) == 8
        _round_trips(raw)
    assert _report_text(tmp_path) == (DATA / "ablation-130e392-report.txt").read_text()


def test_a_live_cells_record_keeps_its_live_part_in_place():
    base = json.loads((DATA / "records-3412e09-fetch.json").read_text())[0]
    live = {"robot_durations": {"t1": 1.5}, "contacts": []}
    stored = {**base, "live": live, "seconds": {"plan": 1.0, "deploy": 0.5, "update": 0.1,
                                                "total": 1.6}}
    rec = CycleRecord.from_json(stored)
    assert rec.live == live and "live" not in rec.extra
    assert list(rec.to_json())[-2:] == ["live", "seconds"]  # as the loop writes it
    assert rec.to_json() == stored
