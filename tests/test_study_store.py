"""The user study's store: design kept once, resume pointer, validation, one transaction per
submit, foreign files refused."""

from __future__ import annotations

import sqlite3
import threading

import pytest

from rapidds.errors import StateError, StudyDataError, StudyDesignError
from rapidds.experiments.study.design import StudyDesign
from rapidds.experiments.study.store import (
    Step,
    StudyStore,
    SurveyItems,
    default_items,
    validate_durations,
)
from rapidds.loop.config import RunConfig
from rapidds.store import RunStore

RUN = RunConfig(world="painting", variant="unconstrained", gamma=1.0, population=4)


def _design(**kw) -> StudyDesign:
    base = {"participants": 8, "systems": ("full", "none"), "rounds": 2, "seed": 3}
    return StudyDesign(**{**base, **kw})


def _answers(store: StudyStore, value: int = 4) -> dict[str, int]:
    return {i: value for i in store.items.ids}


def _do_rounds(store: StudyStore, pid: str, system: str) -> None:
    rid = store.run_id(pid, system)
    store.create_run(rid, store.config_for(pid, system).model_dump())
    for k in range(store.design.rounds):
        store.record_cycle(rid, k, {"cycle": k, "realised": {"makespan": 10.0 - k}},
                           state=b"model")


def test_design_is_stored_once_and_a_different_one_refused(tmp_path):
    path = tmp_path / "study.sqlite"
    with StudyStore.create(path, _design(), RUN) as st:
        assert st.design == _design()
        assert st.base_config.world == "painting"
        assert st.items == default_items()
        ps = st.participants()
        assert len(ps) == 8 and ps[0].id == "P01" and ps[0].position == 1
        assert {p.group for p in ps} == {"left-fast", "left-slow", "right-fast", "right-slow"}
        assert sorted(st.design.assign()["participant"]) == [p.id for p in ps]
        cfg = st.config_for("P02", "none")
        assert (cfg.human, cfg.adapt, cfg.cycles, cfg.seed) == ("P02", "none", 2, 30_002)
        assert st.config_for("P02", "full").seed == cfg.seed  # one person, common numbers
        assert len(st.study_runs()) == 16
        assert not st.set_design(_design(), RUN)  # the same design again: nothing changes
    with pytest.raises(StateError, match=r"different study \(design"):
        StudyStore.create(path, _design(seed=4), RUN).close()
    with pytest.raises(StateError, match=r"different study \(run"):
        StudyStore.create(path, _design(), RUN.replace(gamma=2.0)).close()
    with pytest.raises(StateError, match=r"different study \(items"):
        StudyStore.create(path, _design(), RUN, SurveyItems.parse(
            {"items": [{"id": "a", "text": "A."}]}, "x")).close()


def test_design_needs_known_systems_and_resolved_variant(tmp_path):
    with pytest.raises(StudyDesignError, match="unknown"):
        StudyStore.create(tmp_path / "a.sqlite", _design(systems=("full", "magic")), RUN)
    with pytest.raises(Exception, match="variant resolved"):
        StudyStore.create(tmp_path / "b.sqlite", _design(), RUN.replace(variant=None))


def test_foreign_files_are_refused_in_one_line_and_left_alone(tmp_path):
    run_store = tmp_path / "runs.sqlite"
    RunStore(run_store).close()
    text = tmp_path / "notes.sqlite"
    text.write_text("hello\n")
    other = tmp_path / "other.sqlite"
    db = sqlite3.connect(other)
    db.execute("CREATE TABLE t (x)")
    db.commit()
    db.close()
    for path in (run_store, text, other):
        before = path.read_bytes()
        for opener in (StudyStore, StudyStore.open_readonly):
            with pytest.raises(StateError, match="not a rapidds study store") as exc:
                opener(path)
            assert "\n" not in str(exc.value)
        assert path.read_bytes() == before
    with pytest.raises(StateError, match="no such study store"):
        StudyStore.open_readonly(tmp_path / "missing.sqlite")


def test_a_study_store_is_a_run_store_too(tmp_path):
    """rapidds report and other RunStore readers can read a study's runs."""
    with StudyStore.create(tmp_path / "s.sqlite", _design(), RUN) as st:
        _do_rounds(st, "P01", st.participant("P01").systems[0])
    with RunStore.open_readonly(tmp_path / "s.sqlite") as rs:
        assert len(rs.records()) == 2


def test_next_step_walks_the_protocol_and_refuses_steps_out_of_turn(tmp_path):
    with StudyStore.create(tmp_path / "s.sqlite", _design(), RUN) as st:
        p = st.participant("P03")
        first, second = p.systems
        assert st.next_step("P03") == Step("round", first, 1, 0)
        # a round of the second system before the first is finished
        rid2 = st.run_id("P03", second)
        st.create_run(rid2, st.config_for("P03", second).model_dump())
        with pytest.raises(StateError, match=f"next step is round 1 with system '{first}'"):
            st.record_cycle(rid2, 0, {"cycle": 0})
        rid1 = st.run_id("P03", first)
        st.create_run(rid1, st.config_for("P03", first).model_dump())
        with pytest.raises(StateError, match="not round 2"):
            st.record_cycle(rid1, 1, {"cycle": 1})
        st.record_cycle(rid1, 0, {"cycle": 0}, state=b"m")
        assert st.next_step("P03") == Step("round", first, 1, 1)
        st.record_cycle(rid1, 1, {"cycle": 1}, state=b"m")
        assert st.next_step("P03") == Step("survey", first, 1)
        with pytest.raises(StateError, match="next step is the survey"):
            st.record_cycle(rid2, 0, {"cycle": 0})
        with pytest.raises(StateError, match="next step is the survey about system"):
            st.submit_ranking("P03", [first, second])
        assert st.submit_survey("P03", first, _answers(st, 5))
        assert not st.submit_survey("P03", first, _answers(st, 5))  # a re-post: no change
        with pytest.raises(StateError, match="already submitted"):
            st.submit_survey("P03", first, _answers(st, 6))
        assert st.next_step("P03") == Step("round", second, 2, 0)
        _ = [st.record_cycle(rid2, k, {"cycle": k}, state=b"m") for k in range(2)]
        st.submit_survey("P03", second, _answers(st, 2))
        assert st.next_step("P03") == Step("ranking")
        with pytest.raises(StateError, match="next step is the ranking"):
            st.submit_demographics("P03", {"age": "22"})
        assert st.submit_ranking("P03", [second, first])
        assert st.next_step("P03") == Step("demographics")
        assert st.submit_demographics("P03", {"age": "22", "handedness": "left"})
        assert st.next_step("P03") == Step("done")
        # everyone else has not started
        assert {pid for pid, s in st.progress().items() if s.kind == "done"} == {"P03"}
    # what was stored survives a reopen, read-only
    with StudyStore.open_readonly(tmp_path / "s.sqlite") as ro:
        assert ro.next_step("P03") == Step("done")
        assert ro.rankings() == {"P03": (second, first)}
        assert ro.demographics() == {"P03": {"age": "22", "handedness": "left"}}
        frame = ro.survey_frame()
        assert len(frame) == 2 * len(ro.items.ids)
        assert set(frame[frame.system == first].value) == {5}
        with pytest.raises(StateError, match="read-only"):
            ro.submit_ranking("P04", list(ro.participant("P04").systems))


def test_submissions_are_validated_and_nothing_half_written(tmp_path):
    with StudyStore.create(tmp_path / "s.sqlite", _design(), RUN) as st:
        first = st.participant("P01").systems[0]
        _do_rounds(st, "P01", first)
        bad = _answers(st)
        bad["robot_in_the_way"] = 8
        with pytest.raises(StudyDataError, match="'robot_in_the_way': Input should be less"):
            st.submit_survey("P01", first, bad)
        bad["robot_in_the_way"] = 2.5
        with pytest.raises(StudyDataError, match="robot_in_the_way"):
            st.submit_survey("P01", first, bad)
        partial = _answers(st)
        del partial["team_fluent"]
        with pytest.raises(StudyDataError, match="unanswered: team_fluent"):
            st.submit_survey("P01", first, partial)
        with pytest.raises(StudyDataError, match="unknown items: nope"):
            st.submit_survey("P01", first, {**_answers(st), "nope": 3})
        with pytest.raises(StudyDataError, match="no system 'magic'"):
            st.submit_survey("P01", "magic", _answers(st))
        with pytest.raises(StudyDataError, match="no participant 'P99'"):
            st.submit_survey("P99", first, _answers(st))
        assert st.survey_frame().empty
        st.submit_survey("P01", first, {k: str(v) for k, v in _answers(st, 7).items()})
        assert set(st.survey_frame().value) == {7}


def test_ranking_must_be_a_permutation(tmp_path):
    with StudyStore.create(tmp_path / "s.sqlite", _design(), RUN) as st:
        for system in st.participant("P02").systems:
            _do_rounds(st, "P02", system)
            st.submit_survey("P02", system, _answers(st))
        for bad in (["full"], ["full", "full"], ["full", "none", "none"], ["full", "spatial"]):
            with pytest.raises(StudyDataError, match="exactly once"):
                st.submit_ranking("P02", bad)
        assert st.rankings() == {}
        with pytest.raises(StudyDataError, match="demographics"):
            st.submit_demographics("P02", {"": "x"})


def test_durations_are_positive_finite_and_complete():
    assert validate_durations({"brush": "4.5", "prep_vise": 6}, ["prep_vise", "brush"]) == {
        "prep_vise": 6.0, "brush": 4.5}
    for bad, msg in [({"brush": -1.0}, "'brush': Input should be greater than 0"),
                     ({"brush": 0}, "greater than 0"),
                     ({"brush": float("nan")}, "finite"),
                     ({"brush": float("inf")}, "finite"),
                     ({"brush": "soon"}, "valid number")]:
        with pytest.raises(StudyDataError, match=msg):
            validate_durations(bad, ["brush"])
    with pytest.raises(StudyDataError, match="missing secure_piece; not the person's: mix_l"):
        validate_durations({"brush": 3.0, "mix_l": 2.0}, ["brush", "secure_piece"])
    # a bound no real task exceeds: the study's (here 120 s), else an hour at most
    assert validate_durations({"brush": "120"}, ["brush"], at_most=120.0) == {"brush": 120.0}
    for d, at_most in (("4500", 120.0), (120.01, 120.0), (1e12, 3600.0)):
        with pytest.raises(StudyDataError, match=r"'brush': .* s is longer than any task"):
            validate_durations({"brush": d}, ["brush"], at_most=at_most)
    with pytest.raises(StudyDataError, match="3600 s"):
        validate_durations({"brush": 1e7}, ["brush"])


def test_simulated_trials_are_stored_whole(tmp_path):
    with StudyStore.create(tmp_path / "s.sqlite", _design(), RUN) as st:
        second = st.participant("P05").systems[1]  # in any order: simulated runs are parallel
        rid = st.run_id("P05", second)
        records = [{"cycle": k} for k in range(2)]
        assert st.record_trial(rid, st.config_for("P05", second).model_dump(), records)
        assert not st.record_trial(rid, st.config_for("P05", second).model_dump(), records)
        assert st.rounds_done("P05", second) == 2


def test_item_files(tmp_path):
    good = tmp_path / "items.yaml"
    good.write_text("items:\n  - {id: calm, text: I felt calm.}\n  - {id: fast, text: Fast.}\n")
    assert SurveyItems.load(good).ids == ("calm", "fast")
    for text, msg in [("items: []", "at least 1"),
                      ("items:\n  - {id: a, text: A}\n  - {id: a, text: B}\n", "named twice: a"),
                      ("items:\n  - {id: 'a b', text: A}\n", "pattern"),
                      ("items: [\n", "not valid YAML"),
                      ("- 1\n", "valid dictionary")]:
        good.write_text(text)
        with pytest.raises(StudyDesignError, match=msg):
            SurveyItems.load(good)
    with pytest.raises(StudyDesignError, match=r"missing\.yaml: no such file"):
        SurveyItems.load(tmp_path / "missing.yaml")
    assert "The robot got in the way of me completing my tasks." in {
        i.text for i in default_items().items}


def test_two_processes_creating_one_study_both_get_it(tmp_path):
    path = tmp_path / "s.sqlite"
    errors: list[BaseException] = []

    def make() -> None:
        try:
            StudyStore.create(path, _design(), RUN).close()
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=make) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    with StudyStore.open_readonly(path) as st:
        assert len(st.participants()) == 8
