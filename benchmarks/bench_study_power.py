"""Power and level of the user-study analyses, by simulated studies of 32 participants.

    .venv/bin/python benchmarks/bench_study_power.py [--replicates 1000] [--update-docs]

For each analysis, the share of simulated studies (seeds 0..R-1 per row) in which each effect is
significant at alpha = .05, once with the planted spatial effect and once with none:
- two-way RM ANOVA on a cost (rapidds.experiments.study.power.planted_costs, delta = 0.7 sd);
- Wilcoxon signed-rank test of the ranking (planted_rankings, beta = 0.8);
- ART ANOVA of a 7-point survey item (planted_likert, delta = 0.7 on the latent scale).
The effect sizes are the ones the tests use; a rate under "none planted" is a type I error rate.
With --update-docs the "## User-study statistics" section of docs/benchmarks.md is replaced.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _common import cpu_model, load_average, update_docs_section
from scipy import stats

from rapidds.experiments.study import (
    art_anova,
    planted_costs,
    planted_likert,
    planted_rankings,
    ranking_test,
    rejection_rates,
    rm_anova_2x2,
)


def analyses():
    return {
        "RM ANOVA, cost (delta 0.7)": (
            lambda size: lambda rng: rm_anova_2x2(planted_costs(rng, size), "y")["p"], 0.7),
        "signed-rank, ranking (beta 0.8)": (
            lambda size: lambda rng: [ranking_test(planted_rankings(rng, size)).p], 0.8),
        "ART ANOVA, 7-point item (delta 0.7)": (
            lambda size: lambda rng: art_anova(planted_likert(rng, size), "response",
                                               ["spatial", "temporal"], "participant").table["p"],
            0.7),
    }


def fmt(rates: np.ndarray) -> str:
    return " / ".join(f"{r:.3f}" for r in rates)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--replicates", type=int, default=1000)
    ap.add_argument("--update-docs", action="store_true")
    args = ap.parse_args()
    r = args.replicates
    lo, hi = stats.binom.ppf(0.025, r, 0.05) / r, stats.binom.isf(0.025, r, 0.05) / r
    rows = []
    for name, (make, size) in analyses().items():
        t0 = time.perf_counter()
        planted = rejection_rates(make(size), r, seed=0)
        none = rejection_rates(make(0.0), r, seed=r)
        per_call = (time.perf_counter() - t0) / (2 * r)
        rows.append(f"| {name} | {fmt(planted)} | {fmt(none)} | {per_call * 1e3:.1f} |")
        print(rows[-1], flush=True)
    body = "\n".join([
        f"Simulated studies of 32 participants x 4 systems, {r} per column, alpha = .05"
        f" (`benchmarks/bench_study_power.py --replicates {r}`; {cpu_model()}, 1-minute load"
        f" average {load_average()} at the end). Rates per effect: spatial / temporal /"
        " interaction for the ANOVAs, spatial vs other systems for the ranking. With none"
        f" planted every rate is a type I error rate; 95 % of rates of an exact level-.05 test"
        f" over {r} studies fall in [{lo:.3f}, {hi:.3f}].",
        "",
        "| analysis (planted effect) | rejection rate, planted | rejection rate, none planted |"
        " ms per study |",
        "|---|---|---|---|",
        *rows,
    ])
    print(body)
    if args.update_docs:
        update_docs_section("## User-study statistics", body)


if __name__ == "__main__":
    main()
