"""``rapidds ablation`` (the fetch ablation study on Dask) and ``rapidds report`` (its figures,
tables and claims check, redrawn from the stored records)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from rapidds.cli import app
from rapidds.cli._options import POLICY, SCHEDULER, SEARCH, WORKERS, run_settings, study_checkpoint
from rapidds.cli._progress import TrialProgress
from rapidds.experiments.ablation import (
    ABLATION,
    ARCHETYPES,
    BASELINES,
    WORLD,
    AblationConfig,
)
from rapidds.loop.config import ADAPT_LEVELS

if TYPE_CHECKING:
    from rich.console import Console

_S = AblationConfig()
_SUMMARY_JSON = typer.Option(False, "--json", help="Print the summary as JSON on stdout.")


def _split(value: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in value.split(",") if v.strip())


def _print_report(out: Path, as_json: bool, console: Console) -> None:
    from rapidds.experiments.report import (
        claims_markdown,
        load_ablation,
        table_markdown,
        table_rows,
        write_report,
    )

    data = load_ablation(out)
    paths = write_report(data)
    summary = json.loads(paths["summary"].read_text())
    if as_json:
        print(json.dumps(summary), flush=True)
        return
    claims = summary["claims"]
    console.print(table_markdown(table_rows(data), min(4, data.cycles)), highlight=False,
                  markup=False)
    console.print(claims_markdown(claims), highlight=False, markup=False)
    if "claims_plan_cost" in summary:
        console.print("Plan cost:\n" + claims_markdown(summary["claims_plan_cost"]),
                      highlight=False, markup=False)
    console.print("wrote " + ", ".join(str(p) for p in paths.values()), highlight=False)


_SHARED = ("lam", *SEARCH, "patience", "execution", "reacts", "deviate", "slowdowns")


@app.command("ablation")
@run_settings(*_SHARED, "device", defaults={n: getattr(_S, n) for n in _SHARED})
def ablation_cmd(
    settings: dict[str, Any],
    out: Path = typer.Option(..., help="Folder for study.sqlite, figures and tables; rerunning "
                             "with the same folder skips finished trials."),
    trials: int = typer.Option(_S.trials, help="Trials per archetype and level."),
    cycles: int = typer.Option(_S.cycles, help="Cycles per trial."),
    humans: str = typer.Option(",".join(_S.humans),
                               help=f"Archetypes, comma-separated: {', '.join(ARCHETYPES)}."),
    adapt: str = typer.Option(",".join(_S.levels),
                              help=f"Levels, comma-separated: {', '.join(ADAPT_LEVELS)} "
                                   f"(ablation: {', '.join(ABLATION)}; baselines: "
                                   f"{', '.join(BASELINES)})."),
    seed: int = typer.Option(_S.seed, help="Study seed; trial i runs with seed*10000+i at "
                             "every archetype and level."),
    workers: int | None = WORKERS,
    scheduler: str | None = SCHEDULER,
    gamma: float = typer.Option(_S.gamma, help="Proximity weight of every trial."),
    as_json: bool = _SUMMARY_JSON,
    policy: Path | None = POLICY,
) -> None:
    """Run the fetch ablation study (archetypes x levels x trials) on Dask, then write the
    figure, the table and the claims check. One trial is one task; resumable."""
    from rapidds.experiments.ablation import (
        ablation_store,
        check_scheduler_address,
        check_settings,
        dask_client,
        run_ablation,
    )
    from rapidds.experiments.sessions import log_session

    device = settings.pop("device")
    checkpoint = study_checkpoint(WORLD, policy)
    study = AblationConfig(humans=_split(humans), levels=_split(adapt), trials=trials,
                           cycles=cycles, seed=seed, gamma=gamma, **settings)
    from rich.console import Console

    console = Console(soft_wrap=True)
    err = Console(stderr=True, soft_wrap=True)
    where = scheduler or f"local cluster, {workers or os.cpu_count()} workers"
    if scheduler:
        check_scheduler_address(scheduler)  # before the study's folder is made
    with ablation_store(out) as store:
        check_settings(study, store)  # before starting a cluster for nothing
        try:
            with dask_client(workers, scheduler) as client, TrialProgress() as bar:
                outcome = run_ablation(study, store, client, bar.on_trial, bar.on_start,
                                       device=device, policy=checkpoint)
        except KeyboardInterrupt:
            n = len(store.run_ids())
            err.print(f"interrupted; {n} trials are stored in {out}; rerun the same command "
                      "to finish", highlight=False)
            raise typer.Exit(130) from None
    log_session(out, outcome, where, study=study.model_dump())
    err.print(f"{outcome.ran} trials run, {outcome.skipped} already stored, "
              f"{outcome.wall_s:.1f} s on {outcome.workers} workers ({where})", highlight=False)
    if outcome.failed:
        rid, why = outcome.failed[0]
        err.print(f"{len(outcome.failed)} trial(s) failed, kept with their reasons (report.md; "
                  f"a rerun retries them); {rid}: {why}", highlight=False, markup=False)
    _print_report(out, as_json, console)


@app.command("report")
def report_cmd(
    out: Path = typer.Argument(..., help="A folder written by 'rapidds ablation'."),
    as_json: bool = _SUMMARY_JSON,
) -> None:
    """Redraw a study's figure, table and claims check from its stored records."""
    from rich.console import Console

    _print_report(out, as_json, Console(soft_wrap=True))

