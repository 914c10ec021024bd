"""``rapidds play`` end to end: the server as a subprocess, a real headless Chromium (Debian's,
through Playwright's ``executable_path``; never ``playwright install``) and a bot that presses the
arrow keys to walk the plan's routes. Two cycles are played and stored with the person's
durations and paths, the second planned with what the first taught; a second browser is turned
away; the server is killed mid-cycle and ``--resume`` continues with the learned models; Ctrl-C
stops it cleanly.

``RAPIDDS_SCREENSHOTS=1`` also writes docs/figures/play-midcycle.png and
docs/figures/play-summary.png.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path
from typing import Any

from browser_helpers import NEEDS_CHROMIUM, ROOT, SHOTS, CliServer, open_page
from play_bot import RouteBot, check_planned_with, check_played, play_cycle

from rapidds.store import RunStore
from rapidds.worlds.fetch.world import FetchWorld

pytestmark = NEEDS_CHROMIUM
SEARCH = ["--population", "8", "--generations", "4", "--samples", "8", "--particles", "2",
          "--candidates", "4"]
RUN_ID = "fetch-player-full-s1"


class Server(CliServer):
    """``rapidds play`` in a subprocess on a free port; ``url`` once it listens."""

    def __init__(self, out: Path, *extra: str):
        super().__init__("play", "fetch", "--port", "0", "--out", str(out), "--cycles", "3",
                         "--seed", "1", *SEARCH, *extra)
        line = self.wait_for(lambda line: "open http://" in line)
        self.url = line.split("open ", 1)[1].split()[0]


def test_two_cycles_in_the_browser_are_learned_and_a_killed_server_resumes(
        browser: Any, tmp_path: Path, fetch_world: FetchWorld) -> None:
    out = tmp_path / "play"
    bot = RouteBot(fetch_world, {"t2": "middle", "t3": "outside"})
    server = Server(out)
    try:
        page = open_page(browser, server.url)
        plan0, end0 = play_cycle(page, bot, 0)
        # a second browser for the same run is turned away, politely
        other = open_page(browser, server.url)
        other.wait_for_function("window.rapidds.refused !== null", timeout=20_000)
        assert "played elsewhere" in other.inner_text("#instruction")
        other.close()
        plan1, end1 = play_cycle(page, bot, 1, midcycle_shot=(
            ROOT / "docs" / "figures" / "play-midcycle.png" if SHOTS else None))
        page.wait_for_function("window.rapidds.summary && window.rapidds.summary.cycle === 1",
                               timeout=30_000)
        summary = page.evaluate("window.rapidds.summary")
        assert [p["cycle"] for p in summary["curve"]] == [0, 1]
        assert "s" in page.inner_text("#s-makespan")
        if SHOTS:
            page.check("#heat")
            page.wait_for_function("window.rapidds.phase === 'ready'", timeout=60_000)
            time.sleep(0.3)
            page.screenshot(path=str(ROOT / "docs" / "figures" / "play-summary.png"))
            page.uncheck("#heat")
        # the third cycle is under way when the server is killed: it is lost, nothing else
        play_cycle(page, bot, 2, stop_at=1.5)
        server.proc.kill()
        server.proc.wait(30)
        assert page.errors == []
        page.close()
    finally:
        if server.proc.poll() is None:
            server.proc.kill()

    with RunStore(out / "run.sqlite") as store:
        recs = check_played(store, RUN_ID, [(plan0, end0), (plan1, end1)], fetch_world,
                            bot.modes)
    # the second plan was made with the learned belief, not the prior
    check_planned_with(plan1, recs[0])
    learned = recs[0]["belief"]["mean_durations"]
    prior = {t: fetch_world.problem().task(t).human_mean for t in learned}
    assert any(abs(learned[t] - prior[t]) > 0.3 for t in recs[0]["observed"])

    # resume: the lost cycle is planned again from the stored model, and played
    server = Server(out, "--resume")
    try:
        assert "cycle 3 of 3" in server.out_lines[-1]
        page = open_page(browser, server.url)
        plan2, _ = play_cycle(page, bot, 2)
        check_planned_with(plan2, recs[1])
        page.wait_for_function("window.rapidds.phase === 'done'", timeout=60_000)
        assert "All cycles played" in page.inner_text("#instruction")
        assert page.errors == []
        page.close()
        assert server.stop(signal.SIGINT) == 0  # Ctrl-C
    finally:
        if server.proc.poll() is None:
            server.proc.kill()
    assert any("stopped: 3 of 3 cycles" in line for line in server.out_lines), server.out_lines
    with RunStore(out / "run.sqlite") as store:
        assert [r["cycle"] for r in store.records(RUN_ID)] == [0, 1, 2]
    assert (out / f"{RUN_ID}-cost.png").is_file() and (out / f"{RUN_ID}-map.png").is_file()
