"""Seconds per cycle of the painting loop (plan + execute + learn + record), wall clock and
process CPU time, one torch thread.

    .venv/bin/python benchmarks/bench_painting_cycle.py [--seeds 0,1] [--cycles 7] [--docs]

Runs ``rapidds run painting --human left-slow --gamma 12 --cycles 7`` (full adaptation, the
default search) in memory for each seed. The loop is single-threaded, so on a shared machine
its CPU time is what the wall time would be on an idle core; both are reported, with the load.
The target is a median of at most 2 s on 2 cores.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from _common import cpu_model, load_average, update_docs_section

from rapidds.loop.config import RunConfig
from rapidds.loop.run import AdaptiveRun, CycleResult, load_policy
from rapidds.worlds.painting import PaintingWorld


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--cycles", type=int, default=7)
    ap.add_argument("--docs", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    load0 = load_average()
    policy = load_policy(PaintingWorld())
    wall, cpu, parts = [], [], {"plan": [], "deploy": [], "update": []}
    for seed in (int(s) for s in args.seeds.split(",")):
        cfg = RunConfig(world="painting", human="left-slow", gamma=12.0, cycles=args.cycles,
                        seed=seed)
        run = AdaptiveRun(cfg, policy)
        while not run.finished:
            w0, c0 = time.perf_counter(), time.process_time()
            res: CycleResult = run.step()
            wall.append(time.perf_counter() - w0)
            cpu.append(time.process_time() - c0)
            for k in parts:
                parts[k].append(res.record["seconds"][k])
    med = {k: statistics.median(v) for k, v in parts.items()}
    text = (
        f"`benchmarks/bench_painting_cycle.py --seeds {args.seeds}`: {len(wall)} cycles of "
        f"`rapidds run painting --human left-slow --gamma 12 --cycles {args.cycles}` (full "
        "adaptation, default search: population 24, 40 generations, 32 samples, 4 particles x "
        f"8 candidates), one torch thread, {cpu_model()}, 2 cores shared with other jobs; "
        f"1-min load average {load0} at start, {load_average()} at end.\n\n"
        "| per cycle | median | max |\n|---|---|---|\n"
        f"| wall clock (s) | {statistics.median(wall):.2f} | {max(wall):.2f} |\n"
        f"| process CPU time (s) | {statistics.median(cpu):.2f} | {max(cpu):.2f} |\n\n"
        f"Median wall parts: plan {med['plan']:.2f} s, execute {med['deploy']:.2f} s, learn "
        f"{med['update']:.2f} s. The loop runs on one thread, so its CPU time is what a cycle "
        "takes on a core of its own; the wall clock counts the other jobs' share of the cores.")
    print(text)
    if args.docs:
        update_docs_section("## Painting cycle", text)


if __name__ == "__main__":
    main()
