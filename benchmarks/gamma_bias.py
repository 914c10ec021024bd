"""Why the learned gamma is biased: each channel of evidence replayed through the learner alone.

Runs ``--gamma learn`` for SIMULATED people (bench_gamma.py's true gammas and small search),
keeps every cycle's evidence (answer, signals, peak closeness, exposure), and replays it through
:class:`~rapidds.human.gamma.GammaBelief` three ways: answers alone, signals alone, both. With
the truth known it prints, per person, learned / true gamma for each, the mean offset of their
unclipped answers (2-6) from the learner's expectation at the true gamma (log-units; beside
their simulated answer bias), and their signals against the count the learner expects at the
true gamma. docs/reproduction.md "Why the learned gamma is low".

    .venv/bin/python benchmarks/gamma_bias.py --world fetch --seeds 0-15 --cache bias.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from _common import parse_seeds
from bench_gamma import FACTORS, SEARCH


def one(world: str, seed: int) -> dict[str, Any]:
    import torch

    from rapidds.loop import AdaptiveRun, RunConfig, load_policy
    from rapidds.worlds.registry import make_world

    torch.set_num_threads(1)
    w = make_world(world)
    g_ref = w.problem().objective.gamma
    truth = g_ref * FACTORS[seed % len(FACTORS)]
    cfg = RunConfig(world=world, cycles=10, seed=seed, comfort=truth, gamma_learn=True, **SEARCH)
    recs = AdaptiveRun(cfg, load_policy(w)).run()
    return {"world": world, "seed": seed, "truth": truth, "g_ref": g_ref,
            "evidence": [r["comfort"] for r in recs]}


def replay(run: dict[str, Any], answers: bool, signals: bool) -> float:
    """Learned / true gamma from the run's evidence, of the chosen channels only."""
    from rapidds.human.gamma import GammaBelief, GammaEvidence

    b = GammaBelief(run["g_ref"], 4.0, run["g_ref"])
    for e in run["evidence"]:
        b.observe(GammaEvidence(e["answer"] if answers else None,
                                tuple(e["too_close"]) if signals else (),
                                tuple(e["closeness_at"]) if signals else (), e["peak"],
                                e["exposure"] if signals else 0.0))
    return b.mean() / run["truth"]


def report(runs: list[dict[str, Any]]) -> str:
    from rapidds.human.gamma import CUT, RATE, X_REF

    lines = ["seed truth/ref | learned/true: answers signals both | answer offset (n) bias | "
             "signals/expected"]
    offsets, seen, expected, ratios = [], 0, 0.0, {"a": [], "s": [], "b": []}
    for r in runs:
        ev, k = r["evidence"], r["truth"] / r["g_ref"]
        off = [(e["answer"] - 4) * CUT - math.log(k) - math.log(max(e["peak"], 1e-12) / X_REF)
               for e in ev if 2 <= e["answer"] <= 6]
        n = sum(len(e["too_close"]) for e in ev)
        x = sum(RATE * k * e["exposure"] for e in ev)
        got = {"a": replay(r, True, False), "s": replay(r, False, True), "b": replay(r, True, True)}
        for key, v in got.items():
            ratios[key].append(v)
        offsets += off
        seen, expected = seen + n, expected + x
        lines.append(f"{r['seed']:4d} {k:6.3f} | {got['a']:5.2f} {got['s']:5.2f} {got['b']:5.2f} | "
                     f"{np.mean(off) if off else math.nan:+.2f} ({len(off)}) "
                     f"{ev[0].get('bias', math.nan):+.2f} | {n}/{x:.1f}")
    lines.append(f"median learned/true: answers {np.median(ratios['a']):.2f}, signals "
                 f"{np.median(ratios['s']):.2f}, both {np.median(ratios['b']):.2f}; unclipped "
                 f"answers' offset {np.mean(offsets):+.2f} log (n={len(offsets)}); signals "
                 f"{seen} of {expected:.1f} expected ({seen / max(expected, 1e-9):.2f})")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--world", default="fetch")
    ap.add_argument("--seeds", default="0-15")
    ap.add_argument("--cache", type=Path, default=Path("gamma-bias.jsonl"))
    args = ap.parse_args()
    runs = ([json.loads(x) for x in args.cache.read_text().splitlines() if x.strip()]
            if args.cache.exists() else [])
    have = {(r["world"], r["seed"]) for r in runs}
    with args.cache.open("a") as f:
        for s in parse_seeds(args.seeds):
            if (args.world, s) not in have:
                runs.append(one(args.world, s))
                f.write(json.dumps(runs[-1]) + "\n")
                f.flush()
    print(report([r for r in runs if r["world"] == args.world]))


if __name__ == "__main__":
    main()
