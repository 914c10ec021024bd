"""The study's comfort item against the learned gamma: does the gamma the robot learned for a
person go with how close they said it came?

Per participant x system (one run): the comfort answers of its rounds ("the robot came too close
to me", 1-7) averaged, against the gamma belief after its last round (the posterior's geometric
mean, what the robot planned with). Related by Spearman's rho over the runs, with a 95 %
percentile bootstrap interval that resamples *participants* (each brings all their runs), since a
person's runs are not independent of each other.

Real participants only: a round's answer counts when a person gave it on the round page; an
answer the simulated cell's response model gave (its record says ``simulated``) is left out,
and no answer is ever filled in. A study without the item, or whose runs did not learn gamma,
gets a statement saying so.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from rapidds.experiments.study.store import StudyStore

__all__ = ["BOOTSTRAP", "comfort_section", "comfort_table", "spearman_bootstrap"]

BOOTSTRAP = 2000
"""Bootstrap resamples of the participants for rho's interval."""
COLUMNS = ("participant", "system", "rounds", "comfort", "gamma", "gamma_q10", "gamma_q90")


def comfort_table(store: StudyStore) -> pd.DataFrame:
    """One row per run with at least one answer a person gave: participant, system, rounds
    (answered), comfort (their mean answer), gamma (the belief's geometric mean after the run's
    last round; NaN when the run does not learn gamma), gamma_q10 and gamma_q90."""
    runs = store.study_runs().set_index("run_id")
    answers: dict[str, list[int]] = {}
    last: dict[str, tuple[int, dict[str, Any]]] = {}
    for r in store.cycle_records():
        rid = r.run_id
        if rid not in runs.index:
            continue
        said = r.comfort or {}
        if said.get("answer") is not None and not said.get("simulated"):
            answers.setdefault(rid, []).append(int(said["answer"]))
        belief = r.gamma_belief
        if belief is not None and int(r.cycle) >= last.get(rid, (-1, {}))[0]:
            last[rid] = (int(r.cycle), belief)
    rows = []
    for rid, said in answers.items():
        who, system = runs.loc[rid, ["participant", "system"]]
        belief = last.get(rid, (0, {}))[1]
        rows.append({"participant": who, "system": system, "rounds": len(said),
                     "comfort": float(np.mean(said)),
                     **{k: float(belief.get(b, math.nan)) for k, b in
                        (("gamma", "mean"), ("gamma_q10", "q10"), ("gamma_q90", "q90"))}})
    table = pd.DataFrame.from_records(rows, columns=list(COLUMNS))
    return table.sort_values(["participant", "system"], ignore_index=True)


def _spearman(x: np.ndarray, y: np.ndarray) -> float:
    from scipy.stats import spearmanr

    if np.ptp(x) == 0 or np.ptp(y) == 0:  # no order on one side: rho is undefined
        return math.nan
    return float(spearmanr(x, y).statistic)


def spearman_bootstrap(table: pd.DataFrame, seed: int) -> dict[str, Any]:
    """Spearman's rho of gamma and comfort over the runs, its p (scipy) and a 95 % bootstrap
    interval resampling participants (:data:`BOOTSTRAP` draws from ``seed``; draws where rho is
    undefined are left out and counted)."""
    from scipy.stats import spearmanr

    x, y = table["gamma"].to_numpy(float), table["comfort"].to_numpy(float)
    rho = _spearman(x, y)
    p = float(spearmanr(x, y).pvalue) if math.isfinite(rho) else math.nan
    people = table["participant"].unique()
    rows = {who: np.flatnonzero(table["participant"].to_numpy() == who) for who in people}
    rng = np.random.default_rng([seed, 26])
    draws = []
    for _ in range(BOOTSTRAP):
        idx = np.concatenate([rows[who] for who in rng.choice(people, len(people))])
        draws.append(_spearman(x[idx], y[idx]))
    ok = np.array([d for d in draws if math.isfinite(d)])
    low, high = (np.quantile(ok, [0.025, 0.975]).tolist() if ok.size else [math.nan] * 2)
    return {"rho": rho, "p": p, "ci95": [low, high], "bootstrap": BOOTSTRAP,
            "undefined_draws": BOOTSTRAP - int(ok.size)}


def comfort_section(table: pd.DataFrame, learns: bool, seed: int
                    ) -> tuple[dict[str, Any], list[str]]:
    """The summary's ``comfort`` part and the report's lines."""
    runs = table.to_dict("records")
    s: dict[str, Any] = {"runs": runs, "participants": int(table["participant"].nunique())}
    if table.empty:
        why = "no round holds a comfort answer a person gave (simulated answers are not used)"
        return {**s, "skipped": why}, [f"Skipped: {why}.", ""]
    md = [f"{len(table)} runs of {s['participants']} participants answered \u201cthe robot came "
          "too close to me\u201d (1-7); per run, the mean answer against the gamma belief after "
          "its last round (geometric mean, 10-90 % interval).", "",
          "| participant | system | rounds | mean answer | gamma | q10-q90 |",
          "|---|---|---|---|---|---|"]
    md += [f"| {row['participant']} | {row['system']} | {row['rounds']} | {row['comfort']:.2f} | "
           f"{row['gamma']:.3g} | {row['gamma_q10']:.3g}-{row['gamma_q90']:.3g} |" for row in runs]
    md.append("")
    if not learns or table["gamma"].isna().any():
        why = "the study's runs do not learn gamma (design it with --learn-gamma)"
        return {**s, "skipped": why}, [*md, f"No correlation: {why}.", ""]
    if s["participants"] < 3:
        why = f"{s['participants']} participants: a rank correlation needs at least 3"
        return {**s, "skipped": why}, [*md, f"No correlation: {why}.", ""]
    res = spearman_bootstrap(table, seed)
    s["spearman"] = res
    low, high = res["ci95"]
    md += [f"Spearman's rho (learned gamma vs mean answer) = {res['rho']:.2f}, p = "
           f"{res['p']:.3f}; 95 % bootstrap interval over participants [{low:.2f}, {high:.2f}] "
           f"({res['bootstrap']} resamples, {res['undefined_draws']} without any spread left "
           "out). A person who says the robot came closer than they like should have been "
           "learned a larger gamma: rho > 0.", ""]
    return s, md
