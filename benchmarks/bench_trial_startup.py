"""What a Dask worker pays per trial of the ablation study, this tree against an older checkout.

    .venv/bin/python benchmarks/bench_trial_startup.py --base /tmp/old-checkout \
        [--trials 8] [--repeat 3] [--docs]

Each repeat runs, in a fresh process per checkout (old, new, old, new, ...: both see the same
load), the first ``--trials`` trials of the default study (``rapidds ablation``'s settings) one
after another through the Dask task ``run_trial``, as one worker does, and reads the process CPU
time of each. The first trial of a process also pays the imports and the policy load. The
records (all but the ``seconds`` field) must be identical between the checkouts.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from _common import cpu_model, load_average, update_docs_section

ROOT = Path(__file__).resolve().parents[1]
WORKER = """
import hashlib, json, sys, time
t0 = time.process_time()
import torch
torch.set_num_threads(1)
import rapidds.experiments.ablation as ab
study = getattr(ab, "StudyConfig", None) or getattr(ab, "AblationConfig")
cfgs = study(trials=int(sys.argv[1])).trials_in_order()[: int(sys.argv[1])]
out = []
for c in cfgs:
    r = ab.run_trial(c.model_dump())
    rec = [{k: v for k, v in x.items() if k != "seconds"} for x in r["records"]]
    digest = hashlib.sha1(json.dumps(rec, sort_keys=True).encode()).hexdigest()
    out.append({"cpu": time.process_time() - t0, "records": digest})
    t0 = time.process_time()
print(json.dumps(out))
"""


def one_worker(src: Path, trials: int) -> list[dict[str, float | str]]:
    env = {**os.environ, "PYTHONPATH": str(src)}
    got = subprocess.run([sys.executable, "-c", WORKER, str(trials)], env=env, check=True,
                         capture_output=True, text=True)
    return json.loads(got.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True)
    ap.add_argument("--trials", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--docs", action="store_true")
    args = ap.parse_args()
    trees = {"base": args.base.resolve() / "src", "this tree": ROOT / "src"}
    load0 = load_average()
    runs: dict[str, list[list[dict]]] = {name: [] for name in trees}
    for _ in range(args.repeat):
        for name, src in trees.items():
            runs[name].append(one_worker(src, args.trials))
            print(name, [round(float(t["cpu"]), 2) for t in runs[name][-1]], flush=True)
    same = all(a["records"] == b["records"] for ra, rb in zip(runs["base"], runs["this tree"],
                                                               strict=True)
               for a, b in zip(ra, rb, strict=True))
    rows = []
    for name, got in runs.items():
        first = statistics.median(float(r[0]["cpu"]) for r in got)
        rest = statistics.median(float(t["cpu"]) for r in got for t in r[1:])
        total = statistics.median(sum(float(t["cpu"]) for t in r) for r in got)
        rows.append(f"| {name} | {first:.2f} | {rest:.2f} | {total:.1f} |\n")
    text = (
        f"`benchmarks/bench_trial_startup.py --base {args.base} --trials {args.trials} "
        f"--repeat {args.repeat}`: one process per checkout and repeat, alternating, each "
        f"running the first {args.trials} trials of the default ablation study in sequence as "
        f"one Dask worker does; process CPU time. {cpu_model()}, 2 cores shared with other "
        f"jobs; 1-min load average {load0} at start, {load_average()} at end.\n\n"
        "| code | first trial (imports, policy, prior), CPU s | later trials, median CPU s | "
        f"{args.trials} trials, CPU s |\n|---|---:|---:|---:|\n" + "".join(rows)
        + f"\nRecords identical: {'yes' if same else 'NO'}.")
    print(text)
    if args.docs:
        update_docs_section("## Ablation trials per worker", text)


if __name__ == "__main__":
    main()
