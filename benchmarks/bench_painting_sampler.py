"""A cheaper policy in the painting loop (issue 36 item 3): a faster sampler or a smaller,
distilled network, its cycle CPU time against its plan quality.

    .venv/bin/python benchmarks/bench_painting_sampler.py run --seeds 0-3 --out A.jsonl
    .venv/bin/python benchmarks/bench_painting_sampler.py run --policy DIR --seeds 0-7 --out B.jsonl
    .venv/bin/python benchmarks/bench_painting_sampler.py report A.jsonl B.jsonl

``run``: for each seed, the paper's constrained and unconstrained gamma 12 settings (or those of
its four that ``--settings`` names) with
``left-slow`` (full adaptation, ``--cycles`` cycles, the default search) run once with the
policy as shipped (DDIM, 10 steps) and once with the cheaper arm, alternating, in this process
with one torch thread: ``--sampler`` at ``--steps`` reverse steps (``rapidds run --sampler dpm
--steps 5``; the default arm when neither ``--policy`` nor ``--sampler`` is given) and/or the
checkpoint ``--policy`` (``rapidds run --policy DIR``, e.g. a network distilled by
``rapidds train-policy --teacher``); one JSON line per run (appended to ``--out``, so seeds can
be split over several commands on a loaded machine). ``report``: process CPU seconds per
cycle, the realised cost (makespan + gamma x realised spatial cost) over the settled cycles
4.., paired by (setting, seed) with a 95 % bootstrap interval of the difference, and the
paper's behaviours (cycles shown / tested).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
from _common import cpu_model, load_average, parse_seeds
from bench_quality import paired_bootstrap

HUMAN = "left-slow"
SETTLED = 4
DEFAULT = "ddim 10 (default)"


def run(args: argparse.Namespace) -> None:
    import torch

    from rapidds.experiments.painting import SETTINGS, run_setting, setting_behaviours
    from rapidds.loop.run import load_policy
    from rapidds.worlds.painting import PaintingWorld

    torch.set_num_threads(1)
    world = PaintingWorld()
    policy = load_policy(world, device="cpu")
    sampler = args.sampler or (None if args.policy else "dpm")
    steps = args.steps or (None if sampler is None else 5)
    cheap = policy if args.policy is None else load_policy(world, args.policy, device="cpu")
    name = " ".join(([] if args.policy is None else [f"policy {args.policy.name}"])
                    + ([] if sampler is None else [f"{sampler} {steps}"]))
    arms = {DEFAULT: (policy, None), name: (cheap.with_sampler(sampler), steps)}
    if args.no_default:  # its records are the same by seed: pair with an earlier file's
        del arms[DEFAULT]
    for seed in parse_seeds(args.seeds):
        for setting in [s for s in SETTINGS if s.name in args.settings.split(",")]:
            for arm, (pol, steps) in arms.items():
                load = load_average()
                w0, c0 = time.perf_counter(), time.process_time()
                recs = run_setting(setting, HUMAN, seed, args.cycles, pol, steps=steps)
                cpu, wall = time.process_time() - c0, time.perf_counter() - w0
                settled = recs[min(SETTLED, len(recs) - 1):]
                shown = {f"{setting.name}: {b.belief}: {b.name}": [len(b.shown), len(b.cycles)]
                         for b in setting_behaviours(world, setting, HUMAN, recs)}
                row = {"arm": arm, "setting": setting.name, "seed": seed,
                       "cpu_per_cycle": cpu / len(recs), "wall_per_cycle": wall / len(recs),
                       "cost": statistics.mean(r.realised.cost for r in settled),
                       "behaviours": shown, "load": load}
                with Path(args.out).open("a") as f:
                    f.write(json.dumps(row) + "\n")
                print(arm, setting.name, seed, f"{row['cpu_per_cycle']:.2f} CPU s/cycle",
                      f"cost {row['cost']:.3f}", f"load {load}", flush=True)


def report(args: argparse.Namespace) -> None:
    rows = [json.loads(line) for f in args.files for line in Path(f).read_text().splitlines()
            if line.strip()]
    arms = [DEFAULT, *dict.fromkeys(r["arm"] for r in rows if r["arm"] != DEFAULT)]
    cost = {a: {(r["setting"], r["seed"]): r["cost"] for r in rows if r["arm"] == a}
            for a in arms}
    shown: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0])
    for r in rows:
        for name, (s, t) in r["behaviours"].items():
            shown[r["arm"], name][0] += s
            shown[r["arm"], name][1] += t
    loads = [float(r["load"]) for r in rows if r["load"] != "n/a"] or [float("nan")]
    seeds = sorted({r["seed"] for r in rows})
    settings = sorted({r["setting"] for r in rows})

    def med(arm: str, key: str) -> float:
        return statistics.median(r[key] for r in rows if r["arm"] == arm)

    pairs = []
    for fast in arms[1:]:
        keys = sorted(set(cost[DEFAULT]) & set(cost[fast]))
        diffs = np.array([cost[fast][k] - cost[DEFAULT][k] for k in keys])
        lo, hi = paired_bootstrap(diffs)
        pairs.append(f"- {fast} - default, paired by (setting, seed), {len(diffs)} pairs: "
                     f"{diffs.mean():+.3f} [95 % bootstrap {lo:+.3f}, {hi:+.3f}]\n")
        # by setting too: pooled, a setting where the arm is worse can hide behind one where
        # it is better (the distilled network's constrained gamma 12, docs/benchmarks.md)
        for setting in sorted({k[0] for k in keys}):
            part = np.array([cost[fast][k] - cost[DEFAULT][k] for k in keys if k[0] == setting])
            lo, hi = paired_bootstrap(part)
            pairs.append(f"  - {setting}, {len(part)} pairs: {part.mean():+.3f} "
                         f"[{lo:+.3f}, {hi:+.3f}]\n")
    text = (
        f"`benchmarks/bench_painting_sampler.py`: {', '.join(settings)}, {HUMAN}, 7 cycles, "
        f"seeds {seeds[0]}-{seeds[-1]}, default search, one torch thread, {cpu_model()}, 2 "
        f"cores shared with other sessions; 1-min load average {min(loads):.1f}-"
        f"{max(loads):.1f} at the runs' starts (CPU seconds are upper bounds at this load).\n\n"
        "| arm | runs | CPU s per cycle (median of runs) | wall s per cycle (median) | "
        "realised cost, cycles 4-6 (mean) |\n|---|---:|---:|---:|---:|\n"
        + "".join(f"| {a} | {len(cost[a])} | {med(a, 'cpu_per_cycle'):.2f} | "
                  f"{med(a, 'wall_per_cycle'):.2f} | {statistics.mean(cost[a].values()):.3f} |\n"
                  for a in arms)
        + "\nRealised cost against the default:\n\n" + "".join(pairs) + "\n"
        "| behaviour | " + " | ".join(f"{a}: cycles shown / tested" for a in arms)
        + " |\n|---|" + "---:|" * len(arms) + "\n"
        + "".join(f"| {b} | " + " | ".join(f"{shown[a, b][0]} / {shown[a, b][1]}" for a in arms)
                  + " |\n" for b in sorted({name for _, name in shown})))
    print(text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--seeds", default="0-7")
    r.add_argument("--sampler", choices=("ddim", "ddpm", "dpm"),
                   help="the cheaper arm's sampler (default: dpm without --policy)")
    r.add_argument("--steps", type=int, help="its reverse steps (default: 5 with --sampler)")
    r.add_argument("--policy", type=Path, help="the cheaper arm's checkpoint")
    r.add_argument("--cycles", type=int, default=7)
    r.add_argument("--settings", default="constrained-g12,unconstrained-g12",
                   help="which of the paper's four settings, comma-separated")
    r.add_argument("--out", required=True)
    r.add_argument("--no-default", action="store_true",
                   help="skip the default arm (its runs are the same by seed)")
    p = sub.add_parser("report")
    p.add_argument("files", nargs="+")
    args = ap.parse_args()
    (run if args.cmd == "run" else report)(args)


if __name__ == "__main__":
    main()
