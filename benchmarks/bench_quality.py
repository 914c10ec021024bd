"""Plan quality and speed of the fetch loop, old code against this tree, side by side.

A fixed small study (every archetype x ``--seeds`` trials x 16 cycles, full adaptation, the
ablation study's search settings) runs once with each tree, in fresh processes one after the
other on the same machine. Per trial the score is the mean realised cost of the settled cycles
12-15; trials pair up by (archetype, seed), and the difference new - old gets a 95 % paired
bootstrap interval. Also per tree: seconds per cycle (median, p90) and the process's peak
resident memory.

    .venv/bin/python benchmarks/bench_quality.py --before REV [--seeds 8] [--update-docs]

REV is any commit of this repository (default: efc830e, main before the scheduler speed-ups); it is
checked out into a temporary worktree and imported from there.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from _common import cpu_model, load_average, update_docs_section

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## Plan quality, old and new loop"
HUMANS = ("fast-outside", "slow-middle", "fast-middle", "slow-outside")
SETTLED = slice(12, 16)

TRIALS = r"""
import json, resource, sys, time
import torch
torch.set_num_threads(1)
from rapidds.loop import AdaptiveRun, RunConfig
try:  # this tree: worlds by name
    from rapidds.loop import load_policy
    from rapidds.worlds import make_world
    policy = load_policy(make_world("fetch"))
except ImportError:  # before the redesign
    from rapidds.cli.run import load_policy
    policy = load_policy(None)
humans, seeds = json.loads(sys.argv[1]), int(sys.argv[2])
out = []
for seed in range(seeds):
    for human in humans:
        cfg = RunConfig(human=human, adapt="full", cycles=16, seed=seed, population=24,
                        generations=40, samples=32, patience=8, particles=2, candidates=4)
        recs = AdaptiveRun(cfg, policy).run()
        out.append({"human": human, "seed": seed,
                    "cost": [r.realised.cost for r in recs],
                    "seconds": [(r.seconds or {}).get("total", 0.0) for r in recs]})
print(json.dumps({"trials": out,
                  "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run_tree(src: Path, seeds: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src)}
    res = subprocess.run([sys.executable, "-c", TRIALS, json.dumps(HUMANS), str(seeds)],
                         capture_output=True, text=True, env=env, check=True)
    return json.loads(res.stdout.splitlines()[-1])


def paired_bootstrap(diff: np.ndarray, resamples: int = 4000, seed: int = 0) -> tuple[float,
                                                                                      float]:
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(diff), (resamples, len(diff)))
    means = diff[idx].mean(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--before", default="efc830e")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--update-docs", action="store_true")
    args = ap.parse_args()
    load0 = load_average()
    with tempfile.TemporaryDirectory() as tmp:
        old_tree = Path(tmp) / "old"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(old_tree),
                        args.before], check=True, capture_output=True)
        try:
            results = {"old": run_tree(old_tree / "src", args.seeds)}
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                            str(old_tree)], check=False, capture_output=True)
    results["new"] = run_tree(ROOT / "src", args.seeds)
    load1 = load_average()

    def scores(which: str) -> dict[tuple[str, int], float]:
        return {(t["human"], t["seed"]): float(np.mean(t["cost"][SETTLED]))
                for t in results[which]["trials"]}

    old, new = scores("old"), scores("new")
    rows = ["| archetype | trials | old: mean settled cost | new | new - old [95 % CI] |",
            "|---|---:|---:|---:|---|"]
    all_diff = []
    for h in HUMANS:
        keys = sorted(k for k in old if k[0] == h)
        d = np.array([new[k] - old[k] for k in keys])
        all_diff.append(d)
        lo, hi = paired_bootstrap(d)
        rows.append(f"| {h} | {len(keys)} | {np.mean([old[k] for k in keys]):.3f} | "
                    f"{np.mean([new[k] for k in keys]):.3f} | {d.mean():+.3f} "
                    f"[{lo:+.3f}, {hi:+.3f}] |")
    d = np.concatenate(all_diff)
    lo, hi = paired_bootstrap(d)
    rows.append(f"| **all** | {len(d)} | {np.mean(list(old.values())):.3f} | "
                f"{np.mean(list(new.values())):.3f} | {d.mean():+.3f} [{lo:+.3f}, {hi:+.3f}] |")
    speed = ["| code | s per cycle, median | p90 | peak resident memory |", "|---|---:|---:|---:|"]
    for which, label in (("old", f"old (`{args.before}`)"), ("new", "new (this tree)")):
        secs = np.concatenate([t["seconds"] for t in results[which]["trials"]])
        speed.append(f"| {label} | {np.median(secs):.3f} | {np.percentile(secs, 90):.3f} | "
                     f"{results[which]['max_rss_mb']:.0f} MB |")
    verdict = ("no worse: the interval includes 0 or lies below it" if lo <= 0 else
               "WORSE: the whole interval lies above 0")
    body = (
        f"`benchmarks/bench_quality.py --before {args.before} --seeds {args.seeds}`: every "
        f"archetype x {args.seeds} seeds x 16 cycles, full adaptation, the ablation study's "
        "search settings (population 24, generations 40, K = 32, 2 particles x 4 candidates), "
        "old code then this tree in fresh processes, one torch thread. Score: a trial's mean "
        "realised cost over cycles 12-15; new - old paired by (archetype, seed), 95 % paired "
        f"bootstrap interval. Machine: {cpu_model()}, 2 cores; 1-min load average {load0} at "
        f"start, {load1} at end.\n\n" + "\n".join(rows) + f"\n\nPlan quality: {verdict}.\n\n"
        + "\n".join(speed) + "\n"
    )
    print(body)
    if args.update_docs:
        update_docs_section(SECTION, body)


if __name__ == "__main__":
    main()
