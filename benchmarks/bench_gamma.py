"""Learning each person's gamma: how fast, and what it buys, for SIMULATED people.

Each seed is one simulated person whose true gamma is one of ``--factors`` times the world's
default (seed s takes factor s mod len(factors); the default factors span a factor 32). Three
planners run the same person (same seed, so the same durations and paths where plans agree):

    learn    ``--gamma learn`` (posterior mean), prior: the world's gamma, spread 4
    cautious ``--gamma learn --gamma-plan cautious`` (the posterior's 0.8 quantile); only with
             ``--arms`` naming it
    fixed    the world's fixed default gamma (the paper)
    oracle   a fixed gamma equal to the person's true one
    said     ``--gamma learn`` counting only what the person says, not their reactions (with
             ``--reacts``, where the default ``learn`` counts both)

With ``--reacts`` every arm's person also reacts to the robot (slows or pauses near it, their
distances set by their true gamma: ``SimulatedComfort.reaction``), and ``learn`` learns from
those reactions too; the runs are kept apart from those without (``reacts`` in each run).

Every arm's person answers and signals through the SIMULATED response model
(``rapidds.loop.comfort``, not the learner's likelihood). Per run and cycle: the gamma planned
with, the posterior, the cost under the person's OWN gamma (each cycle's plan scored under the
person's true model: makespan + true gamma x spatial, 256 duration samples: the paper's plan
cost, with their gamma), the realised cost under their gamma, and the "too close" signals.

Summary per world and true gamma: cycles of evidence until the learned gamma is within a factor
1.5 of the truth for good; cost over the oracle's from cycle ``--from`` on (learn and fixed);
"too close" signals per run (learn against fixed).

    .venv/bin/python benchmarks/bench_gamma.py --world fetch --seeds 0-15 --workers 2
    .venv/bin/python benchmarks/bench_gamma.py --world painting --seeds 0-7 --workers 2

Finished runs are appended to ``--runs`` (JSON lines) and not run again.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from _common import cpu_model, load_average, parse_seeds

ROOT = Path(__file__).resolve().parents[1]
FIGURE = ROOT / "docs" / "results" / "gamma.png"
ARMS = ("learn", "fixed", "oracle")  # the default arms; "cautious" on request
FACTORS = (2 ** -2.5, 2 ** -0.83, 2 ** 0.83, 2 ** 2.5)  # lowest to highest: a factor 32
SEARCH = dict(population=12, generations=10, samples=16, patience=4, particles=2, candidates=4)


def one(job: tuple[str, str, int, float, int, bool, str]) -> dict[str, Any]:
    """One run of one arm for one simulated person."""
    import torch

    from rapidds.loop import AdaptiveRun, RunConfig, load_policy
    from rapidds.worlds.registry import make_world

    torch.set_num_threads(1)
    world, arm, seed, factor, cycles, reacts, execution = job
    w = make_world(world)
    g_ref = w.problem().objective.gamma
    truth = g_ref * factor
    kw: dict[str, Any] = {"learn": dict(gamma_learn=True), "fixed": {},
                          "oracle": dict(gamma=truth),
                          "cautious": dict(gamma_learn=True, gamma_plan="cautious"),
                          "said": dict(gamma_learn=True, gamma_reactions=False)}[arm]
    cfg = RunConfig(world=world, cycles=cycles, seed=seed, comfort=truth, reacts=reacts,
                    execution=execution, **kw, **SEARCH)
    t_cpu = time.process_time()
    t0 = time.perf_counter()
    run = AdaptiveRun(cfg, load_policy(w, device="cpu"))
    recs = [r.to_json() for r in run.run()]  # the stored form
    return {
        "world": world, "arm": arm, "seed": seed, "factor": factor, "truth": truth,
        "planned": [r["gamma"] for r in recs],
        "posterior": [r["gamma_belief"]["mean"] if "gamma_belief" in r else None for r in recs],
        "plan_cost": [r["plan_cost"]["makespan"] + truth * r["plan_cost"]["spatial"]
                      for r in recs],
        "realised": [r["realised"]["makespan"] + truth * r["realised"]["spatial"] for r in recs],
        "answers": [r["comfort"]["answer"] for r in recs],
        "too_close": [len(r["comfort"]["too_close"]) for r in recs],
        "reacts": reacts, **({"execution": execution} if execution != "planned" else {}),
        "reactions": [sum(p["agent"] == "person" for p in r.get("pauses", ())) for r in recs],
        "seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - t_cpu,
    }


def cycles_to_learn(posterior: list[float], truth: float, tol: float = 1.5) -> int | None:
    """Cycles of evidence until the posterior mean is within a factor ``tol`` of the truth and
    stays there (None: not by the end)."""
    ok = [abs(math.log(p / truth)) <= math.log(tol) for p in posterior]
    for k in range(len(ok)):
        if all(ok[k:]):
            return k + 1
    return None


def summarise(runs: list[dict[str, Any]], start: int) -> str:
    by = {(r["world"], r["arm"], r["seed"]): r for r in runs}
    lines = [f"| world | true gamma (x default) | seeds | cycles to within x1.5 (per seed) "
             f"| learned gamma at end | plan cost over oracle, cycles {start}+: learn "
             "| fixed | realised cost over oracle: learn | fixed "
             "| too close per run: learn | fixed | oracle |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for world in sorted({r["world"] for r in runs}):
        for factor in sorted({r["factor"] for r in runs if r["world"] == world}):
            seeds = sorted(r["seed"] for r in runs if r["world"] == world
                           and r["factor"] == factor and r["arm"] == "learn"
                           and (world, "fixed", r["seed"]) in by
                           and (world, "oracle", r["seed"]) in by)
            if not seeds:
                continue
            trio = [(by[(world, "learn", s)], by[(world, "fixed", s)], by[(world, "oracle", s)])
                    for s in seeds]
            truth = trio[0][0]["truth"]
            learn_n = [cycles_to_learn(a["posterior"], truth) for a, _, _ in trio]
            def over(key: str, k: int, trio: list[Any] = trio) -> float:
                """Mean over seeds of arm k's mean ``key`` from ``start`` over the oracle's."""
                return float(np.mean([np.mean(t[k][key][start:]) / np.mean(t[2][key][start:]) - 1
                                      for t in trio]))

            def tc(k: int, trio: list[Any] = trio) -> float:
                return float(np.mean([sum(t[k]["too_close"]) for t in trio]))

            end = [a["posterior"][-1] for a, _, _ in trio]
            lines.append(
                f"| {world} | {truth:.3g} (x{factor:.3g}) | {len(seeds)} | "
                f"{', '.join('never' if n is None else str(n) for n in learn_n)} | "
                f"{', '.join(f'{g:.3g}' for g in end)} | "
                f"{100 * over('plan_cost', 0):+.1f} % | {100 * over('plan_cost', 1):+.1f} % | "
                f"{100 * over('realised', 0):+.1f} % | {100 * over('realised', 1):+.1f} % | "
                f"{tc(0):.1f} | {tc(1):.1f} | {tc(2):.1f} |")
    return "\n".join(lines)


def summarise_cautious(runs: list[dict[str, Any]], start: int) -> str:
    """Planning with the cautious quantile beside the mean, per world and true gamma: cost
    over the oracle from cycle ``start`` and "too close" per run (fixed beside them)."""
    by = {(r["world"], r["arm"], r["seed"]): r for r in runs}
    lines = [f"| world | true gamma (x default) | seeds | gamma planned at end: mean | "
             f"cautious | plan cost over oracle, cycles {start}+: mean | cautious | fixed | "
             "too close per run: mean | cautious | fixed |", "|" + "---|" * 11]
    for world in sorted({r["world"] for r in runs}):
        for factor in sorted({r["factor"] for r in runs if r["world"] == world}):
            seeds = sorted(s for (w, a, s), r in by.items() if w == world and a == "cautious"
                           and r["factor"] == factor and all((w, b, s) in by for b in ARMS))
            if not seeds:
                continue
            arms = ("learn", "cautious", "fixed")
            sets = {a: [by[(world, a, s)] for s in seeds] for a in arms}
            oracle = [by[(world, "oracle", s)] for s in seeds]

            def over(a: str, sets: dict[str, list[Any]] = sets,
                     oracle: list[Any] = oracle) -> str:
                v = np.mean([np.mean(r["plan_cost"][start:]) / np.mean(o["plan_cost"][start:])
                             - 1 for r, o in zip(sets[a], oracle, strict=True)])
                return f"{100 * v:+.1f} %"

            lines.append(
                f"| {world} | {sets['learn'][0]['truth']:.3g} (x{factor:.3g}) | {len(seeds)} | "
                + " | ".join(", ".join(f"{r['planned'][-1]:.3g}" for r in sets[a])
                             for a in arms[:2]) + " | "
                + " | ".join(over(a) for a in arms) + " | "
                + " | ".join(f"{np.mean([sum(r['too_close']) for r in sets[a]]):.2f}"
                             for a in arms) + " |")
    return "\n".join(lines)


def summarise_reactions(runs: list[dict[str, Any]], start: int) -> str:
    """Learning with the person's reactions (``learn``) against without (``said``), per world
    and true gamma: cycles to within x1.5, the learned gamma at the end, cost over the oracle
    from cycle ``start``, "too close" signals and the person's pauses (slowed or stopped) per
    run (fixed beside)."""
    by = {(r["world"], r["arm"], r["seed"]): r for r in runs}
    arms = ("learn", "said", "fixed")
    lines = ["| world | true gamma (x default) | seeds | cycles to within x1.5: reactions "
             "| said only | learned at end: reactions | said only | plan cost over oracle, "
             f"cycles {start}+: reactions | said only | fixed | too close per run: reactions | "
             "said only | fixed | person pauses per run: reactions | said only | fixed |",
             "|" + "---|" * 15]
    for world in sorted({r["world"] for r in runs}):
        for factor in sorted({r["factor"] for r in runs if r["world"] == world}):
            seeds = sorted(s for (w, a, s), r in by.items() if w == world and a == "said"
                           and r["factor"] == factor
                           and all((w, b, s) in by for b in (*arms, "oracle")))
            if not seeds:
                continue
            sets = {a: [by[(world, a, s)] for s in seeds] for a in (*arms, "oracle")}
            truth = sets["learn"][0]["truth"]

            def over(a: str, sets: dict[str, list[Any]] = sets) -> str:
                v = np.mean([np.mean(r["plan_cost"][start:]) / np.mean(o["plan_cost"][start:])
                             - 1 for r, o in zip(sets[a], sets["oracle"], strict=True)])
                return f"{100 * v:+.1f} %"

            def per_run(key: str, a: str, sets: dict[str, list[Any]] = sets) -> str:
                return f"{np.mean([sum(r[key]) for r in sets[a]]):.2f}"

            learned = [", ".join("never" if n is None else str(n) for n in
                                 (cycles_to_learn(r["posterior"], truth) for r in sets[a]))
                       for a in arms[:2]]
            lines.append(
                f"| {world} | {truth:.3g} (x{factor:.3g}) | {len(seeds)} | "
                + " | ".join(learned) + " | "
                + " | ".join(", ".join(f"{r['posterior'][-1]:.3g}" for r in sets[a])
                             for a in arms[:2]) + " | "
                + " | ".join(over(a) for a in arms) + " | "
                + " | ".join(per_run("too_close", a) for a in arms) + " | "
                + " | ".join(per_run("reactions", a) for a in arms) + " |")
    return "\n".join(lines)


def figure(runs: list[dict[str, Any]], path: Path = FIGURE) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    worlds = sorted({r["world"] for r in runs})
    fig, axes = plt.subplots(1, len(worlds), figsize=(6 * len(worlds), 4), squeeze=False)
    for ax, world in zip(axes[0], worlds, strict=True):
        learn = [r for r in runs if r["world"] == world and r["arm"] == "learn"]
        colours = plt.get_cmap("viridis")
        factors = sorted({r["factor"] for r in learn})
        said = [r for r in runs if r["world"] == world and r["arm"] == "said"]
        for r in learn + said:
            c = colours(factors.index(r["factor"]) / max(1, len(factors) - 1))
            x = np.arange(len(r["planned"]))
            ax.plot(x, r["planned"], color=c, lw=1, alpha=0.7,
                    ls="--" if r["arm"] == "said" else "-")
            ax.axhline(r["truth"], color=c, lw=0.8, ls=":")
        ax.set_yscale("log")
        ax.set_xlabel("cycle")
        ax.set_ylabel("gamma planned with")
        ax.set_title(f"{world}: {len(learn)} simulated people (dotted: their true gamma)"
                     + ("\nsolid: learning from reactions too; dashed: from what they say"
                        if said else ""), fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--world", default="fetch")
    ap.add_argument("--seeds", default="0-7", help="e.g. 0-7 or 0,2,5")
    ap.add_argument("--cycles", type=int, default=10)
    ap.add_argument("--from", dest="start", type=int, default=6,
                    help="first cycle of the cost comparison")
    ap.add_argument("--runs", type=Path, default=Path("gamma-runs.jsonl"))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--arms", default=",".join(ARMS),
                    help="arms to run, of learn, fixed, oracle, cautious")
    ap.add_argument("--reuse", action="store_true", help="Only summarise the stored runs.")
    ap.add_argument("--reacts", action="store_true",
                    help="The person reacts to the robot by their gamma (arms: add 'said').")
    ap.add_argument("--execution", default="planned", choices=("planned", "reactive"),
                    help="The robot follows its plan (the paper) or monitors and re-plans.")
    ap.add_argument("--figure", type=Path, default=FIGURE)
    args = ap.parse_args()
    done: list[dict[str, Any]] = []
    if args.runs.exists():
        done = [json.loads(x) for x in args.runs.read_text().splitlines() if x.strip()]
    done = [r for r in done if r.get("reacts", False) == args.reacts
            and r.get("execution", "planned") == args.execution]
    have = {(r["world"], r["arm"], r["seed"]) for r in done}
    jobs = [(args.world, arm, s, FACTORS[s % len(FACTORS)], args.cycles, args.reacts,
             args.execution)
            for s in parse_seeds(args.seeds) for arm in args.arms.split(",")
            if (args.world, arm, s) not in have]
    if not args.reuse and jobs:
        t0 = time.perf_counter()
        with ProcessPoolExecutor(args.workers) as pool, args.runs.open("a") as f:
            for r in pool.map(one, jobs):
                f.write(json.dumps(r) + "\n")
                f.flush()
                done.append(r)
                print(f"{r['world']} {r['arm']} seed {r['seed']} truth {r['truth']:.3g}: "
                      f"end {r['planned'][-1]:.3g}, {r['seconds']:.0f} s", flush=True)
        print(f"{len(jobs)} runs in {time.perf_counter() - t0:.0f} s on {cpu_model()}, "
              f"load {load_average()}")
    print(summarise(done, args.start))
    if any(r["arm"] == "cautious" for r in done):
        print(summarise_cautious(done, args.start))
    if any(r["arm"] == "said" for r in done):
        print(summarise_reactions(done, args.start))
    print(f"figure: {figure(done, args.figure)}")


if __name__ == "__main__":
    main()
