"""Plan quality of the device path (tensor value terms, a cycle's moved requests steered in its
first batch) against the CPU's host path, both run on the CPU.

    .venv/bin/python benchmarks/bench_batched_quality.py [--seeds 0-7] [--json OUT]
    .venv/bin/python benchmarks/bench_batched_quality.py --execution reactive   # monitored

On a GPU steering scores candidates with the world's tensor terms and pre-steers the moved
carried requests (:class:`rapidds.loop.carry.CarriedMotions`), which changes floating-point
order (the graded penalty, by about 1e-14 s) and the batches' random streams, so its records
differ from the CPU's. ``DiffusionMotion.default_on_device = True`` runs that path on the CPU,
where it can be compared with the stored one seed by seed: the painting benchmark's run
(unconstrained, gamma 12, left-slow, 7 cycles, settled cycles 4-6) and a fetch run (slow-middle,
8 cycles, settled cycles 4-7), the two paths alternating, one torch thread. Reported: the mean
realised cost of the settled cycles per run, the difference device - host paired by (world,
seed) with a 95 % bootstrap interval, and the painting behaviours shown (docs/reproduction.md).
``--execution reactive``: the runs under the safety monitor, planning for its holds (the
default there), whose hold term the device path scores as tensor operations too.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch
from _common import cpu_model, load_average, parse_seeds
from bench_quality import paired_bootstrap

from rapidds.experiments.painting import SETTINGS, run_setting, setting_behaviours
from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.loop.run import load_policy
from rapidds.motion.diffusion_motion import DiffusionMotion
from rapidds.worlds.registry import make_world

ARMS = {"host": None, "device path": True}


def _painting(seed: int, policy, shown: dict, execution: str) -> float:
    setting = SETTINGS[0]
    recs = run_setting(setting, "left-slow", seed, 7, policy, execution=execution)
    for b in setting_behaviours(make_world("painting"), setting, "left-slow", recs):
        row = shown[f"{b.belief}: {b.name}"]
        row[0] += len(b.shown)
        row[1] += len(b.cycles)
    return statistics.mean(r.realised.cost for r in recs[4:])


def _fetch(seed: int, policy, execution: str) -> float:
    recs = AdaptiveRun(RunConfig(world="fetch", human="slow-middle", cycles=8, seed=seed,
                                 execution=execution), policy).run()
    return statistics.mean(r.realised.cost for r in recs[4:])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-7")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--worlds", default="fetch,painting")
    ap.add_argument("--execution", default="planned", choices=("planned", "reactive"))
    args = ap.parse_args()
    worlds = args.worlds.split(",")
    torch.set_num_threads(1)
    load0 = load_average()
    policies = {w: load_policy(make_world(w), device="cpu") for w in worlds}
    cost: dict[str, dict[str, float]] = defaultdict(dict)
    cpu: dict[str, list[float]] = defaultdict(list)
    shown: dict[str, dict[str, list[int]]] = {a: defaultdict(lambda: [0, 0]) for a in ARMS}
    for seed in parse_seeds(args.seeds):
        for world in worlds:
            for arm, flag in (ARMS.items() if seed % 2 == 0 else reversed(ARMS.items())):
                DiffusionMotion.default_on_device = flag
                c0 = time.process_time()
                got = (_fetch(seed, policies[world], args.execution) if world == "fetch"
                       else _painting(seed, policies[world], shown[arm], args.execution))
                cpu[f"{world} {arm}"].append(time.process_time() - c0)
                cost[arm][f"{world} {seed}"] = got
                print(f"{world} seed {seed} {arm}: settled cost {got:.3f}, CPU "
                      f"{cpu[f'{world} {arm}'][-1]:.1f} s, load {load_average()}", flush=True)
    DiffusionMotion.default_on_device = None
    lines = [f"{args.execution} execution; {cpu_model()}, one torch thread; 1-min load "
             f"average {load0} at start, {load_average()} at end"]
    for world in worlds:
        keys = sorted(k for k in cost["host"] if k.startswith(world))
        diffs = np.array([cost["device path"][k] - cost["host"][k] for k in keys])
        lo, hi = paired_bootstrap(diffs)
        host = np.mean([cost["host"][k] for k in keys])
        dev = np.mean([cost["device path"][k] for k in keys])
        lines.append(f"{world}: {len(keys)} pairs, host {host:.3f}, device path {dev:.3f}, "
                     f"difference {diffs.mean():+.3f} [95 % bootstrap {lo:+.3f}, {hi:+.3f}]")
    for b in sorted(shown["host"]):
        lines.append(f"{b}: host {shown['host'][b][0]} / {shown['host'][b][1]}, device path "
                     f"{shown['device path'][b][0]} / {shown['device path'][b][1]}")
    print("\n".join(lines))
    if args.json is not None:
        args.json.write_text(json.dumps({"cost": cost, "cpu": cpu, "shown": shown}, indent=2))


if __name__ == "__main__":
    main()
