"""``rapidds study``: the user-study instrument (design, simulate, analyze; serve lives beside).

``design`` and ``analyze`` stay light (no torch); ``simulate`` starts a Dask cluster like
``rapidds ablation``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from rapidds.cli import app
from rapidds.cli._options import POLICY, SCHEDULER, SEARCH, WORKERS, run_settings, study_checkpoint
from rapidds.errors import StudyDesignError
from rapidds.experiments.ablation import AblationConfig
from rapidds.experiments.study.systems import SYSTEMS

if TYPE_CHECKING:
    from rapidds.experiments.study.design import StudyDesign
    from rapidds.experiments.study.store import StudyStore, SurveyItems
    from rapidds.loop.config import RunConfig

study_app = typer.Typer(name="study", help="User studies: design, serve, simulate, analyze.",
                        no_args_is_help=True)
app.add_typer(study_app, name="study")


SYSTEMS_DEFAULT = ",".join(SYSTEMS)


def _split(value: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in value.split(",") if v.strip())


_PARTICIPANTS = typer.Option(32, help="Participants (a multiple of order rows x priming groups: "
                             "16 for four systems).")
_SYSTEMS = typer.Option(SYSTEMS_DEFAULT, help="Systems, comma-separated, from "
                        f"{SYSTEMS_DEFAULT.replace(',', ', ')}.")
_ROUNDS = typer.Option(7, help="Rounds (task cycles) with each system.")
_GAMMA = typer.Option(None, help="Proximity weight (default: the world's).")
_SEED = typer.Option(0, help="Study seed: which participant gets which order and group, and "
                     "(simulated) who each participant is.")
_ITEMS = typer.Option(None, help="Survey items file (YAML: items: [{id, text}, ...]); default: "
                      "Hoffman's fluency items + 'The robot got in the way of me completing my "
                      "tasks'. Stored in the study.")
_SEARCH = AblationConfig()  # the study searches as the ablation does; defaults live there
_STUDY = ("world", "variant", *SEARCH, "execution", "reacts", "deviate")
_DEFAULTS = {"world": "painting", **{n: getattr(_SEARCH, n) for n in SEARCH}}
_JSON = typer.Option(False, "--json", help="Print a JSON summary on stdout.")
_MAX_TASK = typer.Option(None, "--max-task-seconds", help="Longest a person's task may take; "
                         "a longer typed duration or tracked task is refused (default: the "
                         "world's bound, 20 x its longest mean task: painting 120 s, fetch "
                         "180 s). Stored with the design.")
_UNBALANCED = typer.Option(False, "--allow-unbalanced", help="Accept a participant count that "
                           "cannot balance order rows x priming groups (near-balance; pilots, "
                           "tests).")
_COMFORT = typer.Option(False, "--comfort-item", help="Ask on every round page how close the "
                       "robot came (\"the robot came too close to me\", 1-7) and offer a 'too "
                       "close' button; analyze relates the answers to the learned gamma.")
_LEARN = typer.Option(False, "--learn-gamma", help="Runs plan with each person's learned gamma "
                      "(--gamma learn, prior about --gamma) from the comfort item's evidence; "
                      "needs --comfort-item.")


def _build(participants: int, systems: str, rounds: int, gamma: float | None, seed: int,
           items: Path | None, search: dict[str, Any],
           unbalanced: bool = False, max_task_s: float | None = None,
           comfort: bool = False, learn: bool = False
           ) -> tuple[StudyDesign, RunConfig, SurveyItems | None]:
    """Validate every option before anything is written: design, world, run settings (``search``:
    the world, the search sizes and the execution inside the cycle), items.
    The priming groups are the world's (painting hand x speed, fetch speed x route)."""
    from rapidds.experiments.study.design import StudyDesign, priming_factors
    from rapidds.experiments.study.store import SurveyItems
    from rapidds.loop.config import RunConfig
    from rapidds.worlds.registry import make_world

    search = dict(search)
    world, variant = search.pop("world"), search.pop("variant")
    w = make_world(world, variant)
    design = StudyDesign(participants=participants, systems=_split(systems), rounds=rounds,
                         seed=seed, require_balance=not unbalanced, max_task_s=max_task_s,
                         factors=priming_factors(w), comfort=comfort)
    if learn and not comfort:  # no evidence: the belief would stay the prior all study long
        raise StudyDesignError("--learn-gamma needs --comfort-item (the evidence it learns from)")
    run = RunConfig(world=world, variant=w.variant, gamma=gamma, cycles=rounds,
                    **({"gamma_learn": True} if learn else {}), **search)
    survey = SurveyItems.load(items) if items is not None else None
    return design, run.resolved(w), survey


def _summary(store: StudyStore, out: Path) -> dict[str, Any]:
    design, run = store.design, store.base_config
    steps = store.progress()
    return {"out": str(out), "participants": design.participants, "systems": design.systems,
            "rounds": design.rounds, "seed": design.seed, "world": run.world,
            "variant": run.variant, "gamma": run.gamma, "balanced": design.balanced,
            "execution": run.execution.kind, "reacts": run.reacts, "deviate": run.deviate,
            "items": list(store.items.ids),
            "runs_finished": sum(store.rounds_done(p.id, s) >= design.rounds
                                 for p in store.participants() for s in p.systems),
            "participants_done": sum(s.kind == "done" for s in steps.values()),
            **({"runs_failed": failed} if (failed := store.failures()) else {})}


@study_app.command("design")
@run_settings(*_STUDY, defaults=_DEFAULTS, aliases={"--world": "world"})
def design_cmd(
    settings: dict[str, Any],
    out: Path = typer.Option(..., help="Folder for design.csv and study.sqlite."),
    participants: int = _PARTICIPANTS, systems: str = _SYSTEMS, rounds: int = _ROUNDS,
    gamma: float | None = _GAMMA, seed: int = _SEED, items: Path | None = _ITEMS,
    allow_unbalanced: bool = _UNBALANCED, max_task_seconds: float | None = _MAX_TASK,
    comfort_item: bool = _COMFORT, learn_gamma: bool = _LEARN, as_json: bool = _JSON,
) -> None:
    """Counterbalanced design (Williams squares, priming groups balanced across orders) written
    to DIR/design.csv and DIR/study.sqlite. The same design again changes nothing; a different
    one in the same folder is refused."""
    from rapidds.experiments.study.store import create_study

    design, run, survey = _build(participants, systems, rounds, gamma, seed, items, settings,
                                 allow_unbalanced, max_task_seconds, comfort_item, learn_gamma)
    with create_study(out, design, run, survey, lock_as="rapidds study design") as store:
        summary = _summary(store, out)
    if as_json:
        print(json.dumps(summary), flush=True)
        return
    table = design.assign()
    typer.echo(table.assign(order=table["order"].map(" > ".join)).to_string(index=False))
    typer.echo(f"{design.participants} participants x {len(design.systems)} systems x "
               f"{design.rounds} rounds on {run.world} ({run.variant}), gamma {run.gamma:g}"
               f"{f', {run.execution} robot' if run.execution.in_cycle else ''}; "
               f"wrote {out / 'design.csv'} and {out / 'study.sqlite'}")


@study_app.command("simulate")
@run_settings(*_STUDY, "device", defaults=_DEFAULTS, aliases={"--world": "world"})
def simulate_cmd(
    settings: dict[str, Any],
    out: Path = typer.Option(..., help="Study folder; created with this design if it has none; "
                             "rerunning skips finished participant x system runs."),
    participants: int = _PARTICIPANTS, systems: str = _SYSTEMS, rounds: int = _ROUNDS,
    gamma: float | None = _GAMMA, seed: int = _SEED, allow_unbalanced: bool = _UNBALANCED,
    max_task_seconds: float | None = _MAX_TASK, workers: int | None = WORKERS,
    scheduler: str | None = SCHEDULER, as_json: bool = _JSON, policy: Path | None = POLICY,
) -> None:
    """The study's protocol with simulated participants drawn around their priming group, each
    system from the population prior, on Dask. Objective measures only: no survey, no ranking."""
    from rich.console import Console

    from rapidds.cli._progress import TrialProgress
    from rapidds.experiments.ablation import check_scheduler_address, dask_client
    from rapidds.experiments.sessions import log_session
    from rapidds.experiments.study.simulate import simulate_study
    from rapidds.experiments.study.store import create_study

    device = settings.pop("device")
    design, run, _ = _build(participants, systems, rounds, gamma, seed, None, settings,
                            allow_unbalanced, max_task_seconds)
    if scheduler:
        check_scheduler_address(scheduler)
    checkpoint = study_checkpoint(run.world, policy)
    err = Console(stderr=True, soft_wrap=True)
    where = scheduler or f"local cluster, {workers or os.cpu_count()} workers"
    with create_study(out, design, run, lock_as="rapidds study simulate") as store:
        try:
            with dask_client(workers, scheduler) as client, TrialProgress() as bar:
                outcome = simulate_study(store, client, bar.on_trial, bar.on_start,
                                         device=device, policy=checkpoint)
        except KeyboardInterrupt:
            err.print(f"interrupted; finished runs are stored in {out}; rerun the same command "
                      "to finish", highlight=False)
            raise typer.Exit(130) from None
        summary = _summary(store, out)
    summary.update(simulated=log_session(out, outcome, where))
    if as_json:
        print(json.dumps(summary), flush=True)
        return
    err.print(f"{outcome.ran} runs simulated, {outcome.skipped} already stored, "
              f"{outcome.wall_s:.1f} s on {outcome.workers} workers ({where}); "
              f"analyse with: rapidds study analyze {out}", highlight=False)
    if outcome.failed:
        rid, why = outcome.failed[0]
        err.print(f"{len(outcome.failed)} run(s) failed, kept with their reasons (a rerun "
                  f"retries them); {rid}: {why}", highlight=False, markup=False)


@study_app.command("analyze")
def analyze_cmd(
    folder: Path = typer.Argument(..., help="Study folder (holding study.sqlite)."),
    as_json: bool = _JSON,
) -> None:
    """The paper's analyses on whatever the study holds: rm-ANOVA of the cost reductions,
    ranking test, ART ANOVA per survey item, figures and report.md."""
    from rapidds.experiments.study.analyze import analyze_study

    result = analyze_study(folder)
    if as_json:
        print(json.dumps(result.summary), flush=True)
        return
    typer.echo(result.report)
    typer.echo("wrote " + ", ".join(str(p) for p in result.files))
