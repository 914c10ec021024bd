"""The paper's painting behaviours in whole runs of the loop, over seeds, and the loop's cycle
time (plan + execute + learn, from each record's ``seconds``).

    .venv/bin/python benchmarks/bench_painting_loop.py --seeds 0-7 --runs runs.jsonl [--docs]
    .venv/bin/python benchmarks/bench_painting_loop.py --policy distilled --runs d.jsonl
    .venv/bin/python benchmarks/bench_painting_loop.py --compare runs.jsonl d.jsonl

Per seed: the case study's four settings with ``left-slow`` (full adaptation, 7 cycles, the
world's lambda), unconstrained gamma 12 with ``left-fast`` (Brush to the faster agent) and with
``right-slow`` (the mirror image: Mix R is then the near mix). Every finished run is appended
to ``--runs`` (JSON lines), and runs already there are not run again, so the script resumes.
The behaviours are :func:`rapidds.experiments.painting.setting_behaviours`. ``--policy``: a
checkpoint directory or the name of one the world ships (``rapidds run --policy``); a runs
file holds one network's runs (each line names its network's fingerprint, and a file of
another network is refused). ``--no-reuse``: every motion steered anew each cycle
(``RunConfig(reuse_motions=False)``), so that one unlucky draw of a motion whose value never
changes (a task with no concurrent human task) is not carried for the whole run: the fairer
setting for comparing networks (docs/benchmarks.md, "Painting loop"). ``--compare BASE OTHER``
runs nothing and pairs two runs files' settled costs by setting.
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
from _common import cpu_model, load_average, parse_seeds, update_docs_section

from rapidds.experiments.painting import SETTINGS, Setting, run_setting, setting_behaviours
from rapidds.loop.run import load_policy
from rapidds.record import CycleRecord
from rapidds.worlds.painting import PaintingWorld

RUNS: tuple[tuple[Setting, str], ...] = (
    *((s, "left-slow") for s in SETTINGS),
    (SETTINGS[0], "left-fast"),
    (SETTINGS[0], "right-slow"),
)


def _seconds(record: CycleRecord) -> float:
    assert record.seconds is not None  # kept by every run since the loop's timing
    return record.seconds["total"]


def _read(path: Path) -> list[dict]:
    """A runs file's lines, each run's records typed."""
    out = []
    for line in path.read_text().splitlines():
        d = json.loads(line)
        out.append({**d, "records": [CycleRecord.from_json(r) for r in d["records"]]})
    return out


# a robot Brush slower than this is the avoidant path (about 6.2 s against 4.5 s direct)
SLOW_BRUSH = 5.5


def compare(base: Path, other: Path) -> str:
    """Two runs files (e.g. two networks) paired by (setting, teammate, seed): the mean
    realised cost of the settled cycles (lambda 0), other - base, per setting and in all, with
    95 % paired bootstrap intervals; and how often the robot's Brush took the slow path."""
    from bench_painting_sampler import SETTLED
    from bench_quality import paired_bootstrap

    runs = {}
    lines = []
    for name, path in (("base", base), ("other", other)):
        rows = _read(path)
        runs[name] = {(d["setting"], d["human"], d["seed"]): d["records"] for d in rows}
        brush = [r.realised.timeline["brush"] for d in rows for r in d["records"]
                 if "brush" in r.plan.robot]
        slow = sum(end - start > SLOW_BRUSH for start, end in brush)
        lines.append(f"{name} ({path.name}): the robot's Brush slower than {SLOW_BRUSH} s in "
                     f"{slow} of {len(brush)} cycles")
    keys = sorted(set(runs["base"]) & set(runs["other"]))

    def cost(recs: list[CycleRecord]) -> float:
        return statistics.mean(r.realised.cost for r in recs[SETTLED:])

    groups = {"all": keys} | {f"{s} {h}": [k for k in keys if k[:2] == (s, h)]
                              for s, h in dict.fromkeys(k[:2] for k in keys)}
    for label, ks in groups.items():
        diffs = np.array([cost(runs["other"][k]) - cost(runs["base"][k]) for k in ks])
        lo, hi = paired_bootstrap(diffs)
        base_mean = statistics.mean(cost(runs["base"][k]) for k in ks)
        lines.append(f"{label}: {len(ks)} pairs, other - base {diffs.mean():+.3f} "
                     f"[{lo:+.3f}, {hi:+.3f}], base mean {base_mean:.2f}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", default="0-4")
    ap.add_argument("--cycles", type=int, default=7)
    ap.add_argument("--runs", type=Path, default=Path("painting-loop-runs.jsonl"))
    ap.add_argument("--policy", help="checkpoint directory or shipped name (default: the "
                    "world's default)")
    ap.add_argument("--no-reuse", action="store_true",
                    help="steer every motion anew each cycle (reuse_motions=False)")
    ap.add_argument("--docs", action="store_true", help="rewrite the docs section")
    ap.add_argument("--compare", type=Path, nargs=2, metavar=("BASE", "OTHER"),
                    help="run nothing: pair two runs files' costs by setting")
    args = ap.parse_args()
    if args.compare:
        print(compare(*args.compare))
        return
    torch.set_num_threads(1)
    load0 = load_average()
    world = PaintingWorld()
    policy = load_policy(world, args.policy, device="cpu")
    done = {}
    if args.runs.exists():
        for d in _read(args.runs):
            if d.get("policy", policy.fingerprint()) != policy.fingerprint():
                raise SystemExit(f"{args.runs} holds runs of another network "
                                 f"({d['policy'][:12]}); pass its --policy or another --runs")
            if d.get("reuse", True) == args.no_reuse:
                raise SystemExit(f"{args.runs} holds runs {'with' if args.no_reuse else 'without'}"
                                 " reused motions; match its --no-reuse or use another --runs")
            done[d["setting"], d["human"], d["seed"]] = d["records"]
    t0 = time.perf_counter()
    for seed in parse_seeds(args.seeds):
        for setting, human in RUNS:
            key = (setting.name, human, seed)
            if key in done:
                continue
            recs = run_setting(setting, human, seed, args.cycles, policy,
                               **({"reuse_motions": False} if args.no_reuse else {}))
            done[key] = recs
            with args.runs.open("a") as f:
                f.write(json.dumps({"setting": setting.name, "human": human, "seed": seed,
                                    "policy": policy.fingerprint(), "reuse": not args.no_reuse,
                                    "records": [r.to_json() for r in recs]}) + "\n")
            print(f"{setting.name} {human} seed {seed}: "
                  f"{sum(_seconds(r) for r in recs):.1f} s", flush=True)
    wall = time.perf_counter() - t0
    seeds = parse_seeds(args.seeds)
    shown: dict[tuple[str, str, str], list[int]] = defaultdict(lambda: [0, 0, 0, 0])
    cycle_s = []
    by_name = {s.name: s for s in SETTINGS}
    for (name, human, seed), recs in done.items():
        if seed not in seeds:
            continue
        cycle_s += [_seconds(r) for r in recs]
        for b in setting_behaviours(world, by_name[name], human, recs):
            row = shown[name, human, f"{b.belief}: {b.name}"]
            row[0] += b.holds
            row[1] += 1
            row[2] += len(b.shown)
            row[3] += len(b.cycles)
    lines = ["| setting | teammate | behaviour | runs (every tested cycle) | cycles |",
             "|---|---|---|---|---|"]
    for (name, human, beh), (runs, n, cyc, ncyc) in shown.items():
        lines.append(f"| {name} | {human} | {beh} | {runs} of {n} | {cyc} of {ncyc} |")
    table = "\n".join(lines)
    q = statistics.quantiles(cycle_s, n=10)
    timing = (f"Cycle time (plan + execute + learn) over {len(cycle_s)} cycles: median "
              f"{statistics.median(cycle_s):.2f} s, 10th-90th percentile {q[0]:.2f}-{q[-1]:.2f}"
              f" s, max {max(cycle_s):.2f} s.")
    print(table)
    print(timing)
    if args.docs:
        update_docs_section("## Painting loop", (
            f"`benchmarks/bench_painting_loop.py --seeds {args.seeds}`: whole runs of the loop "
            f"(full adaptation, {args.cycles} cycles, the world's lambda 10 in the first half, "
            "default search: population 24, 40 generations, 32 samples, 4 particles x 8 "
            f"candidates), seeds {args.seeds}. {cpu_model()}, one torch thread, 2 cores shared "
            f"with other jobs; 1-min load average {load0} at start, {load_average()} at end; "
            f"{wall:.0f} s of runs in this invocation.\n\n{timing}\n\n"
            "Behaviours (docs/reproduction.md, \"Collaborative painting\"): a prior behaviour is "
            "tested on cycle 0, a learned one on every cycle after exploration (lambda 0). "
            "\"runs\": runs where every tested cycle shows it.\n\n" + table))


if __name__ == "__main__":
    main()
