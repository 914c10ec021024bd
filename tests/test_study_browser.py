"""``rapidds study serve`` end to end: the server as a subprocess, a real headless Chromium
(Debian's, through Playwright's ``executable_path``; never ``playwright install``) walks one
participant through two systems x two rounds (a tracker file, durations typed in, the simulated
cell), the survey after each system, the ranking and the demographics form, with a mistake on
each form shown on the page; the server is killed mid-study and restarted, and the page goes on
where it stopped with the same plan. The store is checked at the end. A second participant's
two rounds are played in the browser game (the "game" source) by a bot pressing arrow keys, and
stored with what the game observed.

``RAPIDDS_SCREENSHOTS=1`` also writes docs/figures/study-plan.png, study-input.png,
study-survey.png, study-ranking.png and study-game.png.
"""

from __future__ import annotations

import json
import signal
import socket
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from browser_helpers import NEEDS_CHROMIUM, ROOT, SHOTS, CliServer, close_and_stop, open_page
from play_bot import RouteBot, check_planned_with, check_played, play_cycle
from study_helpers import make_study

from rapidds.experiments.study.store import StudyStore, study_path
from rapidds.web.study.tracker import tracker_csv
from rapidds.worlds.fetch.world import FetchWorld

pytestmark = NEEDS_CHROMIUM
WAIT = 120_000  # ms: a page that plans (seconds on a loaded 2-core machine)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Server(CliServer):
    """``rapidds study serve DIR --json`` in a subprocess; ``url`` once it listens."""

    def __init__(self, folder: Path, port: int):
        super().__init__("study", "serve", str(folder), "--port", str(port), "--json")
        self.hello = json.loads(self.wait_for(lambda line: True))
        self.url = self.hello["url"]


def _submit(page: Any) -> None:
    """Click the form's button and wait for the next page (a refused submit stays: use
    :func:`_refused` for those)."""
    with page.expect_navigation(timeout=WAIT):
        page.click("button[type=submit]")


def _refused(page: Any, message: str) -> None:
    page.click("button[type=submit]")
    page.wait_for_function("document.querySelector('.error').textContent.length > 0",
                           timeout=WAIT)
    assert message in page.inner_text(".error")


def _plan(page: Any) -> dict[str, Any]:
    """What the round page says of the plan: header, sequences, motions, the person's tasks."""
    page.wait_for_selector("#plan", timeout=WAIT)
    return {"where": page.inner_text("header .where"),
            "plan": page.inner_text("#plan"),
            "tasks": page.eval_on_selector_all("input[name^='d:']",
                                               "els => els.map(e => e.name.slice(2))")}


def _shot(page: Any, selector: str, name: str) -> None:
    if SHOTS:
        page.locator(selector).screenshot(path=str(ROOT / "docs" / "figures" / name))


def test_one_participant_through_two_systems_in_the_browser_with_a_restart(
        browser: Any, tmp_path: Path, fetch_world: FetchWorld) -> None:
    folder = make_study(tmp_path, fetch_world)
    with StudyStore.open_readonly(study_path(folder)) as s:
        person = s.participants()[0]
        items = s.items.items
    pid, systems = person.id, person.systems
    mate = fetch_world.teammate(person.group)
    port = _free_port()
    server = Server(folder, port)
    assert server.hello["participants"] == 1 and server.hello["unfinished"] == 1
    observed: dict[int, dict[str, float]] = {}
    try:
        page = open_page(browser, server.hello["overview"], width=1000, height=900)
        assert "order of systems" in page.inner_text("#overview")  # the experimenter's address
        with page.expect_navigation(timeout=WAIT):
            page.click(f"a[href='/p/{pid}']")

        # system 1, round 1: a tracker file
        plan = _plan(page)
        assert "system 1 of 2" in plan["where"] and "round 1 of 2" in plan["where"]
        _shot(page, "#plan", "study-plan.png")
        done = mate.execute(0, plan["tasks"], np.random.default_rng(11))
        observed[0] = {t: ex.duration for t, ex in done.items()}
        page.set_input_files("input[name=tracker_file]", files=[{
            "name": "round1.csv", "mimeType": "text/csv",
            "buffer": tracker_csv(done, fetch_world.dt, t0=30.0).encode()}])
        _submit(page)

        # system 1, round 2: durations typed in, a mistake first
        plan = _plan(page)
        assert "round 2 of 2" in plan["where"]
        page.check("input[name=source][value=typed]")
        typed = {t: round(4.0 + 0.5 * i, 2) for i, t in enumerate(plan["tasks"])}
        for t, d in typed.items():
            page.fill(f"input[name='d:{t}']", str(d))
        page.fill(f"input[name='d:{plan['tasks'][0]}']", "-3")
        _refused(page, "positive number")
        _shot(page, "#input", "study-input.png")
        page.fill(f"input[name='d:{plan['tasks'][0]}']", str(typed[plan["tasks"][0]]))
        _submit(page)
        observed[1] = typed

        # the survey about system 1, one statement left out first
        page.wait_for_selector("#survey", timeout=WAIT)
        assert "The robot got in the way of me completing my tasks." in page.inner_text(
            "#survey")
        for k, item in enumerate(items[:-1]):
            page.check(f"input[name='{item.id}'][value='{1 + k % 7}']")
        _refused(page, "please answer every statement")
        page.check(f"input[name='{items[-1].id}'][value='6']")
        _shot(page, "#survey", "study-survey.png")
        _submit(page)

        # system 2, round 1: the simulated cell
        plan = _plan(page)
        assert "system 2 of 2" in plan["where"] and "round 1 of 2" in plan["where"]
        page.check("input[name=source][value=simulated]")
        _submit(page)
        before = _plan(page)
        assert "round 2 of 2" in before["where"]

        # the server is killed: nothing is lost, the restarted one shows the same plan
        server.proc.kill()
        server.proc.wait(30)
        server = Server(folder, port)
        page.reload()
        after = _plan(page)
        assert after == before
        page.check("input[name=source][value=simulated]")
        _submit(page)

        # the survey about system 2, then the ranking (a system twice first), demographics
        page.wait_for_selector("#survey", timeout=WAIT)
        for item in items:
            page.check(f"input[name='{item.id}'][value='3']")
        _submit(page)
        page.wait_for_selector("#ranking", timeout=WAIT)
        page.select_option("select[name=rank1]", "2")
        page.select_option("select[name=rank2]", "2")
        _refused(page, "each system exactly once")
        page.select_option("select[name=rank2]", "1")
        _shot(page, "#ranking", "study-ranking.png")
        _submit(page)
        page.wait_for_selector("#demographics", timeout=WAIT)
        page.fill("input[name=age]", "27")
        page.fill("input[name=handedness]", "right")
        _submit(page)
        assert "has finished every part" in page.inner_text("#done")
        assert page.errors == []
        page.close()
        assert server.stop(signal.SIGINT) == 0
        bye = json.loads(server.out_lines[-1])
        assert bye["stopped"] and bye["next"] == {}
    finally:
        if server.proc.poll() is None:
            server.proc.kill()

    with StudyStore.open_readonly(study_path(folder)) as s:
        assert s.next_step(pid).kind == "done"
        first = s.records(s.run_id(pid, systems[0]))
        second = s.records(s.run_id(pid, systems[1]))
        assert [r["cycle"] for r in first] == [0, 1] and [r["cycle"] for r in second] == [0, 1]
        for rec in first:
            assert rec["observed"] == pytest.approx(observed[rec["cycle"]], abs=1e-3)
        assert all(r["observed"] for r in second)
        survey = s.survey_frame()
        assert len(survey) == 2 * len(items)
        by = survey.set_index(["system", "item"])["value"]
        assert by[(systems[0], items[-1].id)] == 6 and by[(systems[1], items[0].id)] == 3
        assert s.rankings() == {pid: (systems[1], systems[0])}
        assert s.demographics() == {pid: {"age": "27", "handedness": "right"}}


def test_two_rounds_played_in_the_game_are_stored_as_the_study_rounds(
        browser: Any, tmp_path: Path, fetch_world: FetchWorld) -> None:
    folder = make_study(tmp_path, fetch_world)
    with StudyStore.open_readonly(study_path(folder)) as s:
        person = s.participants()[0]
    pid, system = person.id, person.systems[0]
    assert system == "full"  # the second round is planned with what the first taught
    modes = {"t2": "middle", "t3": "outside"}
    port = _free_port()
    server = Server(folder, port)
    played: list[tuple[dict[str, Any], dict[str, Any]]] = []
    waits: list[float] = []
    try:
        page = open_page(browser, f"{server.url}p/{pid}")
        for rnd in (0, 1):
            assert f"round {rnd + 1} of 2" in _plan(page)["where"]
            with page.expect_navigation(timeout=WAIT):
                page.click("a.play")
            shot = ROOT / "docs" / "figures" / "study-game.png" if SHOTS and rnd == 0 else None
            if rnd == 1:  # the server is killed mid-round: the round is lost, nothing else
                before, _ = play_cycle(page, RouteBot(fetch_world, modes), rnd, stop_at=1.0)
                server.proc.kill()
                server.proc.wait(30)
                with StudyStore.open_readonly(study_path(folder)) as s:
                    assert len(s.records()) == 1
                server = Server(folder, port)  # the page reconnects by itself
            played.append(play_cycle(page, RouteBot(fetch_world, modes), rnd,
                                     midcycle_shot=shot))
            if rnd == 1:  # and plays the same plan again
                after = played[-1][0]
                assert after["sequences"] == before["sequences"]
                for t, span in before["expected"].items():
                    assert after["expected"][t] == pytest.approx(span, abs=1e-6)
            over = time.monotonic()
            # recorded, and the page goes on to the study's next step by itself
            page.wait_for_url(f"**/p/{pid}", timeout=WAIT)
            page.wait_for_selector("#survey" if rnd else "#input", timeout=WAIT)
            waits.append(time.monotonic() - over)
        close_and_stop(page, server)
    finally:
        server.kill()
    print(f"from the end of a game round to the next study page: "
          f"{', '.join(f'{w:.2f}' for w in waits)} s")

    with StudyStore.open_readonly(study_path(folder)) as s:
        assert s.next_step(pid).kind == "survey"
        recs = check_played(s, s.run_id(pid, system), played, fetch_world, modes)
    # the second round's plan is the learned model's, not the prior's
    check_planned_with(played[1][0], recs[0])
    learned = recs[0]["belief"]["mean_durations"]
    prior = {t: fetch_world.problem().task(t).human_mean for t in learned}
    assert any(abs(learned[t] - prior[t]) > 0.3 for t in recs[0]["observed"])


def test_the_comfort_item_and_too_close_presses_are_sent_with_the_round(
        browser: Any, tmp_path: Path, fetch_world: FetchWorld) -> None:
    """A design with the comfort item: the "too close" button waits for the round clock, the
    answer is required, and the presses (seconds on the page's round clock) are stored."""
    folder = make_study(tmp_path, fetch_world, comfort=True)
    with StudyStore.open_readonly(study_path(folder)) as s:
        pid = s.participants()[0].id
    server = Server(folder, _free_port())
    try:
        page = open_page(browser, f"{server.url}p/{pid}", width=1000, height=900)
        _plan(page)
        assert page.is_disabled("button.too-close")  # no clock yet: a press has no time
        page.check("input[name=source][value=simulated]")
        _refused(page, "please answer")
        page.click("button.clock")
        page.click("button.too-close")
        page.click("button.too-close")
        assert page.inner_text(".presses").startswith("2 presses")
        page.check("input[name=comfort][value='5']")
        _submit(page)
        assert page.errors == []
    finally:
        server.stop()
    with StudyStore.open_readonly(study_path(folder)) as s:
        rec = s.records(s.run_id(pid, s.participant(pid).systems[0]))[0]
    said = rec["comfort"]
    assert said["answer"] == 5 and len(said["too_close"]) == 2
    assert 0 <= said["too_close"][0] <= said["too_close"][1]  # seconds since the clock, in order
    assert rec["gamma_belief"]["evidence"] == 1
