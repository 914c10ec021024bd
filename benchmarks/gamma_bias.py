"""Why the learned gamma is biased: each channel of evidence replayed through the learner alone.

Runs ``--gamma learn`` for SIMULATED people (bench_gamma.py's true gammas and small search),
keeps every cycle's evidence (answer, signals, peak closeness, exposure), and replays it through
:class:`~rapidds.human.gamma.GammaBelief` three ways: answers alone, signals alone, both. With
the truth known it prints, per person, learned / true gamma for each, the mean offset of their
unclipped answers (2-6) from the learner's expectation at the true gamma (log-units; beside
their simulated answer bias), and their signals against the count the learner expects at the
true gamma. docs/reproduction.md "Why the learned gamma is low".

With ``--reacts`` the people also react to the robot by their gamma and the learner learns from
it: a fourth channel, reactions alone, and "all" for the three together, with the mean log
offset of each reaction's onset closeness (the geometric middle of the interval it began in)
from the threshold the learner expects at the true gamma (negative: they reacted with the robot
farther than the learner expects of their gamma, so it reads them as more nervous).

    .venv/bin/python benchmarks/gamma_bias.py --world fetch --seeds 0-15 --cache bias.jsonl
    .venv/bin/python benchmarks/gamma_bias.py --world fetch --seeds 0-15 --reacts ...
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


def one(world: str, seed: int, reacts: bool = False) -> dict[str, Any]:
    import torch

    from rapidds.loop import AdaptiveRun, RunConfig, load_policy
    from rapidds.worlds.registry import make_world

    torch.set_num_threads(1)
    w = make_world(world)
    g_ref = w.problem().objective.gamma
    truth = g_ref * FACTORS[seed % len(FACTORS)]
    cfg = RunConfig(world=world, cycles=10, seed=seed, comfort=truth, gamma_learn=True,
                    reacts=reacts, **SEARCH)
    run = AdaptiveRun(cfg, load_policy(w, device="cpu"))
    recs = [r.to_json() for r in run.run()]  # the stored form
    return {"world": world, "seed": seed, "truth": truth, "g_ref": g_ref, "reacts": reacts,
            "evidence": [r["comfort"] for r in recs]}


def replay(run: dict[str, Any], channels: str) -> float:
    """Learned / true gamma from the run's evidence, of the chosen channels only (a: answers,
    s: signals, r: reactions)."""
    import dataclasses

    from rapidds.human.gamma import GammaBelief, GammaEvidence

    b = GammaBelief(run["g_ref"], 4.0, run["g_ref"])
    for e in run["evidence"]:
        ev = GammaEvidence.from_dict(e)
        s, r = "s" in channels, "r" in channels
        b.observe(dataclasses.replace(
            ev, answer=ev.answer if "a" in channels else None,
            too_close=ev.too_close if s else (), closeness_at=ev.closeness_at if s else (),
            exposure=ev.exposure if s else 0.0, reactions=ev.reactions if r else (),
            calm_peak=ev.calm_peak if r else None))
    return b.mean() / run["truth"]


def onset_offsets(run: dict[str, Any]) -> list[float]:
    """Per reaction onset: log of its closeness (the interval's geometric middle) over the
    threshold the learner expects at the true gamma, anchor * g_ref / gamma."""
    k = run["truth"] / run["g_ref"]
    out = []
    for e in run["evidence"]:
        r = e.get("reactions") or {}
        for before, at in r.get("onsets", ()):
            mid = math.sqrt(max(before, 1e-12) * at) if before < at else at
            out.append(math.log(mid / (r["anchor"] / k)))
    return out


def report(runs: list[dict[str, Any]]) -> str:
    from rapidds.human.gamma import CUT, RATE, X_REF

    lines = ["seed truth/ref | learned/true: answers signals both [reactions all] | answer "
             "offset (n) bias | signals/expected [| onset offset (n)]"]
    offsets, seen, expected = [], 0, 0.0
    ratios: dict[str, list[float]] = {"a": [], "s": [], "as": [], "r": [], "asr": []}
    onsets: list[float] = []
    for r in runs:
        ev, k = r["evidence"], r["truth"] / r["g_ref"]
        off = [(e["answer"] - 4) * CUT - math.log(k) - math.log(max(e["peak"], 1e-12) / X_REF)
               for e in ev if 2 <= e["answer"] <= 6]
        n = sum(len(e["too_close"]) for e in ev)
        x = sum(RATE * k * e["exposure"] for e in ev)
        reacts = bool(r.get("reacts"))
        got = {c: replay(r, c) for c in (("a", "s", "as", "r", "asr") if reacts
                                          else ("a", "s", "as"))}
        for key, v in got.items():
            ratios[key].append(v)
        on = onset_offsets(r)
        onsets += on
        offsets += off
        seen, expected = seen + n, expected + x
        lines.append(f"{r['seed']:4d} {k:6.3f} | "
                     + " ".join(f"{v:5.2f}" for v in got.values()) + " | "
                     f"{np.mean(off) if off else math.nan:+.2f} ({len(off)}) "
                     f"{ev[0].get('bias', math.nan):+.2f} | {n}/{x:.1f}"
                     + (f" | {np.mean(on) if on else math.nan:+.2f} ({len(on)})" if reacts
                        else ""))
    med = ", ".join(f"{name} {np.median(ratios[c]):.2f}" for c, name in
                    (("a", "answers"), ("s", "signals"), ("as", "both"), ("r", "reactions"),
                     ("asr", "all")) if ratios[c])
    lines.append(f"median learned/true: {med}; unclipped answers' offset "
                 f"{np.mean(offsets):+.2f} log (n={len(offsets)}); signals {seen} of "
                 f"{expected:.1f} expected ({seen / max(expected, 1e-9):.2f})"
                 + (f"; reaction onsets' offset {np.mean(onsets):+.2f} log (n={len(onsets)})"
                    if onsets else ""))
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--world", default="fetch")
    ap.add_argument("--seeds", default="0-15")
    ap.add_argument("--cache", type=Path, default=Path("gamma-bias.jsonl"))
    ap.add_argument("--reacts", action="store_true",
                    help="The people react to the robot by their gamma; learn from it too.")
    args = ap.parse_args()
    runs = ([json.loads(x) for x in args.cache.read_text().splitlines() if x.strip()]
            if args.cache.exists() else [])
    runs = [r for r in runs if bool(r.get("reacts")) == args.reacts]
    have = {(r["world"], r["seed"]) for r in runs}
    with args.cache.open("a") as f:
        for s in parse_seeds(args.seeds):
            if (args.world, s) not in have:
                runs.append(one(args.world, s, args.reacts))
                f.write(json.dumps(runs[-1]) + "\n")
                f.flush()
    print(report([r for r in runs if r["world"] == args.world]))


if __name__ == "__main__":
    main()
