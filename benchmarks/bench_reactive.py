"""Reacting inside the cycle: planned (the paper), reactive without learning between
cycles (what a CoBOS-like cell does) and both, with people who react to the robot and deviate
from the plan at rates 0, 0.3 and 0.6, in the fetch and painting cells.

Every run is one line of --runs (JSON), so the benchmark resumes where it stopped and can be
run in parts (one world per process); --report reads them all, writes the table and figure
into docs/reproduction.md "Reacting inside the cycle".

    python benchmarks/bench_reactive.py --world fetch --seeds 8 --cycles 4 --runs R.jsonl
    python benchmarks/bench_reactive.py --report --runs R.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import cpu_model, load_average, update_docs_section  # noqa: E402

SYSTEMS = {  # name -> (adapt, execution, slowdowns)
    "planned": ("full", "planned", None),
    "reactive": ("none", "reactive", "off"),
    "both": ("full", "reactive", "learned"),  # plans for the monitor's holds (issue 34)
    "both-noholds": ("full", "reactive", "off"),  # the plan of an open-loop robot, monitored
}
SEARCH = {  # small searches: what this shared 2-core machine affords (stated in the docs)
    "fetch": dict(population=12, generations=10, samples=16, patience=4, particles=2,
                  candidates=4),
    "painting": dict(population=8, generations=4, samples=16, patience=2, particles=1,
                     candidates=2),
}
DOC = ROOT / "docs" / "reproduction.md"
FIGURE = ROOT / "docs" / "results" / "reactive.png"


def run_one(world: str, deviate: float, system: str, seed: int, cycles: int,
            policy: object) -> dict:
    from rapidds.loop import AdaptiveRun, RunConfig
    from rapidds.worlds.registry import make_world

    names = make_world(world).teammate_names
    adapt, execution, slowdowns = SYSTEMS[system]
    cfg = RunConfig(world=world, human=names[seed % len(names)], adapt=adapt, cycles=cycles,
                    seed=seed, execution=execution, reacts=True, deviate=deviate,
                    slowdowns=slowdowns, **SEARCH[world])  # type: ignore[arg-type]
    t0, c0 = time.perf_counter(), time.process_time()
    recs = [r.to_json() for r in AdaptiveRun(cfg, policy).run()]  # type: ignore[arg-type]
    r = [x["realised"] for x in recs]
    prot = [x["protective"] or {} for x in recs]
    return {
        "world": world, "deviate": deviate, "system": system, "seed": seed,
        "human": cfg.human, "cycles": cycles,
        "cost": float(np.mean([x["cost"] for x in r])),
        "makespan": float(np.mean([x["makespan"] for x in r])),
        "min_separation": float(min(x["min_separation"] for x in r)),
        "robot_stops": sum(p["agent"] == "robot" and "stop" in p["reason"]
                           for x in recs for p in x["pauses"]),
        "person_pauses": sum(p["agent"] == "person" for x in recs for p in x["pauses"]),
        "replans": sum(len(x["replans"]) for x in recs),
        "replans_changed": sum(q["changed"] for x in recs for q in x["replans"]),
        "latencies": [q["latency_s"] for x in recs for q in x["replans"]],
        "steer_latencies": [q.get("steer_s", 0.0) for x in recs for q in x["replans"]],
        "moving_inside": sum(p.get("moving_inside", 0) for p in prot),
        "cycles_moving_inside": sum(bool(p.get("moving_inside")) for p in prot),
        "per_cycle": [_cycle(x) for x in recs],
        "seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
    }


def _held(rec: dict, agent: str) -> float:
    """Seconds an agent was held back (stopped or slowed) in one cycle."""
    return float(sum(p["end"] - p["start"] for p in rec["pauses"] if p["agent"] == agent))


def _cycle(rec: dict) -> dict:
    """What one cycle's record says of reacting inside it (for the per-cycle decomposition)."""
    r = rec["realised"]
    slow = rec.get("slowdowns") or {}
    return {
        "cycle": rec["cycle"], "deviation": (rec["deviation"] or {}).get("kind"),
        "robot_lost_s": sum(slow.get("lost", {}).values()),
        "robot_hold_predicted_s": sum(slow.get("predicted", {}).values()),
        "cost": r["cost"], "makespan": r["makespan"], "spatial": r["spatial"],
        "expected": rec["expected"]["objective"], "robot_held_s": _held(rec, "robot"),
        "person_held_s": _held(rec, "person"),
        "replans": [{"reason": q["reason"], "changed": q["changed"],
                     "before": q.get("expected_cost_before"),
                     "after": q["expected_makespan_cost"],
                     "motions": [(m["by"], m.get("used")) for m in q.get("motions", [])]}
                    for q in rec["replans"]],
    }


# the parts of reactive execution, each run on the same plan, person and deviation:
# name -> (the registered execution entry: speed and separation monitoring and/or re-planning,
# steering in re-plans, recalling motions the run steered before); "no memory" steers every
# changed pair anew (what steering costs a re-plan's latency when nothing can be recalled)
PARTS = {
    "open loop": ("planned", False, False),
    "monitoring": ("monitored", False, False),
    "re-planning": ("replanning", True, True),
    "both, no steering": ("reactive", False, False),
    "both (reactive)": ("reactive", True, True),
    "both, no memory": ("reactive", True, False),
}


def decompose_one(world: str, deviate: float, seed: int, policy: object) -> list[dict]:
    """Cycle 0 of the "both" system planned once and executed by each of :data:`PARTS` (same
    draws of the person), so the differences are the parts' own."""
    import copy

    from rapidds.loop import AdaptiveRun, RunConfig
    from rapidds.loop.carry import spatial_stamps, valid_plans
    from rapidds.loop.execute import (
        CycleSetup,
        contingency_motions,
        execute_cycle,
        person_reaction,
        replan_steering,
    )
    from rapidds.worlds.registry import make_world

    names = make_world(world).teammate_names
    cfg = RunConfig(world=world, human=names[seed % len(names)], adapt="full", cycles=1,
                    seed=seed, execution="reactive", reacts=True, deviate=deviate,
                    **SEARCH[world])
    run = AdaptiveRun(cfg, policy)  # type: ignore[arg-type]
    plan = run.plan()
    spatial = run.model.spatial
    beliefs = (run.model.temporal.mean(), run.model.temporal.std())
    out = []
    for part, (execution, steer, recall) in PARTS.items():
        c = cfg.replace(execution=execution)
        human = run.teammate.execute(plan.cycle, plan.best.schedule.tasks("human"),
                                     copy.deepcopy(plan.rng))
        steering = replan_steering(run.world, c, 0, plan.gamma, run.policy, spatial)
        spare = contingency_motions(run.world, run.problem, c, 0, plan.gamma, run.policy,
                                    spatial, plan.best.motions)
        setup = CycleSetup(
            run.world, run.problem, c, 0, plan.gamma, plan.best.schedule,
            {**spare, **plan.best.motions}, beliefs, spatial, spatial.config.beta,
            steering=steering if steer else None,
            memory=valid_plans(plan.motions, spatial_stamps(spatial)) if recall else {})
        dep, dev = execute_cycle(setup, human, run.teammate, person_reaction(run.world, c))
        out.append({
            "world": world, "deviate": deviate, "seed": seed, "part": part,
            "deviation": None if dev is None else dev.kind, "cost": dep.cost,
            "makespan": dep.makespan, "spatial": dep.spatial,
            "robot_held_s": sum(q["end"] - q["start"] for q in dep.pauses
                                if q["agent"] == "robot"),
            "person_held_s": sum(q["end"] - q["start"] for q in dep.pauses
                                 if q["agent"] == "person"),
            "replans": len(dep.replans), "changed": sum(q["changed"] for q in dep.replans),
            "steered": sum(m["by"] == "steered" for q in dep.replans
                           for m in q.get("motions", [])),
            "resteered": sum(bool(m.get("used")) for q in dep.replans
                             for m in q.get("motions", [])),
            "inside": (dep.protective or {}).get("moving_inside", 0),
            "latencies": [q["latency_s"] for q in dep.replans],
            "steer_latencies": [q.get("steer_s", 0.0) for q in dep.replans]})
    return out


def decompose(args: argparse.Namespace) -> None:
    import torch

    from rapidds.loop.run import load_policy
    from rapidds.worlds.registry import make_world

    torch.set_num_threads(1)
    policy = load_policy(make_world(args.world), device="cpu")
    out = Path(args.decomposition)
    done = set()
    if out.exists():
        done = {(d["world"], d["deviate"], d["seed"])
                for d in map(json.loads, out.read_text().splitlines())}
    for seed in range(args.first_seed, args.seeds):
        for deviate in args.deviations:
            if (args.world, deviate, seed) in done:
                continue
            rows = decompose_one(args.world, deviate, seed, policy)
            with out.open("a") as f:
                f.writelines(json.dumps(r) + "\n" for r in rows)
            print(args.world, deviate, seed, {r["part"]: round(r["cost"], 2) for r in rows},
                  flush=True)


def bench(args: argparse.Namespace) -> None:
    import torch

    from rapidds.loop.run import load_policy
    from rapidds.worlds.registry import make_world

    torch.set_num_threads(1)
    runs = Path(args.runs)
    done = set()
    if runs.exists():
        for line in runs.read_text().splitlines():
            d = json.loads(line)
            done.add((d["world"], d["deviate"], d["system"], d["seed"], d["cycles"]))
    policy = load_policy(make_world(args.world), device="cpu")
    for seed in range(args.first_seed, args.seeds):
        for deviate in args.deviations:
            for system in args.systems:
                key = (args.world, deviate, system, seed, args.cycles)
                if key in done:
                    continue
                row = run_one(args.world, deviate, system, seed, args.cycles, policy)
                with runs.open("a") as f:
                    f.write(json.dumps(row) + "\n")
                print(f"{args.world} dev {deviate} {system:8s} seed {seed}: cost "
                      f"{row['cost']:.2f} replans {row['replans']} stops {row['robot_stops']} "
                      f"({row['seconds']:.0f} s)", flush=True)


def _ci(xs: list[float]) -> tuple[float, float]:
    m = float(np.mean(xs))
    half = 1.96 * float(np.std(xs, ddof=1)) / math.sqrt(len(xs)) if len(xs) > 1 else math.nan
    return m, half


def report(args: argparse.Namespace) -> None:
    rows = [json.loads(x) for x in Path(args.runs).read_text().splitlines()]
    worlds = sorted({r["world"] for r in rows})
    lines = [
        "| world | deviation | system | runs | realised cost | makespan (s) | min separation "
        "(m) | robot stops / cycle | person pauses / cycle | re-plans / cycle | "
        "cycles with a moving robot inside S_p |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    summary: dict[tuple[str, float, str], tuple[float, float]] = {}
    for w in worlds:
        for dev in sorted({r["deviate"] for r in rows if r["world"] == w}):
            for system in SYSTEMS:
                sel = [r for r in rows if (r["world"], r["deviate"], r["system"]) == (w, dev,
                                                                                     system)]
                if not sel:
                    continue
                n_cycles = sum(r["cycles"] for r in sel)
                cost, ms = _ci([r["cost"] for r in sel]), _ci([r["makespan"] for r in sel])
                summary[(w, dev, system)] = cost
                lines.append(
                    f"| {w} | {dev:g} | {system} | {len(sel)} | {cost[0]:.2f} ± {cost[1]:.2f} | "
                    f"{ms[0]:.2f} ± {ms[1]:.2f} | "
                    f"{np.median([r['min_separation'] for r in sel]):.2f} (median), "
                    f"{min(r['min_separation'] for r in sel):.2f} (min) | "
                    f"{sum(r['robot_stops'] for r in sel) / n_cycles:.2f} | "
                    f"{sum(r['person_pauses'] for r in sel) / n_cycles:.2f} | "
                    f"{sum(r['replans'] for r in sel) / n_cycles:.2f} | "
                    f"{sum(r['cycles_moving_inside'] for r in sel)} of {n_cycles} |")
    _figure(summary, worlds)
    seeds = sorted({r["seed"] for r in rows})
    cycles = sorted({r["cycles"] for r in rows})
    body = "\n".join([
        f"`python benchmarks/bench_reactive.py` ({len(rows)} runs: {len(seeds)} seeds, "
        f"{'/'.join(map(str, cycles))} cycles per run, people who react (`--reacts`), small "
        f"searches: fetch {SEARCH['fetch']}, painting {SEARCH['painting']}; {cpu_model()}, "
        f"load {load_average()} when the report was written, shared with six other jobs). "
        "Systems: **planned** = the paper (full adaptation, open-loop execution), "
        "**reactive** = `--adapt none --execution reactive` (what a CoBOS-like cell does), "
        "**both** = `--adapt full --execution reactive`. Cost = makespan + gamma x spatial, "
        "mean over a run's cycles, then mean ± 95 % interval over runs.",
        "",
        *lines,
        "",
        f"![cost against deviation rate](results/{FIGURE.name})",
        "",
        *_analysis(rows, worlds),
        *(_decomposition(args.decomposition) if args.decomposition else []),
        args.notes or "",
    ])
    update_docs_section("## Reacting inside the cycle", body, path=DOC)
    print(body)


def _paired(rows: list[dict], w: str, dev: float, a: str, b: str) -> str:
    """Mean ± 95 % interval over seeds of system a's cost minus system b's."""
    cost = {(r["system"], r["seed"]): r["cost"] for r in rows
            if (r["world"], r["deviate"]) == (w, dev)}
    d = [cost[(a, s)] - cost[(b, s)] for (x, s) in cost if x == a and (b, s) in cost]
    m, half = _ci(d) if d else (math.nan, math.nan)
    return f"{m:+.2f} ± {half:.2f}"


def _analysis(rows: list[dict], worlds: list[str]) -> list[str]:
    """Paired differences, what the re-plans did and cost, and how long monitoring held the
    robot, per world and deviation rate."""
    out = ["Paired over seeds (cost difference, mean ± 95 % interval; negative: the first is "
           "cheaper), what the re-plans of **both** did (changed: a different rest was chosen; "
           "expected gain: the expected cost of the rest as planned minus as re-planned, mean "
           "over the changed ones; motions: pairs whose concurrency changed, recalled from "
           "memory / steered now / kept, and how many of them replaced the robot's motion) and "
           "the seconds per cycle monitoring held the robot back (stopped or slowed):", "",
           "| world | deviation | both - planned | both - reactive | re-plans (changed) | "
           "expected gain (s) | motions: recalled / steered / kept (used) | robot held "
           "s / cycle (reactive, both) |", "|---|---|---|---|---|---|---|---|"]
    for w in worlds:
        for dev in sorted({r["deviate"] for r in rows if r["world"] == w}):
            cyc = {sys_: [c for r in rows if (r["world"], r["deviate"], r["system"]) == (
                w, dev, sys_) for c in r["per_cycle"]] for sys_ in SYSTEMS}
            qs = [q for c in cyc["both"] for q in c["replans"]]
            gains = [q["before"] - q["after"] for q in qs if q["changed"] and q["before"]]
            ms = [m for q in qs for m in q["motions"]]
            by = {k: sum(m[0].startswith(k) for m in ms) for k in ("recalled", "steered", "kept")}
            held = [np.mean([c["robot_held_s"] for c in cyc[x]]) if cyc[x] else math.nan
                    for x in ("reactive", "both")]
            out.append(
                f"| {w} | {dev:g} | {_paired(rows, w, dev, 'both', 'planned')} | "
                f"{_paired(rows, w, dev, 'both', 'reactive')} | {len(qs)} "
                f"({sum(q['changed'] for q in qs)}) | "
                f"{np.mean(gains) if gains else 0.0:.2f} | {by['recalled']} / {by['steered']} / "
                f"{by['kept']} ({sum(bool(m[1]) for m in ms)}) | {held[0]:.2f}, {held[1]:.2f} |")
    lat = []
    for w in worlds:
        sel = [r for r in rows if r["world"] == w]
        xs = [x for r in sel for x in r["latencies"]]
        steer = [x for r in sel for x in r.get("steer_latencies", [])]
        steered = sum(any(m[0] == "steered" for m in q["motions"])
                      for r in sel for c in r.get("per_cycle", []) for q in c["replans"])
        if xs:
            lat.append(f"{w}: p95 {1000 * float(np.percentile(xs, 95)):.1f} ms, max "
                       f"{1000 * max(xs):.1f} ms over {len(xs)} re-plans, {steered} of which "
                       f"steered a motion (the motion part: p95 "
                       f"{1000 * float(np.percentile(steer, 95)) if steer else 0.0:.1f} ms)")
    return [*out, "", "Re-planning latency inside a cycle (exhaustive remainder search, then "
            "motions recalled or steered where the concurrency changed; wall clock, torch on "
            "one thread, on the loaded machine): " + "; ".join(lat) + ".", ""]


def holds_report(args: argparse.Namespace) -> None:
    """Issue 34: plans that expect the monitor's holds, paired over seeds, into
    docs/reproduction.md "Plans that expect the safety monitor"."""
    rows = [json.loads(x) for x in Path(args.runs).read_text().splitlines()]
    worlds = sorted({r["world"] for r in rows})
    out = ["| world | deviation | seeds | both − both-noholds | both − planned | "
           "both-noholds − planned | robot held / lost / expected, s per cycle (both; "
           "both-noholds) | cycles with a moving robot inside S_p (planned, both, "
           "both-noholds) |", "|---|---|---|---|---|---|---|---|"]
    for w in worlds:
        for dev in sorted({r["deviate"] for r in rows if r["world"] == w}):
            sel = {sy: [r for r in rows if (r["world"], r["deviate"], r["system"]) == (w, dev, sy)]
                   for sy in ("planned", "both", "both-noholds")}

            def per_cycle(system: str, key: str, sel: dict = sel) -> float:
                cs = [c.get(key, math.nan) for r in sel[system] for c in r["per_cycle"]]
                return float(np.mean(cs)) if cs else math.nan

            def inside(system: str, sel: dict = sel) -> str:
                return (f"{sum(r['cycles_moving_inside'] for r in sel[system])}/"
                        f"{sum(r['cycles'] for r in sel[system])}")

            held = [f"{per_cycle(x, 'robot_held_s'):.2f} / {per_cycle(x, 'robot_lost_s'):.2f} / "
                    f"{per_cycle(x, 'robot_hold_predicted_s'):.2f}"
                    for x in ("both", "both-noholds")]
            out.append(
                f"| {w} | {dev:g} | {len({r['seed'] for r in sel['both']})} | "
                f"{_paired(rows, w, dev, 'both', 'both-noholds')} | "
                f"{_paired(rows, w, dev, 'both', 'planned')} | "
                f"{_paired(rows, w, dev, 'both-noholds', 'planned')} | {held[0]}; {held[1]} | "
                f"{inside('planned')}, {inside('both')}, {inside('both-noholds')} |")
    lat = []
    for w in worlds:
        xs = [x for r in rows if r["world"] == w and r["system"] == "both" for x in r["latencies"]]
        if xs:
            lat.append(f"{w}: p95 {1000 * float(np.percentile(xs, 95)):.1f} ms, max "
                       f"{1000 * max(xs):.1f} ms over {len(xs)} re-plans")
    cpu = sum(r["cpu_seconds"] for r in rows)
    wall = sum(r["seconds"] for r in rows)
    body = "\n".join([
        f"`python benchmarks/bench_reactive.py --world W --seeds 8 --deviations 0,0.3 --systems "
        f"planned,both,both-noholds` ({len(rows)} runs; fetch 4 and painting 2 cycles per run; "
        f"people who react; the small searches above; {cpu_model()}; {wall:.0f} s wall, "
        f"{cpu:.0f} s CPU in all, load {load_average()} when written, the 2 cores shared with "
        "seven other jobs). **planned** = the paper (full adaptation, open loop); **both** = "
        "full adaptation, reactive execution, plans that expect the monitor's holds "
        "(`--slowdowns learned`, the default under reactive execution); **both-noholds** = the "
        "same with `--slowdowns off` (the open-loop robot's plan, monitored). Cost = makespan + "
        "gamma x spatial, mean over a run's cycles; paired over seeds, mean ± 95 % interval, "
        "negative: the first is cheaper.",
        "",
        *out,
        "",
        "Re-planning latency inside a cycle with the slowdown model in the plans (**both**, "
        "wall clock on the loaded machine): " + "; ".join(lat) + ".",
        "",
        args.notes or "",
    ])
    update_docs_section("## Plans that expect the safety monitor", body, path=DOC)
    print(body)


def _decomposition(path: str) -> list[str]:
    """The parts of reactive execution on the same cycle 0 (see :data:`PARTS`)."""
    rows = [json.loads(x) for x in Path(path).read_text().splitlines()]
    out = ["What each part of reactive execution does on its own (`--decomposition`): cycle 0 "
           "of **both** planned once and executed by each part, same person, same draws, same "
           "deviation; difference to open loop paired over (seed, deviation rate) cycles, "
           "mean ± 95 % interval.", "",
           "| world | part | cycles | cost | vs open loop | makespan (s) | gamma x spatial | "
           "robot held (s) | re-plans (changed) | motions steered now (motions replaced) | "
           "re-plan latency p95 / max (ms) | moving inside S_p (instants) |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for w in sorted({r["world"] for r in rows}):
        base = {(r["deviate"], r["seed"]): r for r in rows
                if r["world"] == w and r["part"] == "open loop"}
        for part in PARTS:
            sel = [r for r in rows if r["world"] == w and r["part"] == part]
            d = _ci([r["cost"] - base[(r["deviate"], r["seed"])]["cost"] for r in sel])
            out.append(
                f"| {w} | {part} | {len(sel)} | {np.mean([r['cost'] for r in sel]):.2f} | "
                f"{d[0]:+.2f} ± {d[1]:.2f} | {np.mean([r['makespan'] for r in sel]):.2f} | "
                f"{np.mean([r['cost'] - r['makespan'] for r in sel]):.2f} | "
                f"{np.mean([r['robot_held_s'] for r in sel]):.2f} | "
                f"{sum(r['replans'] for r in sel)} ({sum(r['changed'] for r in sel)}) | "
                f"{sum(r['steered'] for r in sel)} ({sum(r['resteered'] for r in sel)}) | "
                f"{_latency(sel)} | {sum(r['inside'] for r in sel)} |")
    return [*out, ""]


def _latency(rows: list[dict]) -> str:
    """p95 / max of the re-plan latencies of ``rows`` in ms ("-": no re-plan)."""
    xs = [x for r in rows for x in r.get("latencies", [])]
    return (f"{1000 * float(np.percentile(xs, 95)):.0f} / {1000 * max(xs):.0f}" if xs
            else "-")


def _figure(summary: dict, worlds: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(worlds), figsize=(4.5 * len(worlds), 3.2), squeeze=False)
    for ax, w in zip(axes[0], worlds, strict=True):
        for k, system in enumerate(SYSTEMS):
            pts = sorted((d, v) for (ww, d, s), v in summary.items() if ww == w and s == system)
            if not pts:
                continue
            x = np.array([d for d, _ in pts]) + (k - 1) * 0.01
            ax.errorbar(x, [v[0] for _, v in pts], yerr=[v[1] for _, v in pts], marker="o",
                        capsize=3, label=system)
        ax.set_title(w)
        ax.set_xlabel("deviation rate P")
        ax.set_ylabel("realised cost")
        ax.legend(fontsize=8)
    fig.tight_layout()
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURE, dpi=110)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--world", default="fetch")
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--first-seed", type=int, default=0,
                   help="Start at this seed (a second process can take the upper seeds).")
    p.add_argument("--cycles", type=int, default=4)
    p.add_argument("--deviations", type=lambda s: [float(x) for x in s.split(",")],
                   default=[0.0, 0.3, 0.6])
    p.add_argument("--runs", default=os.environ.get("RAPIDDS_BENCH_RUNS", "reactive-runs.jsonl"))
    p.add_argument("--systems", type=lambda s: s.split(","), default=list(SYSTEMS),
                   help=f"Comma-separated, of: {', '.join(SYSTEMS)}.")
    p.add_argument("--report", action="store_true")
    p.add_argument("--report-holds", action="store_true",
                   help="Write the section on plans that expect the monitor (issue 34).")
    p.add_argument("--decomposition", default="",
                   help="Run the per-part decomposition of cycle 0 into this JSONL file.")
    p.add_argument("--notes", default="", help="Text appended to the docs section.")
    args = p.parse_args()
    (holds_report if args.report_holds else report if args.report
     else decompose if args.decomposition else bench)(args)


if __name__ == "__main__":
    main()
