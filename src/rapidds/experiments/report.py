"""Figures, tables and the paper's claims, from a study's stored records only (no recomputing).

Two costs per cycle, each analysed the same way: the realised cost (what the deployed cycle
cost: realised makespan + gamma x realised spatial cost) and the plan cost (the paper's Figure 5
measure: the executed plan scored under the teammate's true model, ``CycleRecord.plan_cost``;
studies stored before it existed have only the first). Statistics (also in
docs/reproduction.md):

- per cycle: median and quartiles over trials of the cost (the figures and ``--json``);
- per trial: the mean cost of its last ``k = 4`` cycles, after exploration, when the
  plan has settled ("trial score"); the table gives the median and IQR over trials of it and
  its gap to the oracle's median;
- claims: for each archetype and ablation level, the difference median(full) - median(level)
  of trial scores, with a 95 % percentile bootstrap CI from 2000 paired resamples of trials
  (trial i of every level shares its seed, so trials are resampled as pairs). "better" if the
  CI lies below 0, "worse" if above, else "tie"; full is "at least as good as every ablation"
  when no comparison is "worse".
"""

from __future__ import annotations

import csv
import io
import json
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rapidds.errors import StateError
from rapidds.experiments.ablation import (
    ABLATION,
    BASELINES,
    PAPER_HUMANS,
    STORE_NAME,
    shared_settings,
)
from rapidds.experiments.sessions import read_sessions
from rapidds.fileio import atomic_write_text
from rapidds.record import CycleRecord
from rapidds.store import RunStore

METRICS = ("cost", "makespan", "spatial", "min_separation", "plan_cost")
"""Columns of a trial's array: the realised ones, then the plan cost (NaN where not stored)."""
MEASURES = {"cost": "realised cost", "plan_cost": "plan cost"}
LAST_K = 4
RESAMPLES = 2000
CONFIDENCE = 0.95
BOOTSTRAP_SEED = 0
PAPER_COUNTS = {"spatial": 3, "temporal": 2}  # archetypes where full beats X (paper, Sec. V-A)
LABELS = {"full": "full (space+time)", "spatial": "spatial only", "temporal": "temporal only",
          "none": "none", "oracle": "oracle", "exact": "exact CP-SAT"}
_LEVEL_ORDER = ABLATION + BASELINES


@dataclass
class AblationData:
    """Complete trials of a stored study.

    trials[human][level][seed] is a (cycles, len(METRICS)) array: realised values, then the
    plan cost (NaN in a study stored before plan costs were recorded).
    """

    path: Path
    cycles: int
    settings: dict[str, Any]
    trials: dict[str, dict[str, dict[int, np.ndarray]]]
    incomplete: list[str] = field(default_factory=list)
    sessions: list[dict[str, Any]] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)  # run_id -> why (kept by the store)

    def metric(self, human: str, level: str, name: str = "cost") -> np.ndarray:
        """(trials, cycles), rows in trial-seed order (so rows of two levels pair up)."""
        cell = self.trials[human][level]
        m = METRICS.index(name)
        return np.array([cell[s][:, m] for s in sorted(cell)]).reshape(len(cell), self.cycles)

    def scores(self, human: str, level: str, measure: str = "cost") -> dict[int, float]:
        """Trial seed -> mean ``measure`` (realised "cost" or "plan_cost") of its last k
        cycles."""
        k, m = min(LAST_K, self.cycles), METRICS.index(measure)
        return {s: float(a[-k:, m].mean()) for s, a in self.trials[human][level].items()}

    @property
    def has_plan_cost(self) -> bool:
        """Every stored cycle has its plan cost."""
        m = METRICS.index("plan_cost")
        return all(np.isfinite(a[:, m]).all() for cell in self.trials.values()
                   for runs in cell.values() for a in runs.values())

    @property
    def humans(self) -> list[str]:
        return list(self.trials)

    def levels(self, human: str) -> list[str]:
        return list(self.trials[human])


def _ordered(keys: set[str], order: tuple[str, ...]) -> list[str]:
    return [k for k in order if k in keys] + sorted(keys - set(order))


def load_ablation(out: Path) -> AblationData:
    """Read ``out/study.sqlite``; a run missing cycles is listed in ``incomplete``, a trial
    that failed in ``failed`` (with its reason); neither is used."""
    path = out / STORE_NAME
    if not path.is_file():
        raise StateError(f"{out} holds no study ({STORE_NAME} missing); "
                         "run 'rapidds ablation --out DIR' first")
    raw: dict[str, dict[str, dict[int, np.ndarray]]] = {}
    incomplete: list[str] = []
    cycles: int | None = None
    settings: dict[str, Any] | None = None
    with RunStore.open_readonly(path) as store:
        failed = {rid: str(f.get("reason")) for rid, f in store.failures().items()}
        by_run: dict[str | None, list[CycleRecord]] = {}
        for rec in store.cycle_records():
            by_run.setdefault(rec.run_id, []).append(rec)
        for rid in store.run_ids():
            cfg = store.run_config(rid) or {}
            shared = shared_settings(cfg)
            if settings is None:
                settings, cycles = shared, int(cfg["cycles"])
            elif shared != settings:
                raise StateError(f"{path}: run '{rid}' has other settings than the study's")
            recs = by_run.get(rid, [])
            if [r.cycle for r in recs] != list(range(int(cfg["cycles"]))):
                incomplete.append(rid)
                continue
            arr = np.array([[float(getattr(r.realised, m)) for m in METRICS[:-1]]
                            + [_plan_cost(r)] for r in recs])
            raw.setdefault(cfg["human"], {}).setdefault(cfg["adapt"], {})[int(cfg["seed"])] = arr
    if cycles is None or settings is None or not raw:
        raise StateError(f"{out} holds no finished trial yet")
    trials = {h: {lv: raw[h][lv] for lv in _ordered(set(raw[h]), _LEVEL_ORDER)}
              for h in _ordered(set(raw), PAPER_HUMANS)}
    return AblationData(out, cycles, settings, trials, incomplete, read_sessions(out), failed)


def _plan_cost(record: CycleRecord) -> float:
    pc = record.plan_cost
    return float("nan") if pc is None else float(pc.cost)


# --------------------------------------------------------------------------------------------
# statistics


def _quartiles(x: np.ndarray, axis: int | None = None) -> tuple[Any, Any, Any]:
    q1, med, q3 = np.percentile(x, [25, 50, 75], axis=axis)
    return q1, med, q3


def summarise_curves(data: AblationData, measure: str = "cost"
                     ) -> dict[str, dict[str, dict[str, Any]]]:
    """{human: {level: {"median", "q1", "q3": per-cycle lists, "trials": n}}}."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for h in data.humans:
        out[h] = {}
        for lv in data.levels(h):
            q1, med, q3 = _quartiles(data.metric(h, lv, measure), axis=0)
            out[h][lv] = {"median": [round(float(v), 4) for v in med],
                          "q1": [round(float(v), 4) for v in q1],
                          "q3": [round(float(v), 4) for v in q3],
                          "trials": len(data.trials[h][lv])}
    return out


def table_rows(data: AblationData) -> list[dict[str, Any]]:
    """One row per archetype and level: trial-score median, IQR, gap to the oracle, and the
    median makespan and spatial cost of the same cycles (where the cost comes from); then the
    same median, IQR and gap for the plan cost when the study has it."""
    k = min(LAST_K, data.cycles)
    plan = data.has_plan_cost
    rows = []
    for h in data.humans:
        oracle = data.scores(h, "oracle") if "oracle" in data.trials[h] else None
        ref = float(np.median(list(oracle.values()))) if oracle else None
        oracle_p = data.scores(h, "oracle", "plan_cost") if plan and oracle else None
        ref_p = float(np.median(list(oracle_p.values()))) if oracle_p else None
        for lv in data.levels(h):
            s = np.array(list(data.scores(h, lv).values()))
            q1, med, q3 = (float(v) for v in _quartiles(s))
            cell = data.trials[h][lv].values()
            mk = float(np.median([a[-k:, 1].mean() for a in cell]))
            sp = float(np.median([a[-k:, 2].mean() for a in cell]))
            sep = float(np.median([a[-k:, 3].min() for a in cell]))
            row: dict[str, Any] = {
                "archetype": h, "level": lv, "trials": len(s), "median": med, "q1": q1, "q3": q3,
                "gap_to_oracle": None if ref is None else med - ref,
                "gap_to_oracle_pct": None if not ref else 100.0 * (med - ref) / ref,
                "makespan": mk, "spatial": sp, "min_separation": sep,
            }
            if plan:
                p1, pm, p3 = (float(v) for v in _quartiles(
                    np.array(list(data.scores(h, lv, "plan_cost").values()))))
                row.update({"plan_median": pm, "plan_q1": p1, "plan_q3": p3,
                            "plan_gap_to_oracle": None if ref_p is None else pm - ref_p})
            rows.append(row)
    return rows


def paired_bootstrap(
    a: np.ndarray, b: np.ndarray, rng: np.random.Generator,
    resamples: int = RESAMPLES, confidence: float = CONFIDENCE,
) -> tuple[float, float, float]:
    """median(a) - median(b) and its percentile CI, resampling the pairs (a[i], b[i])."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    idx = rng.integers(0, len(a), (resamples, len(a)))
    d = np.median(a[idx], axis=1) - np.median(b[idx], axis=1)
    tail = 50.0 * (1.0 - confidence)
    lo, hi = np.percentile(d, [tail, 100.0 - tail])
    return float(np.median(a) - np.median(b)), float(lo), float(hi)


def verdict(lo: float, hi: float) -> str:
    """For a CI of full - ablation (lower cost is better)."""
    return "better" if hi < 0 else "worse" if lo > 0 else "tie"


def check_claims(data: AblationData, resamples: int = RESAMPLES, seed: int = BOOTSTRAP_SEED,
                 measure: str = "cost") -> dict[str, Any]:
    """Per archetype, full against each ablation level on ``measure`` (realised "cost" or
    "plan_cost"); counts set beside the paper's. The bootstrap streams do not depend on the
    measure, so both checks resample the same trials."""
    per: dict[str, Any] = {}
    for h in data.humans:
        if "full" not in data.trials[h]:
            continue
        full = data.scores(h, "full", measure)
        versus: dict[str, Any] = {}
        for lv in ABLATION[1:]:
            if lv not in data.trials[h]:
                continue
            other = data.scores(h, lv, measure)
            common = sorted(set(full) & set(other))
            if len(common) < 2:
                continue
            rng = np.random.default_rng([seed, zlib.crc32(f"{h}/{lv}".encode())])
            d, lo, hi = paired_bootstrap(np.array([full[s] for s in common]),
                                         np.array([other[s] for s in common]), rng, resamples)
            versus[lv] = {"diff": round(d, 4), "ci": [round(lo, 4), round(hi, 4)],
                          "verdict": verdict(lo, hi), "pairs": len(common)}
        per[h] = {"versus": versus,
                  "full_at_least_as_good": (all(v["verdict"] != "worse" for v in versus.values())
                                            if versus else None)}
    counts = {}
    for lv, paper in PAPER_COUNTS.items():
        compared = [h for h in per if lv in per[h]["versus"]]
        counts[lv] = {
            "strictly_better": sum(per[h]["versus"][lv]["verdict"] == "better" for h in compared),
            "lower_median": sum(per[h]["versus"][lv]["diff"] < 0 for h in compared),
            "archetypes": len(compared), "paper": paper,
        }
    return {
        "measure": measure,
        "statistic": (f"per trial: mean {MEASURES[measure]} of the last "
                      f"{min(LAST_K, data.cycles)} "
                      "cycles; per level: median over trials; full - level with a "
                      f"{CONFIDENCE:.0%} paired percentile bootstrap CI ({resamples} resamples "
                      f"of trials, seed {seed}); better: CI < 0, worse: CI > 0, else tie"),
        "per_archetype": per,
        "full_better_than": counts,
    }


def summarise(data: AblationData) -> dict[str, Any]:
    """The ``--json`` summary: per-cycle curves of the realised cost per archetype and level,
    plus ``claims``; with plan costs stored, also ``plan_cost`` (the same curves) and
    ``claims_plan_cost``; where trials failed, ``failed`` (run_id -> reason)."""
    out: dict[str, Any] = dict(summarise_curves(data))
    out["claims"] = check_claims(data)
    if data.failed:
        out["failed"] = dict(sorted(data.failed.items()))
    if data.has_plan_cost:
        out["plan_cost"] = summarise_curves(data, "plan_cost")
        out["claims_plan_cost"] = check_claims(data, measure="plan_cost")
    return out


# --------------------------------------------------------------------------------------------
# writing


def _f(v: float | None, fmt: str = ".2f") -> str:
    return "–" if v is None else format(v, fmt)


def table_markdown(rows: list[dict[str, Any]], k: int) -> str:
    plan = bool(rows) and "plan_median" in rows[0]
    head = (f"| archetype | level | trials | median cost, last {k} | IQR | gap to oracle | "
            "gap % | makespan | spatial | min. separation |"
            + (" plan cost | plan IQR | plan gap to oracle |" if plan else "") + "\n"
            "|---|---|---:|---:|---|---:|---:|---:|---:|---:|"
            + ("---:|---|---:|" if plan else "") + "\n")
    body = "".join(
        f"| {r['archetype']} | {LABELS.get(r['level'], r['level'])} | {r['trials']} | "
        f"{r['median']:.2f} | {r['q1']:.2f}–{r['q3']:.2f} | {_f(r['gap_to_oracle'], '+.2f')} | "
        f"{_f(r['gap_to_oracle_pct'], '+.1f')} | {r['makespan']:.2f} | {r['spatial']:.3f} | "
        f"{r['min_separation']:.2f} |"
        + (f" {r['plan_median']:.2f} | {r['plan_q1']:.2f}–{r['plan_q3']:.2f} | "
           f"{_f(r['plan_gap_to_oracle'], '+.2f')} |" if plan else "") + "\n"
        for r in rows)
    return head + body


def table_csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if v is None else round(v, 6) if isinstance(v, float) else v)
                    for k, v in r.items()})
    return buf.getvalue()


def claims_markdown(claims: dict[str, Any]) -> str:
    lines = ["| archetype | full − spatial only | full − temporal only | full − none | "
             "full at least as good as every ablation |", "|---|---|---|---|---|"]
    for h, c in claims["per_archetype"].items():
        cells = []
        for lv in ABLATION[1:]:
            v = c["versus"].get(lv)
            cells.append("–" if v is None else
                         f"{v['diff']:+.2f} [{v['ci'][0]:+.2f}, {v['ci'][1]:+.2f}] {v['verdict']}")
        ok = c["full_at_least_as_good"]
        yes = "–" if ok is None else "yes" if ok else "no"
        lines.append(f"| {h} | " + " | ".join(cells) + f" | {yes} |")
    lines.append("")
    for lv, n in claims["full_better_than"].items():
        lines.append(f"- full strictly better than {LABELS[lv]} (CI below 0): "
                     f"**{n['strictly_better']} of {n['archetypes']}** archetypes "
                     f"(paper: {n['paper']}); lower median: {n['lower_median']} of "
                     f"{n['archetypes']}")
    lines.append(f"\nStatistic: {claims['statistic']}.")
    return "\n".join(lines) + "\n"


def _curves_for_plot(data: AblationData, measure: str = "cost") -> dict[str, dict[str, np.ndarray]]:
    return {h: {LABELS.get(lv, lv): data.metric(h, lv, measure) for lv in data.levels(h)}
            for h in data.humans}


def plot_settled(data: AblationData, path: Path, measure: str = "cost") -> Path:
    """The cycles after exploration only, on their own scale: exploration's alternating
    allocations cost up to twice as much and flatten the differences that remain after it."""
    from rapidds.plots._mpl import plt, save

    first = int(np.ceil(data.cycles / 2))
    names = data.humans
    fig, axes = plt.subplots(1, len(names), figsize=(4 * len(names), 3.2), squeeze=False)
    for ax, h in zip(axes[0], names, strict=True):
        for lv in data.levels(h):
            arr = data.metric(h, lv, measure)[:, first:]
            x = np.arange(first, data.cycles)
            q1, med, q3 = _quartiles(arr, axis=0)
            color = f"C{_LEVEL_ORDER.index(lv)}" if lv in _LEVEL_ORDER else None
            ax.plot(x, med, label=LABELS.get(lv, lv), color=color, lw=1.6)
            ax.fill_between(x, q1, q3, color=color, alpha=0.12)
        ax.set_title(f"{h}, after exploration")
        ax.set_xlabel("cycle")
    axes[0][0].set_ylabel(MEASURES[measure])
    axes[0][-1].legend(fontsize=8)
    fig.tight_layout()
    return save(fig, path)


def write_report(data: AblationData, out: Path | None = None) -> dict[str, Path]:
    """Write the figure (PNG, PDF; and the cycles after exploration alone, PNG), the same for
    the plan cost when stored (``ablation-plan*``), the table (Markdown, CSV), summary.json
    and report.md."""
    from rapidds.plots.curves import plot_study_panels

    out = out or data.path
    k = min(LAST_K, data.cycles)
    curves = _curves_for_plot(data)
    end = data.cycles / 2 - 0.5
    paths = {
        "png": plot_study_panels(curves, out / "ablation.png", end),
        "pdf": plot_study_panels(curves, out / "ablation.pdf", end),
    }
    if data.cycles >= 4:
        paths["settled"] = plot_settled(data, out / "ablation-settled.png")
    if data.has_plan_cost:
        plan = _curves_for_plot(data, "plan_cost")
        paths["plan_png"] = plot_study_panels(plan, out / "ablation-plan.png", end, "plan cost")
        paths["plan_pdf"] = plot_study_panels(plan, out / "ablation-plan.pdf", end, "plan cost")
        if data.cycles >= 4:
            paths["plan_settled"] = plot_settled(data, out / "ablation-plan-settled.png",
                                                 "plan_cost")
    rows = table_rows(data)
    summary = summarise(data)
    md_table = table_markdown(rows, k)
    files: Mapping[str, tuple[str, str]] = {
        "table_md": ("table.md", md_table),
        "table_csv": ("table.csv", table_csv(rows)),
        "summary": ("summary.json", json.dumps(summary, indent=1) + "\n"),
        "report": ("report.md", report_markdown(data, md_table, summary["claims"],
                                                summary.get("claims_plan_cost"))),
    }
    for key, (name, text) in files.items():
        atomic_write_text(out / name, text)
        paths[key] = out / name
    return paths


def report_markdown(data: AblationData, md_table: str, claims: dict[str, Any],
                    plan_claims: dict[str, Any] | None = None) -> str:
    s = data.settings
    n = sum(len(c) for lv in data.trials.values() for c in lv.values())
    settings = ", ".join(f"{k}={s[k]}" for k in (
        "cycles", "gamma", "lam", "population", "generations", "samples", "patience",
        "particles", "candidates", "study_seed") if k in s)
    wall = [x for x in data.sessions if x.get("ran")]
    timing = "".join(
        f"- {x['finished']}: {x['ran']} trials in {x['wall_s']:.0f} s on {x['workers']} "
        f"workers ({x['cluster']}); {x['skipped']} already stored\n" for x in wall)
    incomplete = (f"\n{len(data.incomplete)} run(s) missing cycles were left out: "
                  f"{', '.join(data.incomplete[:5])}\n" if data.incomplete else "")
    incomplete += (f"\n{len(data.failed)} trial(s) failed and were left out (a rerun retries "
                   "them):\n" + "".join(f"- {rid}: {why}\n"
                                        for rid, why in sorted(data.failed.items()))
                   if data.failed else "")
    return (
        f"# Fetch ablation study\n\n{n} finished trials in `{data.path / STORE_NAME}`; "
        f"{settings}.\n{incomplete}\n![realised cost per cycle](ablation.png)\n\n"
        f"Median over trials (line) and interquartile range (band) of the realised cost per "
        f"cycle; the red line marks the end of exploration (lambda = 0 after it).\n\n"
        + ("![after exploration](ablation-settled.png)\n\n" if data.cycles >= 4 else "")
        + ("![plan cost per cycle](ablation-plan.png)\n\nThe same for the plan cost: the "
           "executed plan scored under the teammate's true model (the paper's Figure 5).\n\n"
           if plan_claims else "")
        + f"## Last {min(LAST_K, data.cycles)} cycles\n\n{md_table}\n"
        f"## The paper's claims, realised cost\n\n{claims_markdown(claims)}"
        + (f"\n## The paper's claims, plan cost\n\n{claims_markdown(plan_claims)}"
           if plan_claims else "")
        + (f"\n## Sessions\n\n{timing}" if timing else "")
    )


def gamma_rows(records: list[CycleRecord]) -> list[dict[str, Any]]:
    """Per cycle of a run that learned gamma (records with ``gamma_belief``): the gamma it was
    planned with, what the person said and signalled, and the posterior after it."""
    rows = []
    for r in records:
        if r.gamma_belief is None:
            continue
        ev, post = r.comfort or {}, r.gamma_belief
        rows.append({"cycle": r.cycle, "planned": r.plan.gamma, "answer": ev.get("answer"),
                     "too_close": len(ev.get("too_close", [])), "peak": ev.get("peak"),
                     "mean": post["mean"], "q10": post["q10"], "q90": post["q90"],
                     "true": ev.get("true_gamma")})
    return rows


def gamma_markdown(rows: list[dict[str, Any]]) -> str:
    """The gamma posterior per cycle as a Markdown table (true gamma: simulated people only)."""
    lines = ["| cycle | planned with | answer (1-7) | too close | peak closeness "
             "| posterior mean | 10-90 % | true (simulated) |", "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['cycle']} | {row['planned']:.3g} | {row['answer'] or '-'} | "
                     f"{row['too_close']} | {_f(row['peak'])} | {row['mean']:.3g} | "
                     f"{row['q10']:.3g}-{row['q90']:.3g} | "
                     f"{'-' if row['true'] is None else format(row['true'], '.3g')} |")
    return "\n".join(lines)
