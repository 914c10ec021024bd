"""Study game rounds: how long a participant waits between rounds played in the browser game.

Designs a fetch study (``rapidds study design --world fetch --systems full,none``, default
search settings) in a temporary folder, starts ``rapidds study serve --json --verbose`` in a
process of its own, and plays participant P01's rounds of their first system in a headless
Chromium (Debian's, through Playwright's ``executable_path``) with the test suite's route bot
(``tests/play_bot.py``: arrow keys along the world's human routes). Reported per round: the game
time when the cycle was over, how long recording the round took in the server and whether the
robot was still finishing then, the next round's plan, and the wait from the game's last state
to the next study page loaded (it includes the page's 0.6 s pause on "Round recorded").

    .venv/bin/python benchmarks/bench_study_game.py [--rounds 3] [--update-docs]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import cpu_model, load_average, update_docs_section

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the route bot and the Chromium lookup of the tests

from browser_helpers import ARGS, CHROMIUM, CliServer  # noqa: E402
from play_bot import RouteBot, play_cycle  # noqa: E402

SECTION = "## Study game rounds"
_LOG = re.compile(r"(round:\S+) recorded in ([\d.]+) s \(game time ([\d.]+) s, cycle ([a-z ]+)\)"
                  r", next plan in ([\d.]+) s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--update-docs", action="store_true")
    args = ap.parse_args()
    if CHROMIUM is None:
        sys.exit("no Chromium: apt-get install chromium (never 'playwright install')")
    from playwright.sync_api import sync_playwright

    from rapidds.worlds.registry import make_world

    world = make_world("fetch")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "study"
        subprocess.run([sys.executable, "-c", "from rapidds.cli import main; main()", "study",
                        "design", "--world", "fetch", "--participants", "8", "--systems",
                        "full,none", "--rounds", str(args.rounds), "--out", str(folder)],
                       check=True, capture_output=True)
        t0 = time.perf_counter()
        server = CliServer("study", "serve", str(folder), "--port", "0", "--json", "--verbose")
        url = json.loads(server.wait_for(lambda line: True, timeout=600))["url"]
        listening = time.perf_counter() - t0
        bot = RouteBot(world, {"t2": "middle", "t3": "outside"})
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
            page = browser.new_page(viewport={"width": 1040, "height": 820}, bypass_csp=True)
            t = time.perf_counter()
            page.goto(f"{url}p/P01", timeout=600_000)
            page.wait_for_selector("#input", timeout=600_000)
            first = time.perf_counter() - t
            for rnd in range(args.rounds):
                with page.expect_navigation(timeout=600_000):
                    page.click("a.play")
                _, end = play_cycle(page, bot, rnd)
                over = time.perf_counter()
                page.wait_for_url("**/p/P01", timeout=600_000)
                page.wait_for_selector("#input, #survey", timeout=600_000)
                rows.append({"round": rnd + 1, "game": end["t"],
                             "wait": time.perf_counter() - over, "load": load_average()})
                print(rows[-1], flush=True)
            browser.close()
        server.stop()
    logged = [m.groups() for m in map(_LOG.search, server.err) if m]
    lines = [
        f"`benchmarks/bench_study_game.py --rounds {args.rounds}`: a fetch study (systems full, "
        "none; default search settings), `rapidds study serve` in its own process, participant "
        "P01's rounds of their first system played in headless Chromium by the tests' route bot. "
        f"Machine: {cpu_model()}, 2 cores shared with other sessions' tests (1-minute load "
        "average in the table). Server listening after "
        f"{listening:.1f} s; first round page {first:.2f} s.",
        "",
        "| round | game over at (s) | record (s) | robot still going at record | next plan (s) "
        "| game end to next study page (s) | load |",
        "|---|---|---|---|---|---|---|",
    ]
    for row, log in zip(rows, logged, strict=False):
        lines.append(f"| {row['round']} | {row['game']:.1f} | {float(log[1]):.2f} | "
                     f"{'yes' if log[3] != 'over' else 'no'} | {float(log[4]):.2f} | "
                     f"{row['wait']:.2f} | {row['load']} |")
    lines += ["", "The wait includes the game page's 0.6 s pause on \u201cRound recorded\u201d; "
              "the last round's next page is the survey (no plan)."]
    text = "\n".join(lines)
    print(text)
    if args.update_docs:
        update_docs_section(SECTION, text)


if __name__ == "__main__":
    main()
