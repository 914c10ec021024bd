"""The first painting cycle against the later ones (issue 36 item 5), before and after the cache.

    .venv/bin/python benchmarks/bench_first_cycle.py --base /tmp/old-checkout [--seeds 0,1]
        [--cycles 3]

Each run is ``rapidds run painting --human left-slow --gamma 12`` (full adaptation, default
search, one torch thread) in a fresh process: process CPU and wall seconds of the run's
construction (the population prior, the world's problem), of cycle 0 (whose record builds the
simulated person's true spatial model for the plan cost) and the median of the later cycles.
Four kinds of run per seed, in this order: the base checkout (``--base DIR``, its ``src``)
with an empty cache (``RAPIDDS_CACHE`` a fresh folder: what the first run on a machine pays),
then with that cache filled (every later run), then this tree the same way with a folder of its
own. The records' digests (timings aside) must agree across the four. "ready" is the process's
CPU from its start to the end of the run's construction: imports, the policy, the world.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from _common import cpu_model, load_average, parse_seeds

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

CHILD = r"""
import hashlib, json, sys, time
import torch
torch.set_num_threads(1)
from bench_painting_cycle import _strip_timing
from rapidds.loop.config import RunConfig
from rapidds.loop.run import AdaptiveRun, load_policy
from rapidds.worlds.painting import PaintingWorld

seed, cycles = int(sys.argv[1]), int(sys.argv[2])
policy = load_policy(PaintingWorld(), device="cpu")
cfg = RunConfig(world="painting", human="left-slow", gamma=12.0, cycles=cycles, seed=seed)
c0, w0 = time.process_time(), time.perf_counter()
run = AdaptiveRun(cfg, policy)
out = {"construct_cpu": time.process_time() - c0, "construct_wall": time.perf_counter() - w0,
       "ready_cpu": time.process_time(), "cpu": [], "wall": []}
digest = hashlib.sha256()
while not run.finished:
    c0, w0 = time.process_time(), time.perf_counter()
    rec = run.step().record.to_json()
    out["cpu"].append(time.process_time() - c0)
    out["wall"].append(time.perf_counter() - w0)
    digest.update(json.dumps(_strip_timing(rec), sort_keys=True, default=str).encode())
out["digest"] = digest.hexdigest()[:16]
print(json.dumps(out))
"""


def _child(src: Path, seed: int, cycles: int, cache: str) -> dict[str, object]:
    env = {**os.environ, "PYTHONPATH": f"{src}{os.pathsep}{HERE}", "RAPIDDS_CACHE": cache}
    proc = subprocess.run([sys.executable, "-c", CHILD, str(seed), str(cycles)], env=env,
                          capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--cycles", type=int, default=3)
    args = ap.parse_args()
    load0 = load_average()
    trees = (("base", args.base.resolve() / "src"), ("this tree", ROOT / "src"))
    got: dict[str, list[dict]] = {f"{t}, {c}": [] for t, _ in trees
                                  for c in ("empty cache", "cache filled")}
    for seed in parse_seeds(args.seeds):
        for tree, src in trees:
            with tempfile.TemporaryDirectory() as cache:
                for kind in ("empty cache", "cache filled"):
                    name = f"{tree}, {kind}"
                    res = _child(src, seed, args.cycles, cache)
                    got[name].append(res)
                    print(f"seed {seed} {name}: ready {res['ready_cpu']:.2f}, construct "
                          f"{res['construct_cpu']:.2f}, cycle 0 {res['cpu'][0]:.2f}, later "
                          f"{statistics.median(res['cpu'][1:]):.2f} CPU s; digest "
                          f"{res['digest']}, load {load_average()}", flush=True)
    digests = {r["digest"] for runs in got.values() for r in runs}
    same = len(digests) == len(parse_seeds(args.seeds))
    rows = []
    for name, runs in got.items():
        def med(key: str, runs: list[dict] = runs) -> float:
            return statistics.median(float(r[key]) for r in runs)

        first = statistics.median(r["cpu"][0] for r in runs)
        later = statistics.median(c for r in runs for c in r["cpu"][1:])
        rows.append(f"| {name} | {med('ready_cpu'):.2f} | {med('construct_cpu'):.2f} | "
                    f"{first:.2f} | {later:.2f} | "
                    f"{first / later:.2f} | "
                    f"{statistics.median(r['wall'][0] for r in runs):.2f} / "
                    f"{statistics.median(w for r in runs for w in r['wall'][1:]):.2f} |")
    text = (
        f"`benchmarks/bench_first_cycle.py --base {args.base} --seeds {args.seeds} --cycles "
        f"{args.cycles}`: `rapidds run painting --human left-slow --gamma 12`, each run in a "
        f"fresh process, one torch thread, {cpu_model()}, 2 cores shared with other sessions; "
        f"1-min load average {load0} at start, {load_average()} at end. Records (timings "
        f"aside) {'identical' if same else 'DIFFERENT'} across the four kinds of run.\n\n"
        "| run | ready CPU s | construction CPU s | cycle 0 CPU s | later cycles CPU s "
        "(median) | cycle 0 / later | wall s cycle 0 / later |\n"
        "|---|---:|---:|---:|---:|---:|---|\n"
        + "\n".join(rows) + "\n")
    print(text)


if __name__ == "__main__":
    main()
