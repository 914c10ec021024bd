"""Study app: how long an experimenter waits for ``rapidds study serve`` on the paper's world.

Designs a painting study (``rapidds study design``, default search settings) in a temporary
folder, starts ``rapidds study serve --json`` in a process of its own and, as a browser would,
walks participant P01 through their first ``--systems`` systems (every round from the simulated
cell, then the survey) over HTTP. Reported: seconds until the server listens, and per round the
submit (learn + store, one transaction) and the next page (its plan, made in the server's worker
right after the submit; the first round of a system plans from the population prior).

    .venv/bin/python benchmarks/bench_study_serve.py [--systems 2] [--rounds 7]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-c", "from rapidds.cli import main; main()"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--systems", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args()
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "study"
        subprocess.run([*CLI, "study", "design", "painting", "--participants", "16",
                        "--rounds", str(args.rounds), "--out", str(folder)], check=True,
                       env=env, capture_output=True)
        t0 = time.perf_counter()
        proc = subprocess.Popen([*CLI, "study", "serve", str(folder), "--port", "0", "--json"],
                                stdout=subprocess.PIPE, text=True, env=env)
        assert proc.stdout is not None
        url = json.loads(proc.stdout.readline())["url"].rstrip("/")
        print(f"listening after {time.perf_counter() - t0:.1f} s "
              f"(load {os.getloadavg()[0]:.2f})", flush=True)

        def call(path: str, body: dict | None = None) -> tuple[str, float]:
            t = time.perf_counter()
            req = urllib.request.Request(
                url + path, data=None if body is None else json.dumps(body).encode(),
                headers={"Content-Type": "application/json"})
            with urllib.request.urlopen(req, timeout=900) as r:
                text = r.read().decode()
            return text, time.perf_counter() - t

        page, first = call("/p/P01")
        print("| system | round | submit (s) | next page (s) | load |\n|---|---|---|---|---|")
        print(f"| 1 | 1 | - | {first:.2f} | {os.getloadavg()[0]:.2f} |", flush=True)
        try:
            for block in range(1, args.systems + 1):
                for r in range(1, args.rounds + 1):
                    step = page.split("data-step='", 1)[1].split("'", 1)[0]
                    _, submit = call("/api/p/P01/round",
                                     {"step": step, "fields": {"source": "simulated"}})
                    page, wait = call("/p/P01")
                    if r == args.rounds:  # the survey page: answer it, then the next plan
                        step = page.split("data-step='", 1)[1].split("'", 1)[0]
                        ids = sorted({x.split("'")[0] for x in page.split("name='")[1:]})
                        call("/api/p/P01/survey", {"step": step, "fields": dict.fromkeys(ids,
                                                                                         "4")})
                        if block == args.systems:
                            print(f"| {block} | {r} | {submit:.2f} | (survey) | "
                                  f"{os.getloadavg()[0]:.2f} |")
                            break
                        page, wait = call("/p/P01")
                    nxt = (block + 1, 1) if r == args.rounds else (block, r + 1)
                    print(f"| {block} | {r} | {submit:.2f} | {wait:.2f} (plan of "
                          f"{nxt[0]}.{nxt[1]}) | {os.getloadavg()[0]:.2f} |", flush=True)
        finally:
            proc.send_signal(signal.SIGINT)
            proc.wait(60)


if __name__ == "__main__":
    main()
