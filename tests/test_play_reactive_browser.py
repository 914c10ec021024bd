"""``rapidds play --execution reactive`` in a real headless Chromium: the bot plays one cycle
with the arrow keys and dawdles with its last object; the page shows the robot's state and the
re-plan, and the stored cycle holds the order the bot took and the re-plan its overrun caused.

In this job's first plan (the person t2 then t0, the robot t3 then t1) precedence leaves the
person no other order, and the robot starts each task the moment it may: an overrun is the
deviation a person can make there (another order and a taken robot task are played, on
hand-made plans, in tests/test_play_reactive.py).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from browser_helpers import NEEDS_CHROMIUM, CliServer, close_and_stop, open_page
from play_bot import RouteBot, human_tasks, play_cycle

from rapidds.store import RunStore
from rapidds.worlds.fetch.world import FetchWorld

pytestmark = NEEDS_CHROMIUM
SEARCH = ["--population", "8", "--generations", "4", "--samples", "8", "--particles", "2",
          "--candidates", "4"]
RUN_ID = "fetch-player-full-reactive-s1"


def test_the_robot_reacts_live_in_the_browser_and_the_cycle_is_stored(
        browser: Any, tmp_path: Path, fetch_world: FetchWorld) -> None:
    server = CliServer("play", "fetch", "--port", "0", "--out", str(tmp_path), "--cycles", "1",
                       "--seed", "1", "--execution", "reactive", *SEARCH)
    try:
        line = server.wait_for(lambda line: "open http://" in line)
        page = open_page(browser, line.split("open ", 1)[1].split()[0])
        page.wait_for_function("window.rapidds.phase === 'ready'", timeout=90_000)
        plan = page.evaluate("window.rapidds.plan")
        last = human_tasks(plan["sequences"]["human"])[-1]
        bot = RouteBot(fetch_world, hold={last: 4.0})  # past its learned mean + 1.28 sd
        _, end = play_cycle(page, bot, 0)
        assert end["execution"] == "reactive"
        assert [(r["reason"], r["task"]) for r in end["replans"]] == [("overran", last)]
        line = page.evaluate("document.getElementById('robot-state').textContent")
        assert line.startswith("Robot") and "re-planned at" in line and "ran long" in line
        # the cycle is stored (and the run finished) before the server is stopped
        page.wait_for_function("window.rapidds.phase === 'done'", timeout=60_000)
        close_and_stop(page, server)
    finally:
        server.kill()
    with RunStore(tmp_path / "run.sqlite") as store:
        (rec,) = store.records(RUN_ID)
    took = sorted((t for t in end["times"] if end["owner"][t] == "human"),
                  key=lambda t: end["times"][t][0])
    assert rec["executed"]["human"] == took  # the order the bot fetched in, as the page saw it
    assert [(r["reason"], r["task"]) for r in rec["replans"]] == [("overran", last)]
    for t, (s, f) in end["times"].items():
        assert rec["realised"]["timeline"][t] == pytest.approx([s, f], abs=2e-3)
