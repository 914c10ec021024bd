"""The paper's ablation under a compliant executor, beside the open-loop one (issue 34 item 5).

Reads a study written by ``rapidds ablation --execution reactive --reacts --out DIR`` (and
redrawn by ``rapidds report DIR``), copies its figures, table and summary into
docs/results/ablation-reactive/, and writes docs/reproduction.md "The ablation under a compliant
executor": the paper's claims counted under each executor (the open-loop study's from the
committed docs/results/summary.json) and the time the monitor held the robot per level.

    python benchmarks/compliant_ablation.py runs/ablation-reactive [--command "..."]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import load_average, update_docs_section  # noqa: E402

DOC = ROOT / "docs" / "reproduction.md"
RESULTS = ROOT / "docs" / "results"
TARGET = RESULTS / "ablation-reactive"
FILES = ("ablation.png", "ablation-plan.png", "ablation-settled.png", "ablation-plan-settled.png",
         "table.md", "summary.json", "report.md")


def holds(study: Path, last: int = 4) -> dict[tuple[str, str], tuple[float, float, float, int]]:
    """(archetype, level) -> mean per cycle of the seconds the robot was held back (its pauses:
    stopped, slowed or yielding), the seconds it lost (its slowdowns record), and the hold its
    plans expected, over every cycle of every finished trial; and the trials counted."""
    from rapidds.store import RunStore

    out: dict[tuple[str, str], list[tuple[float, float, float]]] = {}
    trials: dict[tuple[str, str], set[str]] = {}
    with RunStore.open_readonly(study / "study.sqlite") as store:
        cfgs = {rid: store.run_config(rid) or {} for rid in store.run_ids()}
        for rec in store.cycle_records():
            cfg = cfgs[str(rec.run_id)]
            ex = rec.execution.in_cycle
            if ex is None:
                continue
            key = (cfg["human"], cfg["adapt"])
            held = sum(p["end"] - p["start"] for p in ex.pauses if p["agent"] == "robot")
            s = rec.slowdowns
            lost = s.total_lost if s is not None else float("nan")
            expected = float(sum(s.predicted.values())) if s is not None else float("nan")
            out.setdefault(key, []).append((held, lost, expected))
            trials.setdefault(key, set()).add(str(rec.run_id))
    return {k: (*np.mean(np.array(v), axis=0).tolist(), len(trials[k]))  # type: ignore[misc]
            for k, v in out.items()}


def _count(claims: dict) -> str:
    parts = []
    for lv, n in claims["full_better_than"].items():
        parts.append(f"better than {lv} only: {n['strictly_better']} of {n['archetypes']} "
                     f"(paper {n['paper']}), lower median {n['lower_median']} of "
                     f"{n['archetypes']}")
    ok = sum(bool(c["full_at_least_as_good"]) for c in claims["per_archetype"].values())
    return "; ".join(parts) + f"; full at least as good as every ablation: {ok} of " \
        f"{len(claims['per_archetype'])}"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("study", type=Path)
    p.add_argument("--command", default="rapidds ablation --execution reactive --reacts "
                   "--out runs/ablation-reactive")
    p.add_argument("--notes", default="")
    args = p.parse_args()
    from rapidds.experiments.report import claims_markdown, load_ablation, summarise

    data = load_ablation(args.study)
    summary = summarise(data)
    TARGET.mkdir(parents=True, exist_ok=True)
    for name in FILES:
        if (args.study / name).exists():
            shutil.copyfile(args.study / name, TARGET / name)
    open_loop = json.loads((RESULTS / "summary.json").read_text())
    n = {h: {lv: len(data.trials[h][lv]) for lv in data.levels(h)} for h in data.humans}
    sizes = sorted({k for cell in n.values() for k in cell.values()})
    full = sizes == [20] and data.cycles == 16 and len(data.humans) == 4
    hold = holds(args.study)
    rows = ["| archetype | level | trials | robot held (s / cycle) | robot lost to the monitor "
            "(s / cycle) | holds the plans expected (s / cycle) |", "|---|---|---|---|---|---|"]
    for h in data.humans:
        for lv in data.levels(h):
            held, lost, exp, k = hold.get((h, lv), (float("nan"),) * 3 + (0,))
            rows.append(f"| {h} | {lv} | {k} | {held:.2f} | {lost:.2f} | {exp:.2f} |")
    body = "\n".join([
        ("" if full else "**REDUCED SIZE** (the machine's 2 cores were shared with seven other "
         f"jobs; trials per cell: {'/'.join(map(str, sizes))} of the paper's 20). The full "
         f"size is `{args.command}` (the defaults: 4 archetypes, 6 levels, 20 trials, 16 "
         "cycles; resumable: the same command finishes a stopped study).\n"),
        f"`{args.command}` then `rapidds report {args.study}`: the paper's fetch ablation with "
        "speed and separation monitoring, re-planning on deviations, a person who reacts to the "
        "robot, and plans that expect the monitor's holds (`--slowdowns learned`, the "
        f"default under reactive execution); {data.cycles} cycles per trial; settings "
        f"{ {k: v for k, v in data.settings.items() if k in ('population', 'generations', 'samples', 'particles', 'candidates', 'gamma', 'lam', 'study_seed')} }; "  # noqa: E501
        f"load {load_average()} when this was written. Files: "
        "[realised cost](results/ablation-reactive/ablation.png), [plan cost (Figure 5)]"
        "(results/ablation-reactive/ablation-plan.png), "
        "[table](results/ablation-reactive/table.md), "
        "[report](results/ablation-reactive/report.md).",
        "",
        "| Figure 5 (plan cost) | open loop (the paper's executor) | compliant (monitored) |",
        "|---|---|---|",
        "| | ![open loop](results/ablation-plan.png) | "
        "![compliant](results/ablation-reactive/ablation-plan.png) |",
        "",
        "The paper's claims, realised cost, **compliant executor**:",
        "",
        claims_markdown(summary["claims"]),
        *(["The paper's claims, plan cost, **compliant executor**:", "",
           claims_markdown(summary["claims_plan_cost"])] if "claims_plan_cost" in summary
          else []),
        "Counted (realised cost): open loop — " + _count(open_loop["claims"]) + "; compliant — "
        + _count(summary["claims"]) + ".",
        "",
        *(["Counted (plan cost): open loop — " + _count(open_loop["claims_plan_cost"])
           + "; compliant — " + _count(summary["claims_plan_cost"]) + ".", ""]
          if "claims_plan_cost" in summary and "claims_plan_cost" in open_loop else []),
        "Time the monitor cost the robot per level (mean per cycle over every cycle of every "
        "trial): held = its pauses (stopped, slowed or yielding), lost = its realised "
        "durations beyond its motions', expected = the holds its plans predicted.",
        "",
        *rows,
        "",
        args.notes,
    ])
    update_docs_section("## The ablation under a compliant executor", body, path=DOC)
    print(body)


if __name__ == "__main__":
    main()
