"""Teammates who change (beyond the paper): how fast each model follows a person who changes
at a cycle.

Fetch, 24 cycles, the change at cycle 12 (``--at``). Kinds of change:

    fatigue   fast-outside -> slow-outside      practice  slow-middle -> fast-middle
    habit     fast-middle -> fast-outside (t2/t3 route)
    drift     fast-middle, durations x1.04 per cycle from cycle 12
    none      fast-outside throughout (false alarms, and no worse than the paper's model)

Models: ``paper`` (forgetting 1, no detection: today's), ``forget`` (exponential forgetting
0.8), ``detect`` (change-point detection, reset), ``ask`` (detection + a question the simulated
person answers truthfully), ``person`` (detection, and a change acted on moves the person's
other tasks by the same ratio: ``--whole-person``), ``person-ask`` (that, asking first), and the
``oracle`` planner that knows the person as they are now.

Per run: belief error at cycle c = mean over the human tasks the person did after the change of
|learned mean - true mean| / true mean (the truth of cycle c); cycles to learn = cycles after
the change until the error is below 10 % and stays there; cost over oracle = mean realised cost
over cycles at+4 .. end over the oracle's, same seed; plan cost over oracle = the same with each
cycle's plan cost (its schedule and motions scored under the person's true model, 256 duration
samples: the paper's Figure 5 measure, without the luck of one cycle's durations); false
alarms = resets or questions about a change before the true one (any, for ``none``);
person-level moves are not counted as alarms (they follow one).

    .venv/bin/python benchmarks/bench_changes.py --seeds 0-3 --workers 2 [--update-docs]

Every finished run is appended to ``--runs`` (JSON lines) and not run again, so an interrupted
invocation resumes, and ``--models`` runs a subset (the summary covers every stored run of the
chosen seeds).
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from _common import cpu_model, load_average, parse_seeds, update_docs_section

SECTION = "## Teammates who change (fetch)"
ROOT = Path(__file__).resolve().parents[1]
RAW = ROOT / "docs" / "results" / "changes.json"
FIGURE = ROOT / "docs" / "results" / "changes.png"

KINDS: dict[str, dict[str, Any]] = {
    "fatigue": dict(human="fast-outside", change="slow-outside@{at}"),
    "practice": dict(human="slow-middle", change="fast-middle@{at}"),
    "habit": dict(human="fast-middle", change="fast-outside@{at}"),
    "drift": dict(human="fast-middle", drift=0.04, drift_from="{at}"),
    "none": dict(human="fast-outside"),
}
MODELS: dict[str, dict[str, Any]] = {
    "paper": {},
    "forget": dict(forgetting=0.8),
    "detect": dict(detect=True),
    "ask": dict(detect=True, ask=True),
    "person": dict(detect=True, whole_person=True),
    "person-ask": dict(detect=True, ask=True, whole_person=True),
    "oracle": dict(adapt="oracle"),
}


def _config(kind: str, model: str, seed: int, cycles: int, at: int) -> dict[str, Any]:
    kw = {k: (int(v.format(at=at)) if k == "drift_from" else v.format(at=at))
          if isinstance(v, str) and "{at}" in v else v for k, v in KINDS[kind].items()}
    return dict(kw, **MODELS[model], cycles=cycles, seed=seed)


def one(job: tuple[str, str, int, int, int]) -> dict[str, Any]:
    """One run: per-cycle belief error, cost and alarms."""
    import torch

    from rapidds.loop import AdaptiveRun, RunConfig, load_policy
    from rapidds.worlds.registry import make_world

    torch.set_num_threads(1)
    kind, model, seed, cycles, at = job
    run = AdaptiveRun(RunConfig(**_config(kind, model, seed, cycles, at)),
                      load_policy(make_world("fetch"), device="cpu"))
    recs = run.run()
    done = sorted({t for r in recs[at:] for t in r.observed})
    err = []
    for r in recs:
        truth = run.teammate.at(r.cycle + 1).true_mean_durations()  # what the next plan needs
        belief = r.belief["mean_durations"]
        err.append(float(np.mean([abs(belief[t] - truth[t]) / truth[t] for t in done]))
                   if done and belief else float("nan"))
    alarms = [(r.cycle, a) for r in recs for a in r.changes or [] if "task" in a]
    return {"kind": kind, "model": model, "seed": seed, "cycles": cycles, "at": at, "error": err,
            "cost": [r.realised.cost for r in recs],
            "plan_cost": [r.plan_cost.cost if r.plan_cost else float("nan") for r in recs],
            "false_alarms": sum(1 for c, a in alarms if kind == "none" or a["since_cycle"] < at),
            "alarms": len(alarms),
            "seconds": float(sum((r.seconds or {}).get("total", 0.0) for r in recs))}


def _learned_after(err: list[float], at: int) -> int:
    """Cycles after the change until the error is < 10 % for good (len - at + 1: never)."""
    tail = err[at:]
    for k in range(len(tail)):
        if all(e < 0.10 for e in tail[k:]):
            return k + 1  # k + 1 cycles of observations of the new person
    return len(tail) + 1


def _over(runs: list[dict[str, Any]], by: dict[tuple[str, str, int], dict[str, Any]],
          key: str, at: int) -> list[float]:
    """Per run: mean ``key`` over cycles at+4.. over the oracle's of the same seed, minus 1."""
    out = []
    for r in runs:
        o = by.get((r["kind"], "oracle", r["seed"]))
        if o is not None:
            out.append(float(np.mean(r[key][at + 4:]) / np.mean(o[key][at + 4:]) - 1))
    return out


def summarise(results: list[dict[str, Any]], at: int, cycles: int) -> str:
    lines = ["| change | model | cycles to learn (median, max) | belief error at end "
             f"| realised cost over oracle, cycles {at + 4}-{cycles - 1} (per seed) "
             "| plan cost over oracle (mean ± s.e.) | false alarms / runs |",
             "|---|---|---|---|---|---|---|"]
    by = {(r["kind"], r["model"], r["seed"]): r for r in results}
    seeds = sorted({r["seed"] for r in results})
    for kind in KINDS:
        for model in MODELS:
            if model == "oracle":
                continue
            runs = [by[(kind, model, s)] for s in seeds if (kind, model, s) in by]
            if not runs:
                continue
            learn = [_learned_after(r["error"], at) for r in runs]
            over, plan = _over(runs, by, "cost", at), _over(runs, by, "plan_cost", at)
            never = cycles - at + 1
            fmt = [("never" if x >= never else str(x)) for x in (int(np.median(learn)),
                                                               max(learn))]
            se = np.std(plan, ddof=1) / np.sqrt(len(plan)) if len(plan) > 1 else float("nan")
            lines.append(f"| {kind} | {model} | {fmt[0]}, {fmt[1]} | "
                         f"{100 * np.mean([r['error'][-1] for r in runs]):.1f} % | "
                         f"{100 * np.mean(over):+.1f} % "
                         f"({', '.join(f'{100 * x:+.1f}' for x in over)}) | "
                         f"{100 * np.mean(plan):+.1f} ± {100 * se:.1f} % | "
                         f"{sum(r['false_alarms'] for r in runs)} / {len(runs)} |")
    return "\n".join(lines)


def figure(results: list[dict[str, Any]], at: int, kind: str = "fatigue") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b, c) = plt.subplots(1, 3, figsize=(15, 3.8))
    for model in MODELS:
        runs = [r for r in results if r["kind"] == kind and r["model"] == model]
        if not runs:
            continue
        x = np.arange(len(runs[0]["cost"]))
        ls = "--" if model == "oracle" else "-"
        if model != "oracle":
            a.plot(x, 100 * np.nanmean([r["error"] for r in runs], axis=0), label=model)
        b.plot(x, np.mean([r["cost"] for r in runs], axis=0), label=model, ls=ls)
        c.plot(x, np.mean([r["plan_cost"] for r in runs], axis=0), label=model, ls=ls)
    for ax in (a, b, c):
        ax.axvline(at - 0.5, color="k", lw=0.8, ls=":")
        ax.set_xlabel("cycle")
        ax.legend(fontsize=7)
    a.axhline(10, color="grey", lw=0.8)
    a.set_ylabel("belief error of mean durations [%]")
    b.set_ylabel("realised cost (makespan + γ·spatial)")
    c.set_ylabel("plan cost under the true person")
    fig.suptitle(f"fetch, {kind}: {KINDS[kind]['human']} -> "
                 f"{KINDS[kind].get('change', '').split('@')[0]} at cycle {at} "
                 f"(mean of {len({r['seed'] for r in results})} seeds)")
    fig.tight_layout()
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURE, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", default="0-3", help="e.g. 0-3 or 0,2,5")
    ap.add_argument("--models", default=",".join(MODELS), help="the models to run")
    ap.add_argument("--runs", type=Path, default=Path("changes-runs.jsonl"),
                    help="finished runs (JSON lines); those already there are not run again")
    ap.add_argument("--cycles", type=int, default=24)
    ap.add_argument("--at", type=int, default=12)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--reuse", action="store_true", help="Summarise the stored raw results.")
    ap.add_argument("--update-docs", action="store_true")
    args = ap.parse_args()
    t0 = time.perf_counter()
    seeds = parse_seeds(args.seeds)
    if args.reuse:
        results = json.loads(RAW.read_text())
    else:
        done: dict[tuple[str, str, int, int, int], dict[str, Any]] = {}
        if args.runs.exists():
            for line in args.runs.read_text().splitlines():
                d = json.loads(line)
                done[d["kind"], d["model"], d["seed"], d["cycles"], d["at"]] = d
        jobs = [(k, m, s, args.cycles, args.at) for s in seeds for k in KINDS
                for m in args.models.split(",") if (k, m, s, args.cycles, args.at) not in done]
        unknown = set(args.models.split(",")) - set(MODELS)
        if unknown:
            ap.error(f"unknown models {sorted(unknown)}; known: {', '.join(MODELS)}")
        with ProcessPoolExecutor(args.workers) as ex:
            for r in ex.map(one, jobs):
                done[r["kind"], r["model"], r["seed"], r["cycles"], r["at"]] = r
                with args.runs.open("a") as f:
                    f.write(json.dumps(r) + "\n")
                print(f"{r['kind']} {r['model']} seed {r['seed']}: {r['seconds']:.0f} s",
                      flush=True)
        results = [r for (_, _, s, c, a), r in done.items()
                   if s in seeds and c == args.cycles and a == args.at]
        RAW.parent.mkdir(parents=True, exist_ok=True)
        RAW.write_text(json.dumps(results))
    wall = time.perf_counter() - t0
    table = summarise(results, args.at, args.cycles)
    figure(results, args.at)
    print(table)
    body = (f"`benchmarks/bench_changes.py --seeds {args.seeds} --workers {args.workers}` "
            f"({len(results)} runs of {args.cycles} cycles, change at cycle {args.at}; "
            f"{wall:.0f} s wall in the last invocation on {cpu_model()}, load average "
            f"{load_average()} at its end; "
            "raw per-cycle numbers in docs/results/changes.json, figure "
            "docs/results/changes.png). Definitions in the script's docstring.\n\n"
            + table)
    if args.update_docs:
        update_docs_section(SECTION, body)


if __name__ == "__main__":
    main()
