"""``rapidds play --gamma learn`` in a real headless Chromium: the person presses T ("too close")
during the cycle and answers the comfort question on the page once it is over; the stored cycle
holds both, and the run goes on only after the answer."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from browser_helpers import NEEDS_CHROMIUM, open_page
from play_bot import RouteBot, play_cycle
from test_play_browser import Server

from rapidds.store import RunStore
from rapidds.worlds.fetch.world import FetchWorld

pytestmark = NEEDS_CHROMIUM


def test_the_page_takes_too_close_and_the_comfort_answer(
        browser: Any, tmp_path: Path, fetch_world: FetchWorld) -> None:
    out = tmp_path / "play"
    server = Server(out, "--gamma", "learn", "--cycles", "1")
    try:
        page = open_page(browser, server.url)
        assert page.is_hidden("#comfort")
        _, end = play_cycle(page, RouteBot(fetch_world), 0, signal_at=0.5)
        assert end["signals"] == 1
        page.wait_for_selector("#comfort", state="visible", timeout=30_000)  # asked once over
        assert "too close" in page.inner_text("#comfort")
        page.keyboard.press("9")  # no such answer: the page sends nothing
        page.click("#comfort-answers button[data-answer='5']")
        page.wait_for_function("window.rapidds.phase === 'done'", timeout=60_000)
        page.wait_for_selector("#comfort", state="hidden", timeout=5_000)
        assert page.errors == []
        page.close()
    finally:
        server.stop()
    with RunStore(out / "run.sqlite") as store:
        (rec,) = store.records("fetch-player-full-glearn-s1")
    assert rec["comfort"]["answer"] == 5 and len(rec["comfort"]["too_close"]) == 1
    assert 0.5 <= rec["comfort"]["too_close"][0] <= end["t"]
    assert rec["gamma_belief"]["evidence"] == 1
