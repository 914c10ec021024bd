"""Fetch loop benchmark: time per cycle, and full adaptation against none for every archetype.

For each archetype and seed, run 16 cycles with ``full`` and with ``none`` (same seed, so the
same teammate draws) and compare the median realised cost over the last 4 cycles.

    .venv/bin/python benchmarks/bench_loop.py --seeds 3 [--update-docs]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from _common import cpu_model, load_average, update_docs_section

from rapidds.loop import AdaptiveRun, RunConfig, load_policy
from rapidds.worlds.fetch import ARCHETYPES
from rapidds.worlds.registry import make_world

SECTION = "## Adaptive loop (fetch)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--cycles", type=int, default=16)
    ap.add_argument("--update-docs", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    policy = load_policy(make_world("fetch"), device="cpu")
    rows, times = [], []
    wins = 0
    t_all, load0 = time.perf_counter(), load_average()
    for human in ARCHETYPES:
        tails: dict[str, list[float]] = {"full": [], "none": []}
        for seed in range(args.seeds):
            for adapt in ("full", "none"):
                cfg = RunConfig(human=human, adapt=adapt, cycles=args.cycles, seed=seed)
                recs = AdaptiveRun(cfg, policy).run()
                times += [(r.seconds or {}).get("total", 0.0) for r in recs]
                tails[adapt].append(float(np.median([r.realised.cost for r in recs[-4:]])))
        full, none = float(np.median(tails["full"])), float(np.median(tails["none"]))
        per_seed = sum(f < n for f, n in zip(tails["full"], tails["none"], strict=True))
        wins += full < none
        rows.append(f"| {human} | {full:.2f} | {none:.2f} | {100 * (full - none) / none:+.1f}% "
                    f"| {per_seed}/{args.seeds} |")
    wall = time.perf_counter() - t_all
    t = np.array(times)
    lines = [
        SECTION,
        "",
        f"`benchmarks/bench_loop.py --seeds {args.seeds}`: {args.cycles} cycles per run, default "
        "`RunConfig` (GA population 24, patience 8, K = 32, 4 particles x 8 SVDD candidates per "
        "motion request), bundled policy, one torch thread.",
        f"Machine: {torch.get_num_threads()} torch thread on {cpu_model()} (2 cores); 1-min load "
        f"average {load0} at start, {load_average()} at end (the cores are shared, so seconds "
        "are upper bounds).",
        "",
        f"Time per cycle (plan + deploy + model update), {t.size} cycles: median "
        f"{np.median(t):.2f} s, p90 {np.percentile(t, 90):.2f} s, max {t.max():.2f} s. "
        f"Total {wall / 60:.1f} min.",
        "",
        "Median realised cost over the last 4 of 16 cycles (median over seeds):",
        "",
        "| teammate | full | none | full vs none | seeds where full < none |",
        "|---|---|---|---|---|",
        *rows,
        "",
        f"full below none for {wins} of {len(ARCHETYPES)} archetypes.",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    if args.update_docs:
        update_docs_section(SECTION, text.split("\n", 1)[1])


if __name__ == "__main__":
    main()
