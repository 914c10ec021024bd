"""Fewer reverse diffusion steps in the painting loop: cycle time against plan quality.

    .venv/bin/python benchmarks/bench_painting_steps.py [--seeds 0-3] [--steps 6] [--docs]

``RunConfig.steps`` (``rapidds run --steps``) sets the reverse steps of every steered motion;
the default (None) keeps the policy's 10. For each seed, the paper's unconstrained and
constrained gamma 12 settings with ``left-slow`` (full adaptation, 7 cycles) run once with the
default and once with ``--steps``, interleaved (default, fewer, default, ...), in this process
with one torch thread. Reported: process CPU seconds per cycle; the realised cost
(makespan + gamma x realised spatial cost) over the settled cycles 4-6, paired by (setting,
seed) with a 95 % bootstrap interval of the difference; and the paper's behaviours (share of
the cycles each was tested on that showed it). The default keeps today's records; this measures
whether the faster setting keeps the quality the issue asks for before anyone relies on it.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import defaultdict

import numpy as np
import torch
from _common import cpu_model, load_average, parse_seeds, update_docs_section
from bench_quality import paired_bootstrap

from rapidds.experiments.painting import SETTINGS, run_setting, setting_behaviours
from rapidds.loop.run import load_policy
from rapidds.worlds.painting import PaintingWorld

SETTLED = slice(4, None)
HUMAN = "left-slow"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-3")
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--docs", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    load0 = load_average()
    world = PaintingWorld()
    policy = load_policy(world, device="cpu")
    arms = {"default (10)": None, f"steps {args.steps}": args.steps}
    cpu: dict[str, list[float]] = defaultdict(list)
    cost: dict[str, dict[tuple[str, int], float]] = defaultdict(dict)
    shown: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0])
    for seed in parse_seeds(args.seeds):
        for setting in SETTINGS[:2]:
            for arm, steps in arms.items():
                t0 = time.process_time()
                recs = run_setting(setting, HUMAN, seed, 7, policy, steps=steps)
                cpu[arm].append((time.process_time() - t0) / len(recs))
                cost[arm][setting.name, seed] = statistics.mean(
                    r["realised"]["cost"] for r in recs[SETTLED])
                for b in setting_behaviours(world, setting, HUMAN, recs):
                    row = shown[arm, f"{setting.name}: {b.belief}: {b.name}"]
                    row[0] += len(b.shown)
                    row[1] += len(b.cycles)
                print(arm, setting.name, seed, f"{cpu[arm][-1]:.2f} s/cycle",
                      f"cost {cost[arm][setting.name, seed]:.3f}", flush=True)
    base, fast = arms
    keys = sorted(cost[base])
    diffs = [cost[fast][k] - cost[base][k] for k in keys]
    lo, hi = paired_bootstrap(np.asarray(diffs))
    behaviours = sorted({name for _, name in shown})
    text = (
        f"`benchmarks/bench_painting_steps.py --seeds {args.seeds} --steps {args.steps}`: "
        f"unconstrained and constrained gamma 12, {HUMAN}, 7 cycles, seeds {args.seeds}, "
        f"default search, one torch thread, {cpu_model()}, 2 cores shared with other jobs; "
        f"1-min load average {load0} at start, {load_average()} at end (CPU seconds, less "
        "sensitive to load than wall seconds, are still upper bounds).\n\n"
        "| steps | CPU s per cycle (median of runs) | realised cost, cycles 4-6 (mean) |\n"
        "|---|---:|---:|\n"
        + "".join(f"| {arm} | {statistics.median(cpu[arm]):.2f} | "
                  f"{statistics.mean(cost[arm].values()):.3f} |\n" for arm in arms)
        + f"\nRealised cost, {fast} - default, paired by (setting, seed), {len(diffs)} pairs: "
        f"{statistics.mean(diffs):+.3f} [95 % bootstrap {lo:+.3f}, {hi:+.3f}].\n\n"
        "| behaviour | " + " | ".join(f"{arm}: cycles shown / tested" for arm in arms)
        + " |\n|---|" + "---:|" * len(arms) + "\n"
        + "".join(f"| {b} | " + " | ".join(f"{shown[arm, b][0]} / {shown[arm, b][1]}"
                                            for arm in arms) + " |\n" for b in behaviours))
    print(text)
    if args.docs:
        update_docs_section("## Painting cycle with fewer reverse steps", text)


if __name__ == "__main__":
    main()
