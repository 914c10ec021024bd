"""Seconds per cycle of the painting loop (plan + execute + learn + record), wall clock and
process CPU time, one torch thread.

    .venv/bin/python benchmarks/bench_painting_cycle.py [--seeds 0,1] [--cycles 7] [--docs]
    .venv/bin/python benchmarks/bench_painting_cycle.py --base /tmp/old-checkout [--rounds 2]

Runs ``rapidds run painting --human left-slow --gamma 12 --cycles 7`` (full adaptation, the
default search) in memory for each seed. The loop is single-threaded, so on a shared machine
its CPU time is what the wall time would be on an idle core; both are reported, with the load.

``--base DIR`` measures the checkout at DIR (its ``src``) beside this one: every (round, seed)
runs in a fresh process of each tree, the two alternating, and the runs' records (timings
aside) are compared by digest, so a speed-up that changed a plan shows.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _common import cpu_model, load_average, middle_start, parse_seeds, sync, update_docs_section

ROOT = Path(__file__).resolve().parents[1]


def _strip_timing(obj: object) -> object:
    if isinstance(obj, dict):
        return {k: _strip_timing(v) for k, v in obj.items() if k != "seconds"}
    if isinstance(obj, list):
        return [_strip_timing(v) for v in obj]
    return obj


# the world's teammate and gamma of the measured run: the painting config, and a
# fetch run for "the fetch cycle no slower"
WORLDS = {"painting": ("left-slow", 12.0), "fetch": ("slow-middle", None)}


def run_seed(seed: int, cycles: int, device: str = "cpu", world: str = "painting",
             policy: str | None = None, threads: int = 1, warm_up: bool = False,
             cuda_graphs: bool | None = None) -> dict[str, object]:
    """One run in this process on ``device`` (the CPU unless told: this benchmark is the CPU's
    even on a machine with a GPU; bench_device.py measures both): per-cycle wall and CPU
    seconds, the wall parts, the records' digest. ``world``: painting (the issue's config)
    or fetch (its default search, teammate slow-middle). ``policy``: a checkpoint or the name
    of one the world ships (``rapidds run --policy``); ``threads``: torch's intra-op threads
    (``rapidds run --threads``); ``warm_up``: one small batch through the network on its
    device before the run (how much of a first cycle on a GPU is loading its kernels);
    ``cuda_graphs``: whether the network's passes and the steering value's calls replay CUDA
    graphs on a GPU (``DiffusionPolicy.cuda_graphs``, None: the policy's default, on since
    2026-11-28; on a GPU the network's shapes captured and any failure come back as
    ``graphs``)."""
    import torch

    from rapidds.loop.config import RunConfig
    from rapidds.loop.run import AdaptiveRun, CycleResult, load_policy
    from rapidds.worlds.registry import make_world

    torch.set_num_threads(threads)
    w = make_world(world)
    try:  # the device always named: load_policy's default ("auto") is the GPU where one is
        net = load_policy(w, policy, device=device)
    except TypeError:  # a checkout from before load_policy took a device: the CPU's
        if device != "cpu" or policy is not None:
            raise
        net = load_policy(w)
    if cuda_graphs is not None:
        net.cuda_graphs = cuda_graphs
    if warm_up:
        net.sample(net.config.task_names[0], 8, start=middle_start(net), generator=0)
        sync(net.device)
    human, gamma = WORLDS[world]
    cfg = RunConfig(world=world, human=human, gamma=gamma, cycles=cycles, seed=seed)
    w0 = time.perf_counter()
    run = AdaptiveRun(cfg, net)  # on a GPU the run warms its kernels up here
    out: dict[str, list] = {"wall": [], "cpu": [], "plan": [], "deploy": [], "update": [],
                            "requests": [], "realised": [],
                            "construct": [time.perf_counter() - w0]}
    digest = hashlib.sha256()
    while not run.finished:
        w0, c0 = time.perf_counter(), time.process_time()
        res: CycleResult = run.step()
        out["wall"].append(time.perf_counter() - w0)
        out["cpu"].append(time.process_time() - c0)
        # the stored form: a typed record here, a dict in checkouts from before it was typed
        rec = res.record.to_json() if hasattr(res.record, "to_json") else res.record
        for k in ("plan", "deploy", "update"):
            out[k].append(rec["seconds"][k])
        # the steering requests the search made (a cycle's cost is mostly theirs, and runs
        # that differ in float rounding make different ones)
        out["requests"].append(rec.get("search", {}).get("motion_requests"))
        out["realised"].append(res.record.realised.cost)  # the plan quality a tree's change moves
        digest.update(json.dumps(_strip_timing(rec), sort_keys=True,
                                 default=str).encode())
    replayed = getattr(net, "_replayed", None)
    if getattr(net, "cuda_graphs", False) and net.device.type == "cuda":
        # the network's captured shapes, and why a capture failed if one did
        out["graphs"] = [0 if replayed is None else len(replayed.graphs),
                         getattr(net, "graph_notes", {})]
    return {**out, "digest": digest.hexdigest()[:16]}


def _child(src: Path, seed: int, cycles: int, world: str = "painting") -> dict[str, object]:
    env = {**os.environ, "PYTHONPATH": f"{src}{os.pathsep}{Path(__file__).parent}"}
    code = ("import json, bench_painting_cycle as b; "
            f"print(json.dumps(b.run_seed({seed}, {cycles}, world={world!r})))")
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def compare(base: Path, seeds: list[int], cycles: int, rounds: int,
            world: str = "painting") -> str:
    """Base and this tree alternating run by run; CPU and wall medians over all cycles."""
    load0 = load_average()
    trees = {"base": base.resolve() / "src", "this tree": ROOT / "src"}
    got: dict[str, list[dict]] = {name: [] for name in trees}
    for r in range(rounds):
        for seed in seeds:
            for name, src in (trees.items() if r % 2 == 0 else reversed(trees.items())):
                res = _child(src, seed, cycles, world)
                got[name].append({**res, "seed": seed})
                print(f"round {r} seed {seed} {name}: CPU median "
                      f"{statistics.median(res['cpu']):.3f} s, digest {res['digest']}, "
                      f"load {load_average()}", flush=True)
    same = all(a["digest"] == b["digest"] for a, b in zip(got["base"], got["this tree"],
                                                          strict=True))
    rows = []
    for name, runs in got.items():
        cpu = [c for run in runs for c in run["cpu"]]
        wall = [c for run in runs for c in run["wall"]]
        parts = {k: statistics.median(c for run in runs for c in run[k])
                 for k in ("plan", "deploy", "update")}
        rows.append(f"| {name} | {statistics.median(cpu):.2f} | {max(cpu):.2f} | "
                    f"{statistics.median(wall):.2f} | {parts['plan']:.2f} / "
                    f"{parts['deploy']:.2f} / {parts['update']:.2f} |")
    human, gamma = WORLDS[world]
    run = f"rapidds run {world} --human {human}" + ("" if gamma is None else f" --gamma {gamma:g}")
    return (
        f"`benchmarks/bench_painting_cycle.py --base {base} --seeds "
        f"{','.join(map(str, seeds))} --cycles {cycles} --rounds {rounds} --world {world}`: "
        f"{len(seeds) * rounds} runs per tree of `{run} --cycles {cycles}`, each in a fresh "
        "process, base and this tree "
        f"alternating run by run; {cpu_model()}, one torch thread, 2 cores shared with other "
        f"jobs; 1-min load average {load0} at start, {load_average()} at end. Records "
        f"(timings aside) {'identical' if same else 'DIFFERENT'} run by run.\n\n"
        "| tree | CPU s per cycle (median) | CPU s (max) | wall s (median) | "
        "wall plan / execute / learn (median) |\n|---|---:|---:|---:|---|\n"
        + "\n".join(rows) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--cycles", type=int, default=7)
    ap.add_argument("--docs", action="store_true")
    ap.add_argument("--base", type=Path, help="an older checkout to measure beside this one")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--policy", help="without --base: a checkpoint, or the name of one the "
                    "world ships (distilled)")
    ap.add_argument("--threads", type=int, default=1, help="without --base: torch threads")
    ap.add_argument("--world", choices=sorted(WORLDS), default="painting",
                    help="with --base: the run measured (default: the issue's painting run)")
    args = ap.parse_args()
    if args.base is not None:
        print(compare(args.base, parse_seeds(args.seeds), args.cycles, args.rounds,
                      args.world))
        return
    load0 = load_average()
    runs = [run_seed(seed, args.cycles, policy=args.policy, threads=args.threads)
            for seed in parse_seeds(args.seeds)]
    extra = (f" --policy {args.policy}" if args.policy else "") + (
        f" --threads {args.threads}" if args.threads != 1 else "")
    wall = [c for r in runs for c in r["wall"]]
    cpu = [c for r in runs for c in r["cpu"]]
    med = {k: statistics.median(c for r in runs for c in r[k])
           for k in ("plan", "deploy", "update")}
    text = (
        f"`benchmarks/bench_painting_cycle.py --seeds {args.seeds}{extra}`: {len(wall)} "
        f"cycles of `rapidds run painting --human left-slow --gamma 12 --cycles {args.cycles}"
        f"{extra}` (full adaptation, default search: population 24, 40 generations, 32 "
        f"samples, 4 particles x 8 candidates), {args.threads} torch thread(s), {cpu_model()}, "
        "2 cores shared with other jobs; "
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
