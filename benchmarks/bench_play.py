"""Browser game: does the server hold its 60 Hz state updates while the planner plans?

Each condition starts a game server in a fresh process (the same PlaySession, FastAPI app and
uvicorn server as ``rapidds play``, default search settings), connects a WebSocket client from
this process, starts the cycle and walks the avatar back and forth (so every tick moves it and
checks the walls), then counts the state messages the client receives for ``--seconds``:

* ``idle``: nothing else runs in the server (the planner waits for the person);
* ``thread``: a thread in the server process plans fetch cycles back to back (``AdaptiveRun.plan``
  with the default GA and steering settings), as the session's worker thread does between
  cycles, sharing the GIL with the tick;
* ``process``: the same planning in a separate process, for comparison.

Reported: state messages per second, the gaps between them (p50, p99, max), how far the game
clock drifts from the wall clock, and how many plans the planner finished meanwhile.

    .venv/bin/python benchmarks/bench_play.py [--seconds 10] [--update-docs]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from _common import cpu_model, load_average, update_docs_section

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## Browser game"
MODES = ("idle", "thread", "process")


# -- the server side (a child process) ----------------------------------------------------------
def _plan_forever(count_file: str, stop: threading.Event | None = None) -> None:
    import torch

    from rapidds.loop.config import RunConfig
    from rapidds.loop.run import AdaptiveRun

    torch.set_num_threads(1)
    run = AdaptiveRun(RunConfig(human="fast-middle", cycles=100))
    n = 0
    while stop is None or not stop.is_set():
        run.plan()
        n += 1
        Path(count_file).write_text(str(n))


def serve(mode: str, port_file: str, count_file: str) -> None:
    import torch

    from rapidds.loop.config import RunConfig
    from rapidds.loop.run import load_policy
    from rapidds.web.player import BrowserPlayer
    from rapidds.web.server import listen
    from rapidds.web.server import serve as serve_app
    from rapidds.web.session import PlaySession
    from rapidds.worlds.registry import make_world

    torch.set_num_threads(1)
    world = make_world("fetch")
    out = Path(tempfile.mkdtemp(prefix="bench-play-"))
    session = PlaySession(RunConfig(human="bench", cycles=100), out, world=world,
                          policy=load_policy(world), player=BrowserPlayer(world, "bench"))
    session.open()
    planner, stop, thread = None, threading.Event(), None
    if mode == "thread":
        thread = threading.Thread(target=_plan_forever, args=(count_file, stop), daemon=True)
        thread.start()
    elif mode == "process":
        planner = mp.get_context("spawn").Process(target=_plan_forever, args=(count_file,),
                                                  daemon=True)
        planner.start()
    while mode != "idle" and not Path(count_file).exists():  # measure planning, not start-up
        time.sleep(0.1)
    sock = listen("127.0.0.1", 0)
    Path(port_file).write_text(str(sock.getsockname()[1]))
    try:
        serve_app(session, sock)
    except KeyboardInterrupt:  # the parent's SIGINT, re-raised by uvicorn after shutting down
        pass
    finally:
        session.stop()
        stop.set()
        if thread is not None:
            thread.join(60)
        if planner is not None:
            planner.terminate()
            planner.join(10)


# -- the client side ----------------------------------------------------------------------------
async def _measure(port: int, seconds: float, count_file: Path) -> dict[str, float]:
    import websockets

    async with websockets.connect(f"ws://127.0.0.1:{port}/ws", max_size=2**22) as ws:
        seq = 0
        cycle = None
        while cycle is None:  # wait for the first plan
            msg = json.loads(await ws.recv())
            if msg["type"] == "phase" and msg["phase"] == "ready":
                cycle = msg["cycle"]
        seq += 1
        await ws.send(json.dumps({"type": "start", "seq": seq, "cycle": cycle}))
        targets = [(2.2, 9.3), (2.2, 5.6)]  # up and down beside the home, inside the fence
        # warm up 1 s: the page's first burst (scene, plan) is over
        t_end = time.perf_counter() + 1.0
        while time.perf_counter() < t_end:
            await ws.recv()
        plans0 = int(count_file.read_text()) if count_file.exists() else 0
        arrivals, clock = [], []
        t0 = time.perf_counter()
        k = 0
        while (now := time.perf_counter()) - t0 < seconds:
            if int((now - t0) / 1.0) != k:  # walk the other way every second
                k += 1
                seq += 1
                x, y = targets[k % 2]
                await ws.send(json.dumps({"type": "target", "seq": seq, "x": x, "y": y}))
            msg = json.loads(await ws.recv())
            if msg["type"] == "state":
                arrivals.append(time.perf_counter())
                clock.append(msg["t"])
        plans1 = int(count_file.read_text()) if count_file.exists() else 0
    a = np.asarray(arrivals)
    gaps = np.diff(a) * 1000
    wall = a[-1] - a[0]
    return {"fps": (len(a) - 1) / wall, "p50": float(np.percentile(gaps, 50)),
            "p99": float(np.percentile(gaps, 99)), "max": float(gaps.max()),
            "drift": (clock[-1] - clock[0]) / wall, "plans": plans1 - plans0,
            "frames": len(a)}


def run_mode(mode: str, seconds: float) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        port_file, count_file = Path(tmp) / "port", Path(tmp) / "plans"
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT / "src"),
                                                          str(ROOT / "benchmarks"),
                                                          env.get("PYTHONPATH")]))
        child = subprocess.Popen(
            [sys.executable, __file__, "--serve", mode, str(port_file), str(count_file)],
            env=env)
        try:
            end = time.monotonic() + 180
            while not port_file.exists() or not port_file.read_text():
                if child.poll() is not None or time.monotonic() > end:
                    raise RuntimeError(f"the {mode} server did not start")
                time.sleep(0.1)
            load = load_average()
            res = asyncio.run(_measure(int(port_file.read_text()), seconds, count_file))
            res["load"] = float(load) if load != "n/a" else float("nan")
            return res
        finally:
            child.send_signal(signal.SIGINT)
            try:
                child.wait(60)
            except subprocess.TimeoutExpired:
                child.kill()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--update-docs", action="store_true")
    ap.add_argument("--serve", nargs=3, metavar=("MODE", "PORT_FILE", "COUNT_FILE"),
                    help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.serve:
        serve(*args.serve)
        return
    rows = {}
    for mode in MODES:
        r = run_mode(mode, args.seconds)
        rows[mode] = r
        print(f"{mode:8s} {r['fps']:6.1f} frames/s  gaps p50 {r['p50']:5.1f} ms  p99 "
              f"{r['p99']:5.1f} ms  max {r['max']:6.1f} ms  game/wall clock {r['drift']:.3f}  "
              f"plans {r['plans']}  load {r['load']:.2f}", flush=True)
    if args.update_docs:
        lines = [
            f"`benchmarks/bench_play.py --seconds {args.seconds:g}`: the `rapidds play` server "
            "(60 Hz tick, default search settings) in its own process, one WebSocket client in "
            "another, the avatar walking; the planner planning fetch cycles back to back "
            "meanwhile, in a thread of the server process or in a process of its own.",
            f"Machine: {cpu_model()}, 2 cores shared with other work; the 1-minute load "
            "average at the start of each condition is in the table.",
            "",
            "| planner | state messages/s | gap p50 (ms) | gap p99 (ms) | gap max (ms) | "
            "game clock / wall clock | plans finished | load |",
            "|---|---|---|---|---|---|---|---|",
        ]
        names = {"idle": "idle", "thread": "thread (what `rapidds play` does)",
                 "process": "separate process"}
        for mode, r in rows.items():
            lines.append(f"| {names[mode]} | {r['fps']:.1f} | {r['p50']:.1f} | {r['p99']:.1f} "
                         f"| {r['max']:.1f} | {r['drift']:.3f} | {r['plans']} | "
                         f"{r['load']:.2f} |")
        update_docs_section(SECTION, "\n".join(lines))


if __name__ == "__main__":
    main()
