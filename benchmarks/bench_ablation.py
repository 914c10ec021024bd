"""Ablation study on Dask: wall time of a fixed small study on 1 and on 2 local workers.

    .venv/bin/python benchmarks/bench_ablation.py [--trials 4] [--cycles 8] [--update-docs]

The study: fast-middle and slow-middle x full, spatial, temporal, exact, ``--trials`` trials of
``--cycles`` cycles, the study's default search settings (what ``rapidds ablation`` runs). Each
worker count gets a fresh LocalCluster (single-threaded worker processes) and a fresh store; the
time counted is from submitting the first trial to storing the last (``run_ablation``); apart, the
cluster's start, including each worker's imports and policy load (done before timing). The two
runs must store identical records (the result does not depend on how many workers computed it).
With --update-docs the "## Ablation study" section of docs/benchmarks.md is replaced (or added).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import torch
from _common import cpu_model, update_docs_section

from rapidds.experiments.ablation import AblationConfig, ablation_store, dask_client, run_ablation
from rapidds.store import RunStore


def _load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3]) if Path(
        "/proc/loadavg").exists() else "n/a"


MALLOC_NOTE = (
    "Workers start without Dask's default MALLOC_TRIM_THRESHOLD_ "
    "(`rapidds.experiments.ablation.LOCAL_WORKER_ENV`): with it, one trial took 2.2x the wall "
    "time of a plain process (9.2 s against 4.1 s, 45 % of it system time); without it, the "
    "same.\n"
)


def _warm_up() -> None:
    from rapidds.experiments.ablation import _worker_policy
    from rapidds.worlds.registry import make_world

    _worker_policy("fetch")
    make_world("fetch").prior()


def _records(path: Path) -> dict[str, list[dict]]:
    with RunStore.open_readonly(path) as st:
        return {rid: [{k: v for k, v in r.items() if k != "seconds"} for r in st.records(rid)]
                for rid in st.run_ids()}


def measure(
    study: AblationConfig, workers: int, root: Path
) -> tuple[dict[str, float], str, dict[str, list[dict]]]:
    """(seconds: cluster start, study wall time, sum of trial times; load after; records)."""
    out = root / f"w{workers}"
    t0 = time.perf_counter()
    with dask_client(workers) as client:
        client.wait_for_workers(workers)
        client.run(_warm_up)  # imports and the policy: paid once per worker, not measured
        start = time.perf_counter() - t0
        cpu0 = client.run(time.process_time)
        with ablation_store(out) as store:
            res = run_ablation(study, store, client)
        cpu1 = client.run(time.process_time)
    assert res.ran == res.total, (res.ran, res.total)
    cpu = sum(cpu1[w] - cpu0.get(w, 0.0) for w in cpu1)
    times = {"start": start, "wall": res.wall_s, "trial_sum": sum(res.trial_seconds),
             "cpu": cpu}
    return times, _load(), _records(out / "study.sqlite")


def run(trials: int, cycles: int) -> str:
    study = AblationConfig(humans=("fast-middle", "slow-middle"),
                        levels=("full", "spatial", "temporal", "exact"), trials=trials,
                        cycles=cycles)
    n = trials * len(study.humans) * len(study.levels)
    load0 = _load()
    with tempfile.TemporaryDirectory() as tmp:
        one, _, rec1 = measure(study, 1, Path(tmp))
        two, load1, rec2 = measure(study, 2, Path(tmp))
    same = rec1 == rec2
    cpu = os.cpu_count()
    return (
        f"Machine: {cpu_model()}, {cpu} cores (shared with other "
        f"jobs: 1-min load average {load0} at start, {load1} at end), torch "
        f"{torch.__version__}, 1 torch thread per worker.\n"
        f"Study: 2 archetypes x (full, spatial, temporal, exact) x {trials} trials = {n} trials "
        f"of {cycles} cycles, study search settings (population {study.population}, generations "
        f"{study.generations}, samples {study.samples}, particles {study.particles}, candidates "
        f"{study.candidates}).\n\n"
        "| workers | cluster start | study wall time | trials/min | workers' CPU time | "
        "cores used | speed-up |\n|---:|---:|---:|---:|---:|---:|---:|\n"
        + "".join(
            f"| {w} | {m['start']:.1f} s | {m['wall']:.1f} s | {60 * n / m['wall']:.1f} | "
            f"{m['cpu']:.1f} s | {m['cpu'] / m['wall']:.2f} | {one['wall'] / m['wall']:.2f} |\n"
            for w, m in ((1, one), (2, two)))
        + f"\nRecords identical on 1 and 2 workers: {'yes' if same else 'NO'}. Cores used: the "
        "workers' CPU time (time.process_time in each worker, summed) / wall time; below the "
        "worker count when other jobs, the client or the scheduler held the cores. With the "
        "same CPU work in both runs, speed-up = ratio of cores used, so on 2 free cores it "
        "would approach 2. " + MALLOC_NOTE
    )



def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=4)
    ap.add_argument("--cycles", type=int, default=8)
    ap.add_argument("--update-docs", action="store_true")
    args = ap.parse_args()
    table = run(args.trials, args.cycles)
    print(table)
    if args.update_docs:
        update_docs_section("## Ablation study", "`benchmarks/bench_ablation.py`\n\n" + table)


if __name__ == "__main__":
    main()
