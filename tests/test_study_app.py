"""The study app through its HTTP interface (FastAPI's TestClient, the real session, store and
planner on a small fetch study): pages, one stored round or answer per submit, input refused
with a message and nothing stored, stale pages refused, and resume after a restart."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from browser_helpers import CliServer
from cli_helpers import cli_cmd
from fastapi.testclient import TestClient
from study_helpers import SEARCH, make_study

from rapidds.experiments.study.design import StudyDesign
from rapidds.experiments.study.store import StudyStore, create_study, study_path
from rapidds.loop.config import RunConfig
from rapidds.motion.policy import DiffusionPolicy
from rapidds.store import RunStore
from rapidds.web.server import allowed_hosts
from rapidds.web.study.app import MAX_BODY, StudyWorker, create_study_app
from rapidds.web.study.runner import InputError, StudySession
from rapidds.web.study.tracker import tracker_csv
from rapidds.worlds.fetch.world import FetchWorld

BASE = "http://127.0.0.1:8000"
HOSTS = ["127.0.0.1", "localhost"]


class Study:
    """A study folder served by a worker and a TestClient; ``restart()`` opens it afresh."""

    def __init__(self, folder: Path, world: FetchWorld, policy: DiffusionPolicy):
        self.folder, self.world, self.policy = folder, world, policy
        self._open()

    def _open(self) -> None:
        self.worker = StudyWorker(lambda: StudySession(self.folder, policy=self.policy,
                                                       world=self.world))
        self.client = TestClient(create_study_app(self.worker, HOSTS), base_url=BASE)

    @property
    def token(self) -> str:
        """The experimenter's key to the overview."""
        return str(self.client.app.state.token)  # type: ignore[attr-defined]

    def restart(self) -> None:
        self.close()
        self._open()

    def close(self) -> None:
        self.client.close()
        self.worker.close()

    def post(self, pid: str, kind: str, step: str, fields: dict[str, str] | None = None,
             **extra: Any) -> Any:
        return self.client.post(f"/api/p/{pid}/{kind}",
                                json={"step": step, "fields": fields or {}, **extra})

    def step(self, pid: str) -> str:
        page = self.client.get(f"/p/{pid}")
        assert page.status_code == 200, page.text
        return page.text.split("data-step='", 1)[1].split("'", 1)[0]

    def stored(self) -> tuple[int, int, int, int]:
        """(rounds, survey answers, rankings, demographics) in the store, read by another
        connection: what is committed."""
        with StudyStore.open_readonly(study_path(self.folder)) as s:
            return (len(s.records()), len(s.survey_frame()), len(s.rankings()),
                    len(s.demographics()))


@pytest.fixture()
def study(tmp_path: Path, fetch_world: FetchWorld,
          fetch_policy: DiffusionPolicy) -> Iterator[Study]:
    s = Study(make_study(tmp_path, fetch_world), fetch_world, fetch_policy)
    try:
        yield s
    finally:
        s.close()


def _pid(study: Study) -> str:
    return study.worker.run(lambda s: s.store.participants()[0].id)


def _human_tasks(study: Study, pid: str) -> list[str]:
    held = study.worker.run(lambda s: s.plan(pid))
    return [t for t in held[1].human if not t.startswith("wait:")]


def test_a_round_page_shows_the_plan_and_each_submit_stores_one_round(study: Study) -> None:
    pid = _pid(study)
    overview = study.client.get("/", params={"token": study.token})
    assert overview.status_code == 200 and f"/p/{pid}" in overview.text
    page = study.client.get(f"/p/{pid}")
    assert page.status_code == 200
    assert "Round 1: the robot's plan" in page.text and "data:image/svg+xml;base64," in page.text
    assert "system 1 of 2" in page.text and "round 1 of 2" in page.text
    for name in ("full", "none"):  # the participant's pages never name the system
        assert f"'{name}'" not in page.text
    for source in ("tracker", "simulated", "typed"):  # the group names a simulated person
        assert f"value={source}" in page.text
    step = study.step(pid)
    assert step.startswith("round:") and step.endswith(":0")
    # the simulated cell: the priming group's simulated person does the tasks
    r = study.post(pid, "round", step, {"source": "simulated"})
    assert r.status_code == 200 and r.json() == {"next": f"/p/{pid}"}
    assert study.stored() == (1, 0, 0, 0)
    assert "too_close" not in page.text  # a design without the comfort item does not ask it
    # the same page posted again (a double click, a second tab) is refused, not stored twice
    again = study.post(pid, "round", step, {"source": "simulated"})
    assert again.status_code == 409 and "out of date" in again.json()["error"]
    assert study.stored() == (1, 0, 0, 0)
    # durations typed in: stored as typed, paths at the world's dt
    step = study.step(pid)
    assert step.endswith(":1")
    tasks = _human_tasks(study, pid)
    typed = {t: 3.25 + i for i, t in enumerate(tasks)}
    r = study.post(pid, "round", step, {"source": "typed",
                                        **{f"d:{t}": f"{d}" for t, d in typed.items()}})
    assert r.status_code == 200, r.text
    assert study.stored() == (2, 0, 0, 0)
    with StudyStore.open_readonly(study_path(study.folder)) as s:
        rid = s.run_id(pid, s.participant(pid).systems[0])
        rec = s.records(rid)[-1]
        assert rec["observed"] == pytest.approx(typed)
        arrays = s.arrays(rid, rec["cycle"])
    for t, d in typed.items():
        assert arrays[f"human/{t}"].shape[0] == int(np.ceil(d / study.world.dt - 1e-9)) + 1


def test_a_tracker_file_round_is_stored_as_the_file_says(study: Study) -> None:
    pid = _pid(study)
    step = study.step(pid)
    tasks = _human_tasks(study, pid)
    person = study.worker.run(lambda s: s.teammate(pid))
    done = person.execute(0, tasks, np.random.default_rng(7))
    text = tracker_csv(done, study.world.dt, t0=50.0)
    r = study.post(pid, "round", step, {"source": "tracker"}, tracker=text)
    assert r.status_code == 200, r.text
    with StudyStore.open_readonly(study_path(study.folder)) as s:
        rid = s.run_id(pid, s.participant(pid).systems[0])
        rec = s.records(rid)[0]
        arrays = s.arrays(rid, 0)
    for t in tasks:
        assert rec["observed"][t] == pytest.approx(done[t].duration, abs=1e-3)
        np.testing.assert_allclose(arrays[f"human/{t}"].reshape(-1, 2),
                                   done[t].trajectory.reshape(-1, 2), atol=1e-4)


@pytest.mark.parametrize(("fields", "extra", "message"), [
    ({"source": "typed"}, {}, "type the duration"),
    ({"source": "typed", "d:*": "abc"}, {}, "positive number"),
    ({"source": "typed", "d:*": "-2"}, {}, "positive number"),
    ({"source": "typed", "d:*": "nan"}, {}, "positive number"),
    ({"source": "tracker"}, {}, "choose the tracker file"),
    ({"source": "tracker"}, {"tracker": "task,point,t,x,y\nnope,0,0,1,1\n"}, "does not do"),
    ({"source": "tracker"}, {"tracker": "task,t\n"}, "lacks column"),
    ({"source": "tracker"}, {"tracker": "task,point,t,x,y\n*,0,0,1,1\n*,0,1,900,1\n"},
     "metres"),
    ({"source": "teleport"}, {}, "choose where"),
    # bounds that no real task exceeds (fetch: 180 s), never a 500
    ({"source": "typed", "d:*": "4500"}, {}, "longer than any task of this study (180 s"),
    ({"source": "typed", "d:*": "1e12"}, {}, "longer than any task"),
    ({"source": "tracker"}, {"tracker": "task,point,t,x,y\n*,0,0,1,1\n*,0,1e12,1,1\n"},
     "longer than any task"),
    ({"source": "tracker"}, {"tracker": "[" * 100_000}, "nested too deeply"),
    ({"source": "tracker"}, {"tracker": "task,point,t,x,y," + ",".join(
        f"c{i}" for i in range(100_000)) + "\n*,0,0,1,1\n"}, "100005 columns"),
    ({"source": "tracker"}, {"tracker": json.dumps([{f"c{i}": 1 for i in range(40)}])},
     "more than 32 distinct fields"),
    # issue 35: JSON objects with different fields (pandas built objects x all fields), their
    # variants, and numbers too long for int()
    ({"source": "tracker"}, {"tracker": json.dumps(
        [{f"k{i}_{j}": 1 for j in range(30)} for i in range(2000)])},
     "more than 32 distinct fields"),
    ({"source": "tracker"}, {"tracker": json.dumps([{f"c{i}": 1} for i in range(60_000)])},
     "more than 32 distinct fields"),
    ({"source": "tracker"}, {"tracker": '[{"task": "*", "point": 0, "t": 1' + "1" * 5000
                                        + ', "x": 1, "y": 1}]'}, "not a finite number"),
    ({"source": "tracker"}, {"tracker": "task,point,t,x,y\n*,0," + "1" * 5000 + ",1,1\n"},
     "not a finite number"),
    ({"source": "simulated", "d:mix_r": "3"}, {}, "unknown field(s) in the round: d:mix_r"),
    ({"source": "tracker", "launch": "1"}, {}, "unknown field(s) in the round: launch"),
    # a design without the comfort item knows none of its fields
    ({"source": "simulated", "comfort": "4"}, {}, "unknown field(s) in the round: comfort"),
    ({"source": "simulated", "too_close": "1.5"}, {}, "unknown field(s) in the round: too_close"),
])
def test_bad_round_input_is_refused_with_a_message_and_nothing_stored(
        study: Study, fields: dict[str, str], extra: dict[str, str], message: str) -> None:
    pid = _pid(study)
    step = study.step(pid)
    tasks = _human_tasks(study, pid)
    fields = {k.replace("*", tasks[0]): v for k, v in fields.items()}
    for t in tasks[1:]:
        if any(k.startswith("d:") for k in fields):
            fields[f"d:{t}"] = "4.0"
    extra = {k: v.replace("*", tasks[0]) for k, v in extra.items()}
    r = study.post(pid, "round", step, fields, **extra)
    assert r.status_code == 400, r.text
    assert message in r.json()["error"]
    assert study.stored() == (0, 0, 0, 0)
    assert study.step(pid) == step  # the same round, ready for a corrected submit


@pytest.fixture()
def comfort_study(tmp_path: Path, fetch_world: FetchWorld,
                  fetch_policy: DiffusionPolicy) -> Iterator[Study]:
    """A study whose design asks the comfort item and whose runs learn gamma (--gamma learn)."""
    s = Study(make_study(tmp_path, fetch_world, comfort=True), fetch_world, fetch_policy)
    try:
        yield s
    finally:
        s.close()


@pytest.mark.parametrize(("fields", "message"), [
    ({"source": "simulated"}, "please answer \u201cThe robot came too close to me\u201d"),
    ({"source": "simulated", "comfort": "9"}, "the answer must be 1..7, got '9'"),
    ({"source": "simulated", "comfort": "0"}, "the answer must be 1..7"),
    ({"source": "simulated", "comfort": "4.5"}, "the answer must be 1..7"),
    ({"source": "simulated", "comfort": "abc"}, "the answer must be 1..7"),
    ({"source": "simulated", "comfort": "4", "too_close": "-1"}, "'-1' is not a time"),
    ({"source": "simulated", "comfort": "4", "too_close": "abc"}, "'abc' is not a time"),
    ({"source": "simulated", "comfort": "4", "too_close": "nan"}, "'nan' is not a time"),
    ({"source": "simulated", "comfort": "4", "too_close": "inf"}, "'inf' is not a time"),
    ({"source": "simulated", "comfort": "4", "too_close": "1e12"}, "'1e12' is not a time"),
    ({"source": "simulated", "comfort": "4", "too_close": "99999"}, "'99999' is not a time"),
    ({"source": "simulated", "comfort": "4", "too_close": "1.5,,2"}, "'' is not a time"),
    ({"source": "simulated", "comfort": "4", "too_close": ",".join(["1"] * 201)},
     "201 presses in one round, at most 200"),
    ({"source": "simulated", "comfort": "4", "bag": "x", "launch": "1"},
     "unknown field(s) in the round: launch"),
])
def test_bad_comfort_input_is_refused_with_a_message_and_nothing_stored(
        comfort_study: Study, fields: dict[str, str], message: str) -> None:
    pid = _pid(comfort_study)
    step = comfort_study.step(pid)
    r = comfort_study.post(pid, "round", step, fields)
    assert r.status_code == 400, r.text
    assert message in r.json()["error"]
    assert comfort_study.stored() == (0, 0, 0, 0)
    assert comfort_study.step(pid) == step


def test_the_comfort_item_goes_with_the_round_to_the_gamma_learner(comfort_study: Study) -> None:
    study = comfort_study
    pid = _pid(study)
    page = study.client.get(f"/p/{pid}").text
    assert "The robot came too close to me" in page and "name=too_close" in page
    assert "Too close!" in page and "name=comfort value=7" in page
    r = study.post(pid, "round", study.step(pid), {"source": "simulated", "comfort": "7",
                                                   "too_close": "2.5,0.75"})
    assert r.status_code == 200, r.text
    with StudyStore.open_readonly(study_path(study.folder)) as s:
        rid = s.run_id(pid, s.participant(pid).systems[0])
        rec = s.records(rid)[-1]
    said = rec["comfort"]
    assert said["answer"] == 7 and said["too_close"] == [0.75, 2.5]  # sorted, as sent
    assert "simulated" not in said  # the person said it, not the simulated cell's model
    assert len(said["closeness_at"]) == 2 and said["peak"] > 0
    belief = rec["gamma_belief"]
    assert belief["evidence"] == 1
    # "too close" at 7 of 7 moves the belief above the prior's median (the world's gamma)
    assert belief["median"] > study.world.problem().objective.gamma
    assert rec["gamma"] == pytest.approx(study.world.problem().objective.gamma)  # planned prior
    # a round played in the game has to bring the item too (the game asks it: tests of the
    # study's game source)
    with pytest.raises(InputError, match="please answer"):
        study.worker.run(lambda s: s._comfort("game", {}))


def test_malformed_requests_get_4xx_never_500(study: Study) -> None:
    pid = _pid(study)
    step = study.step(pid)
    c = study.client
    url = f"/api/p/{pid}/round"
    json_type = {"content-type": "application/json"}
    cases = [
        (c.post(url, content=b"{not json", headers={"content-type": "application/json"}), 422),
        (c.post(url, content=b"step=x", headers={"content-type": "text/plain"}), 415),
        (c.post(url, json={"step": step, "fields": {}, "surprise": 1}), 422),
        (c.post(url, json={"step": 3, "fields": {}}), 422),
        (c.post(url, json={"step": step, "fields": {"source": 5}}), 422),
        (c.post(url, json=[1, 2]), 422),
        (c.post(url, content=b"{}" + b" " * (MAX_BODY + 1),
                headers={"content-type": "application/json"}), 413),
        (c.post(url, json={"step": step, "fields": {"source": "simulated"}},
                headers={"origin": "http://evil.example"}), 403),
        (c.post("/api/p/P99/round", json={"step": step, "fields": {}}), 404),
        (c.post("/api/p/..%2F..%2Fetc/round", json={"step": step, "fields": {}}), 404),
        (c.post(f"/api/p/{pid}/launch", json={"step": step, "fields": {}}), 404),
        (c.post(f"/api/p/{pid}/survey", json={"step": step, "fields": {}}), 409),
        (c.get("/p/P99"), 404),
        (c.get("/", headers={"host": "rebind.example"}), 400),
        (c.post(url, content=b"[" * 100_000, headers=json_type), 422),  # RecursionError
        (c.post(url, content=b'{"step": "\\ud800", "fields": {}}', headers=json_type), 422),
        (c.post(url, content=b'{"step": "x", "fields": {"\\udfff": "1"}}', headers=json_type),
         422),
    ]
    for response, status in cases:
        assert response.status_code == status, (response.request.url, response.text)
        if response.request.url.path.startswith("/api/"):
            assert response.json()["error"]
    assert study.stored() == (0, 0, 0, 0)


def _finish_rounds(study: Study, pid: str) -> None:
    for _ in range(4):
        step = study.step(pid)
        assert step.startswith("round:")
        assert study.post(pid, "round", step, {"source": "simulated"}).status_code == 200
        if step.endswith(":1"):
            return


def test_survey_ranking_and_demographics_validate_and_store_once(study: Study) -> None:
    pid = _pid(study)
    items = study.worker.run(lambda s: s.items())
    _finish_rounds(study, pid)
    step = study.step(pid)
    assert step.startswith("survey:")
    page = study.client.get(f"/p/{pid}").text
    assert "The robot got in the way of me completing my tasks." in page
    answers = {i["id"]: str(1 + k % 7) for k, i in enumerate(items)}
    part = dict(list(answers.items())[:-1])
    r = study.post(pid, "survey", step, part)
    assert r.status_code == 400 and "please answer every statement" in r.json()["error"]
    r = study.post(pid, "survey", step, {**answers, items[0]["id"]: "8"})
    assert r.status_code == 400 and "1..7" in r.json()["error"]
    assert study.stored() == (2, 0, 0, 0)
    assert study.post(pid, "survey", step, answers).status_code == 200
    assert study.stored() == (2, len(items), 0, 0)
    assert study.post(pid, "survey", step, answers).status_code == 409  # never twice
    _finish_rounds(study, pid)
    assert study.post(pid, "survey", study.step(pid), answers).status_code == 200
    step = study.step(pid)
    assert step == "ranking"
    for bad, message in (({"rank1": "1", "rank2": "1"}, "exactly once"),
                         ({"rank1": "2"}, "place 2 is empty"),
                         ({"rank1": "2", "rank2": "3"}, "not one of the systems"),
                         ({"rank1": "2", "rank2": "1", "rank3": "1"}, "unknown field")):
        r = study.post(pid, "ranking", step, bad)
        assert r.status_code == 400 and message in r.json()["error"], r.text
    assert study.post(pid, "ranking", step, {"rank1": "2", "rank2": "1"}).status_code == 200
    step = study.step(pid)
    assert step == "demographics"
    r = study.post(pid, "demographics", step, {"age": "twenty"})
    assert r.status_code == 400 and "age" in r.json()["error"]
    r = study.post(pid, "demographics", step, {"age": "23", "handedness": "left", "gender": ""})
    assert r.status_code == 200
    assert "has finished every part" in study.client.get(f"/p/{pid}").text
    with StudyStore.open_readonly(study_path(study.folder)) as s:
        systems = s.participant(pid).systems
        assert s.rankings() == {pid: (systems[1], systems[0])}  # system 2 first
        assert s.demographics() == {pid: {"age": "23", "handedness": "left"}}
        survey = s.survey_frame()
    assert sorted(survey["system"].unique()) == sorted(systems)
    assert json.loads(survey.groupby("item")["value"].first().to_json()) == {
        i: int(v) for i, v in answers.items()}


def test_a_restarted_server_resumes_with_the_same_plan(study: Study) -> None:
    pid = _pid(study)
    assert study.post(pid, "round", study.step(pid), {"source": "simulated"}).status_code == 200
    step = study.step(pid)
    before = study.worker.run(lambda s: s.plan(pid))[1].as_dict()
    study.restart()  # a killed server: the plan was never stored, it is planned again
    assert study.step(pid) == step
    after = study.worker.run(lambda s: s.plan(pid))[1].as_dict()
    for key in ("human", "robot", "routes", "step"):
        assert after[key] == before[key]
    assert after["expected"] == pytest.approx(before["expected"])
    assert after["makespan"] == pytest.approx(before["makespan"])
    assert study.post(pid, "round", step, {"source": "simulated"}).status_code == 200
    assert study.stored() == (2, 0, 0, 0)


def test_a_group_without_a_simulated_person_needs_a_tracker_file(
        tmp_path: Path, fetch_world: FetchWorld, fetch_policy: DiffusionPolicy) -> None:


    design = StudyDesign(participants=1, systems=("full", "none"), rounds=1,
                         factors={"hand": ("left", "right")}, require_balance=False)
    create_study(tmp_path, design, RunConfig(world="fetch", **SEARCH).resolved(fetch_world)
                 ).close()
    study = Study(tmp_path, fetch_world, fetch_policy)
    try:
        pid = _pid(study)
        step = study.step(pid)
        for source in ("simulated", "typed"):
            r = study.post(pid, "round", step, {"source": source, "d:t0": "3"})
            assert r.status_code == 400 and "upload a tracker file" in r.json()["error"]
        page = study.client.get(f"/p/{pid}").text  # offers only what can work for them
        assert "value=tracker checked" in page
        assert "value=simulated" not in page and "value=typed" not in page
        tasks = _human_tasks(study, pid)
        done = fetch_world.teammate("slow-middle").execute(0, tasks, np.random.default_rng(1))
        r = study.post(pid, "round", step, {"source": "tracker"},
                       tracker=tracker_csv(done, fetch_world.dt))
        assert r.status_code == 200, r.text
        assert study.stored() == (1, 0, 0, 0)
    finally:
        study.close()


def test_serve_refuses_a_folder_without_a_study_in_one_line(tmp_path: Path) -> None:


    RunStore(tmp_path / "plain" / "study.sqlite").close()  # a run store, not a study
    env_path = str(Path(__file__).resolve().parents[1] / "src")
    for folder, message in ((tmp_path / "none", "holds no study"),
                            (tmp_path / "plain", "not a rapidds study store")):
        out = subprocess.run(
            cli_cmd("study", "serve", str(folder), "--port", "0"), capture_output=True,
            text=True, timeout=300, env={**os.environ, "PYTHONPATH": env_path})
        assert out.returncode == 2, out.stderr
        assert message in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr


def test_the_overview_is_the_experimenters_only_and_no_participant_page_links_to_it(
        study: Study) -> None:
    """The blind: the overview lists each participant's systems by name, so it needs the
    experimenter's token, and no page a participant sees leads to it."""
    pid = _pid(study)
    order = " → ".join(study.worker.run(lambda s: s.store.participant(pid).systems))
    for params in ({}, {"token": ""}, {"token": "guess"}, {"token": study.token[:-1]}):
        r = study.client.get("/", params=params)
        assert r.status_code == 403 and "experimenter" in r.text, params
        assert order not in r.text and f"/p/{pid}" not in r.text
    ok = study.client.get("/", params={"token": study.token})
    assert ok.status_code == 200 and order in ok.text
    seen = [study.client.get(f"/p/{pid}").text, study.client.get("/p/P99").text]
    _finish_rounds(study, pid)
    seen.append(study.client.get(f"/p/{pid}").text)  # the survey
    assert "Think of the first system" in seen[-1]
    for text in seen:
        assert "href='/'" not in text and 'href="/"' not in text and "overview" not in text
        assert study.token not in text and order not in text


def test_the_study_answers_on_the_ipv6_loopback(study: Study) -> None:
    """--host ::1: the address the server prints, http://[::1]:PORT/, works."""
    c = TestClient(create_study_app(study.worker, allowed_hosts("::1"), token="k"),
                   base_url="http://[::1]:8000")
    pid = _pid(study)
    assert c.get("/", params={"token": "k"}).status_code == 200
    page = c.get(f"/p/{pid}")
    assert page.status_code == 200 and "Round 1: the robot's plan" in page.text
    r = c.post(f"/api/p/{pid}/round", json={"step": study.step(pid),
                                             "fields": {"source": "simulated"}},
               headers={"origin": "http://[::1]:8000"})
    assert r.status_code == 200, r.text
    assert study.stored() == (1, 0, 0, 0)
    assert c.get(f"/p/{pid}", headers={"host": "rebind.example"}).status_code == 400


def test_study_serve_on_the_ipv6_loopback_prints_addresses_that_work(
        tmp_path: Path, fetch_world: FetchWorld) -> None:
    """``rapidds study serve --host ::1`` end to end: the participant address it prints answers,
    the overview answers to the experimenter's address it prints and to nothing else."""
    folder = make_study(tmp_path, fetch_world)
    server = CliServer("study", "serve", str(folder), "--host", "::1", "--port", "0", "--json")
    try:
        hello = json.loads(server.wait_for(lambda line: True, timeout=300))
        assert hello["url"].startswith("http://[::1]:") and hello["overview"].startswith(
            hello["url"] + "?token=")

        def get(url: str) -> tuple[int, str]:
            try:
                with urllib.request.urlopen(url, timeout=300) as r:
                    return r.status, r.read().decode()
            except urllib.error.HTTPError as exc:
                return exc.code, exc.read().decode()

        status, page = get(hello["url"] + "p/P01")
        assert status == 200 and "Round 1: the robot's plan" in page
        assert get(hello["url"])[0] == 403
        status, page = get(hello["overview"])
        assert status == 200 and "order of systems" in page
    finally:
        assert server.stop() == 0, "".join(server.err)[-2000:]


def test_a_number_too_long_for_int_in_the_body_is_400(study: Study) -> None:
    pid = _pid(study)
    body = b'{"step": "x", "fields": {}, "n": ' + b"1" * 5000 + b"}"
    r = study.client.post(f"/api/p/{pid}/round", content=body,
                          headers={"content-type": "application/json"})
    assert r.status_code == 400 and "number too long" in r.json()["error"]


def test_a_big_tracker_file_is_measured_unescaped_and_never_echoed(study: Study) -> None:
    """A 7.6 MiB file (JSON escaping makes its body past 8 MiB) is read, not refused for its
    size; what is wrong with it comes back in a line, never the file."""
    pid = _pid(study)
    step = study.step(pid)
    row = '"zz",0,1.000,1.000,1.000\n'
    text = "task,point,t,x,y\n" + row * int(7.6 * 2**20 / len(row))
    r = study.post(pid, "round", step, {"source": "tracker"}, tracker=text)
    assert r.status_code == 400 and "larger than" not in r.json()["error"], r.text[:300]
    assert "does not do this round" in r.json()["error"] and len(r.content) < 1000
    huge = "task,point,t,x,y\n" + "a" * (7 * 2**20) + ",0,0,1,1\n"
    r = study.post(pid, "round", step, {"source": "tracker"}, tracker=huge)
    assert r.status_code == 400 and len(r.content) < 1000, r.text[:300]
    assert study.stored() == (0, 0, 0, 0)


def test_a_bad_bag_is_named_without_the_servers_folder(study: Study) -> None:
    pid = _pid(study)
    (study.folder / "bags").mkdir()
    (study.folder / "bags" / "round1.bag").write_bytes(b"not a bag")
    for name in ("round1.bag", "missing.bag"):
        r = study.post(pid, "round", study.step(pid), {"source": "bag", "bag": name})
        assert r.status_code == 400, r.text
        said = r.json()["error"]
        assert name in said and str(study.folder) not in said and "/tmp" not in said, said


def test_study_serve_stops_on_sigterm_as_on_ctrl_c(tmp_path: Path,
                                                   fetch_world: FetchWorld) -> None:
    """A service manager's stop (SIGTERM): exit 0 with the closing summary, as Ctrl-C."""
    folder = make_study(tmp_path, fetch_world)
    server = CliServer("study", "serve", str(folder), "--port", "0", "--json")
    try:
        json.loads(server.wait_for(lambda line: True, timeout=300))
        assert server.stop(signal.SIGTERM) == 0, "".join(server.err)[-2000:]
        assert json.loads(server.out_lines[-1])["stopped"] is True
    finally:
        server.kill()
