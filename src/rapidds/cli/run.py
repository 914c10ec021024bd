"""``rapidds run`` (the multi-cycle loop with a simulated teammate), ``rapidds demo`` and
``rapidds worlds``.

Heavy libraries (torch, matplotlib) are imported inside the commands, so ``--help`` is fast.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from rapidds.cli import app, fail
from rapidds.cli._device import DeviceOption
from rapidds.loop.config import ADAPT_LEVELS, RunConfig

if TYPE_CHECKING:
    from rich.console import Console

    from rapidds.loop.run import AdaptiveRun, CycleResult
    from rapidds.motion.policy import DiffusionPolicy
    from rapidds.record import CycleRecord

_D = RunConfig.model_fields


def console() -> Console:
    """stdout console; piped output gets a width that fits the tables instead of 80 columns."""
    from rich.console import Console

    probe = Console()
    return Console(soft_wrap=True, width=None if probe.is_terminal else 160)


def set_threads(threads: int) -> None:
    """The networks are small: one thread per process beats several fighting over 2 cores."""
    import torch

    torch.set_num_threads(threads)


def _cycle_row(rec: CycleRecord) -> list[str]:
    p, e, r = rec.plan, rec.expected, rec.realised
    routes = ",".join(f"{j}:{m[0]}" for j, m in sorted(p.routes.items()) if m != "direct")
    return [
        str(rec.cycle), f"{p.lam:g}", " ".join(map(str, p.human)), " ".join(map(str, p.robot)),
        routes or "-", f"{e.makespan + p.gamma * e.spatial:.2f}",
        f"{r.makespan:.2f}", f"{r.spatial:.2f}", f"{r.cost:.2f}",
        f"{r.min_separation:.2f}", "-" if rec.seconds is None else f"{rec.seconds['total']:.2f}",
    ]


_HEADER = ["cycle", "λ", "human", "robot", "motions", "exp.cost", "makespan", "spatial",
           "cost", "min.sep", "s"]
_WIDTHS = [5, 4, 18, 18, 12, 8, 8, 7, 7, 7, 5]


def _line(cells: list[str]) -> str:
    return "  ".join(c.rjust(w) if k not in (2, 3, 4) else c.ljust(w)
                     for k, (c, w) in enumerate(zip(cells, _WIDTHS, strict=True)))


def write_pictures(run: AdaptiveRun, out: Path) -> list[Path]:
    """The run's pictures (:func:`rapidds.plots.run.save_run_pictures`) from its store."""
    from rapidds.plots.run import save_run_pictures

    assert run.store is not None
    rid = run.config.run_id
    records = run.store.cycle_records(rid)
    arrays = run.store.arrays(rid, records[-1].cycle) if records else {}
    return save_run_pictures(out, rid, records, arrays, run.model.spatial, run.world,
                             run.config.exploration_end)


def redraw_missing_gantts(run: AdaptiveRun, out: Path) -> None:
    """Charts of stored cycles that a kill left undrawn (a cycle is stored before its chart)."""
    from rapidds.loop.run import timeline_of
    from rapidds.plots.gantt import save_gantt
    from rapidds.plots.run import gantt_path

    assert run.store is not None
    rid = run.config.run_id
    for rec in run.store.cycle_records(rid):
        path = gantt_path(out, rid, rec.cycle)
        if not path.exists():
            ex = rec.execution.in_cycle
            save_gantt(timeline_of(run.problem, rec), path,
                       title=f"{rid} cycle {rec.cycle} (realised)",
                       pauses=ex.pauses if ex else (), replans=ex.replans if ex else ())


def execute(
    cfg: RunConfig, policy: DiffusionPolicy | None, out: Path | None, resume: bool,
    as_json: bool, con: Console, title: str | None = None,
) -> AdaptiveRun:
    """Run (or resume) one configuration, printing a row or a JSON line per cycle."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from rapidds.loop.run import AdaptiveRun
    from rapidds.plots.gantt import save_gantt
    from rapidds.plots.run import gantt_path
    from rapidds.store import RunStore

    store = RunStore(out / "run.sqlite", lock_as="rapidds run") if out is not None else None
    run = AdaptiveRun(cfg, policy, store)
    rid = run.config.run_id
    if store is not None and run.next_cycle and not resume:
        fail(f"{out} already holds run '{rid}' ({run.next_cycle} cycles); "
             "pass --resume to continue it or choose another --out")
    err = Console(stderr=True, soft_wrap=True)
    if run.finished:
        err.print(f"run '{rid}' in {out} is already finished ({run.config.cycles} cycles); "
                  "nothing to run, pictures redrawn", highlight=False)
    if not as_json and not run.finished:
        con.print(f"[bold]{title or rid}[/bold]")
        con.print(_line(_HEADER), highlight=False)
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("{task.fields[info]}"), console=err, transient=True,
                  disable=not err.is_terminal) as bar:
        task = bar.add_task(rid, total=run.config.cycles, completed=run.next_cycle, info="")

        def on_cycle(res: CycleResult) -> None:
            rec = res.record
            if as_json:
                print(json.dumps(rec.to_json(), allow_nan=False), flush=True)
            else:
                con.print(_line(_cycle_row(rec)), highlight=False)
            if out is not None:
                save_gantt(res.deployment.timeline, gantt_path(out, rid, rec.cycle),
                           title=f"{rid} cycle {rec.cycle} (realised)",
                           pauses=res.deployment.pauses, replans=res.deployment.replans)
            bar.update(task, advance=1, info=f"cost {rec.realised.cost:.2f}")

        try:
            run.run(on_cycle)
        except KeyboardInterrupt:
            err.print(f"interrupted after cycle {run.next_cycle - 1}; every finished cycle is "
                      f"stored{'; continue with --resume' if out else ''}")
            raise typer.Exit(130) from None
    if out is not None:
        redraw_missing_gantts(run, out)
        write_pictures(run, out)
    return run


def parse_gamma(text: str | None) -> float | None:
    """``--gamma``'s number (range checks are RunConfig's); one line and exit 2 otherwise."""
    if text is None:
        return None
    try:
        return float(text)
    except ValueError:
        fail(f"--gamma is a number >= 0 or 'learn', got {text!r}")
        raise AssertionError from None  # fail() exits


def gamma_settings(text: str | None) -> dict[str, Any]:
    """``--gamma``'s RunConfig fields: 'learn' learns it, a number fixes it."""
    learn = text is not None and text.strip().lower() == "learn"
    return {"gamma": None if learn else parse_gamma(text), "gamma_learn": learn}


@app.command("run")
def run_cmd(
    world: str = typer.Argument(_D["world"].default, help="World to run in (see "
                                "'rapidds worlds')."),
    human: str | None = typer.Option(None, help="Simulated teammate, by the world's name for "
                                     "it (see 'rapidds worlds').", show_default="the world's "
                                     "first"),
    variant: str | None = typer.Option(None, help="Variant of the world's job.",
                                       show_default="the world's first"),
    cycles: int = typer.Option(_D["cycles"].default, help="Cycles I."),
    adapt: str = typer.Option(_D["adapt"].default, help=f"Adaptation: {', '.join(ADAPT_LEVELS)}."),
    seed: int = typer.Option(_D["seed"].default, help="Seed; the same seed gives the same run."),
    gamma: str | None = typer.Option(None, help="Proximity weight, or 'learn': learn this "
                                     "person's from their comfort answers and 'too close' "
                                     "signals.", show_default="the world's"),
    gamma_prior: str | None = typer.Option(None, help="With --gamma learn: the prior G or "
                                           "G:SPREAD (one log-sd is a factor SPREAD).",
                                           show_default="the world's gamma, spread 4"),
    gamma_plan: str = typer.Option(_D["gamma_plan"].default, help="With --gamma learn: plan "
                                   "with the posterior's mean or an upper quantile "
                                   "(cautious)."),
    comfort: float | None = typer.Option(None, help="The simulated teammate's own gamma "
                                         "(they answer and signal by it).",
                                         show_default="drawn from a population with "
                                         "--gamma learn"),
    lam: float | None = typer.Option(None, help="Diversity weight for the first half of the "
                                     "cycles.", show_default="the world's"),
    out: Path | None = typer.Option(None, help="Folder for run.sqlite and the pictures."),
    resume: bool = typer.Option(False, help="Continue the run stored in --out."),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per cycle on stdout."),
    policy: Path | None = typer.Option(None, help="Policy checkpoint (default: the world's "
                                       "bundled one)."),
    population: int = typer.Option(_D["population"].default, help="GA population C."),
    generations: int = typer.Option(_D["generations"].default, help="GA generations G."),
    samples: int = typer.Option(_D["samples"].default, help="Monte-Carlo duration samples K."),
    particles: int = typer.Option(_D["particles"].default, help="Steered samples per motion "
                                  "request."),
    candidates: int = typer.Option(_D["candidates"].default, help="SVDD candidates M per step."),
    steps: int | None = typer.Option(None, help="Reverse diffusion steps per motion.",
                                     show_default="the policy's"),
    sampler: str | None = typer.Option(None, help="Reverse kernel: ddim, ddpm or dpm "
                                       "(DPM-Solver++ 2M, for few steps: --sampler dpm --steps "
                                       "5; docs/benchmarks.md).", show_default="the policy's"),
    surrogate: bool = typer.Option(False, help="Evaluate spatial costs with the MLP surrogate."),
    threads: int = typer.Option(1, min=1, max=256, help="Torch CPU threads (1 is fastest on "
                                "small machines)."),
    device: DeviceOption = "auto",
    change: str | None = typer.Option(None, help="The teammate becomes another one at a cycle: "
                                      "NAME@CYCLE[,NAME@CYCLE...], e.g. slow-outside@12."),
    drift: float = typer.Option(0.0, help="The teammate's durations grow by this fraction per "
                                "cycle (negative: practice)."),
    drift_from: int = typer.Option(0, help="Cycle the drift starts at."),
    forgetting: float = typer.Option(_D["forgetting"].default, help="Forgetting factor of the "
                                     "models in (0, 1]; 1 is the paper's."),
    detect: bool = typer.Option(False, help="Detect changes of the teammate and restart the "
                                "beliefs of the tasks that changed."),
    hazard: float = typer.Option(_D["hazard"].default, help="Prior probability of a change at "
                                 "one observation (with --detect)."),
    ask: bool = typer.Option(False, help="On a detected change, ask the teammate (a simulated "
                             "one answers truthfully); a denial keeps the belief."),
    whole_person: bool = typer.Option(False, help="With --detect: a change seen on some tasks "
                                      "moves the beliefs of the others by the same ratio "
                                      "(fatigue, practice); with --ask, if the teammate agrees."),
    reexplore: int = typer.Option(0, help="Cycles planned with lambda again after a detected "
                                  "change."),
    execution: str = typer.Option(_D["execution"].default, help="Inside the cycle: planned (the "
                                  "paper: the robot follows its plan) or reactive (speed and "
                                  "separation monitoring, re-planning on deviations)."),
    reacts: bool = typer.Option(False, help="The simulated person slows down or pauses when "
                                "the moving robot comes close (with --comfort or --gamma learn: "
                                "at distances set by their own gamma)."),
    gamma_reactions: bool = typer.Option(_D["gamma_reactions"].default, help="With --reacts: "
                                         "the person's reactions are evidence about their "
                                         "gamma too (else only what they say)."),
    deviate: float = typer.Option(0.0, help="Probability per cycle that the simulated person "
                                  "deviates from the plan (another order, a pause, a robot "
                                  "task taken)."),
    slowdowns: str | None = typer.Option(None, help="With --execution reactive: plan for the "
                                         "safety monitor's slowdowns, learned (the prediction "
                                         "corrected by what it really cost), predicted, or off "
                                         "(the paper's open-loop plan).",
                                         show_default="learned under reactive execution"),
    slowdown_mean: float = typer.Option(_D["slowdown_mean"].default, help="Prior mean of the "
                                        "learned correction of predicted slowdowns (a factor)."),
    slowdown_sd: float = typer.Option(_D["slowdown_sd"].default, help="Prior spread of that "
                                      "correction."),
) -> None:
    """Run the adaptive loop with a simulated teammate: plan, deploy, learn, every cycle."""
    if resume and out is None:
        fail("--resume needs --out (the folder of the run to continue)")
    # every option named after a RunConfig field is that setting (one name, one meaning)
    settings = {k: v for k, v in locals().items() if k in RunConfig.model_fields}
    cfg = RunConfig(**{**settings, **gamma_settings(gamma)})
    from rapidds.loop.run import load_policy
    from rapidds.worlds.registry import make_world

    con = console()
    set_threads(threads)
    w = make_world(cfg.world, cfg.variant)
    run = execute(cfg, load_policy(w, policy, cfg.device), out, resume, as_json, con)
    if not as_json:
        _say_done(run, out, con)


def _say_done(run: AdaptiveRun, out: Path | None, con: Console) -> None:
    """After a run (not with --json): the learned gamma per cycle, and what was written."""
    if run.config.gamma_learn and run.store is not None:
        from rapidds.experiments.report import gamma_markdown, gamma_rows

        con.print("\nlearned gamma (docs/design-notes.md \"Learning each person's gamma\")")
        con.print(gamma_markdown(gamma_rows(run.store.cycle_records(run.config.run_id))),
                  highlight=False)
    if out is not None:
        rid = run.config.run_id
        con.print(f"wrote {out / 'run.sqlite'}, {out / f'{rid}-cost.png'}, "
                  f"{out / f'{rid}-map.png'}, {out / 'gantt'}/")


@app.command("worlds")
def worlds_cmd(
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """List the registered worlds with their variants, teammates and tasks."""
    from rapidds.worlds.registry import make_world, world_names

    info = {}
    for name in world_names():
        w = make_world(name)
        info[name] = {"variants": list(w.variants), "teammates": list(w.teammate_names),
                      "tasks": list(w.task_ids), "workspace_dim": w.workspace_dim,
                      "robot_dim": w.state_dim, "views": list(w.views)}
    if as_json:
        typer.echo(json.dumps(info))
        return
    for name, d in info.items():
        typer.echo(f"{name}: {d['robot_dim']}-D robot in a {d['workspace_dim']}-D workspace")
        typer.echo(f"  variants:  {', '.join(d['variants'])}")
        typer.echo(f"  teammates: {', '.join(d['teammates'])}")
        typer.echo(f"  tasks:     {', '.join(d['tasks'])}")


@app.command("demo")
def demo_cmd(
    out: Path = typer.Option(Path("rapidds-demo"), help="Folder for the results."),
    world: str = typer.Option("fetch", help="World to run in."),
    human: str | None = typer.Option(None, help="Teammate (see 'rapidds worlds').",
                                     show_default="fast-middle in fetch, else the world's first"),
    cycles: int = typer.Option(16, help="Cycles per run."),
    seed: int = typer.Option(0, help="Seed."),
    threads: int = typer.Option(1, min=1, max=256, help="Torch CPU threads (1 is fastest on "
                                "small machines)."),
) -> None:
    """Show adaptation in a few minutes on a laptop CPU: one teammate, full adaptation against
    none, what was learned, what it cost, and the pictures."""
    import numpy as np
    from rich.table import Table

    from rapidds.loop.model import prior_model
    from rapidds.loop.run import load_policy
    from rapidds.store import RunStore
    from rapidds.worlds.registry import make_world

    con = console()
    set_threads(threads)
    w = make_world(world)
    policy = load_policy(w)
    if human is None and world == "fetch":
        human = "fast-middle"
    runs = {}
    for level in ("full", "none"):
        cfg = RunConfig(world=world, human=human, adapt=level, cycles=cycles, seed=seed)
        sub = out / level
        resume = False
        if (sub / "run.sqlite").exists():
            with RunStore.open_readonly(sub / "run.sqlite") as st:
                resume = st.last_cycle(cfg.resolved(w).run_id) is not None
        runs[level] = execute(cfg, policy, sub, resume, False, con,
                              title=f"{human or w.teammate_names[0]}, adaptation: {level}")

    full = runs["full"]
    name = full.config.human
    prior = prior_model(full.world, full.config).temporal.mean()
    learned = full.model.temporal.mean()
    truth = full.world.teammate(str(name)).true_mean_durations()
    t = Table("task", "prior (population)", "learned", "true", "times observed",
              title=f"what full adaptation learned about {name}: mean duration [s]")
    assert full.store is not None
    recs = full.store.cycle_records(full.config.run_id)
    for k, task in enumerate(full.problem.ids):
        if task not in truth:
            continue
        seen = sum(task in r.observed for r in recs)
        t.add_row(task, f"{prior[k]:.2f}", f"{learned[k]:.2f}", f"{truth[task]:.2f}", str(seen))
    con.print(t)

    t = Table("adaptation", "cost, first cycle", "median cost, last 4", "makespan, last 4",
              "spatial, last 4", "min separation, last 4", "robot motions, last 4",
              title=f"teammate {name}: realised cost (makespan + gamma x spatial)")
    for level, run in runs.items():
        assert run.store is not None
        recs = run.store.cycle_records(run.config.run_id)
        tail = [r.realised for r in recs[-min(4, len(recs)):]]
        med = [float(np.median([getattr(r, k) for r in tail]))
               for k in ("cost", "makespan", "spatial", "min_separation")]
        motions = sorted({f"{j}:{m}" for r in recs[-len(tail):] for j, m in r.plan.routes.items()
                          if m != "direct"})
        t.add_row(level, f"{recs[0].realised.cost:.2f}", *(f"{m:.2f}" for m in med),
                  " ".join(motions))
    con.print(t)
    con.print(f"pictures and runs in {out.resolve()}: " + ", ".join(
        f"{lv}/{r.config.run_id}-cost.png {lv}/{r.config.run_id}-map.png {lv}/gantt/"
        for lv, r in runs.items()))
    sys.stdout.flush()
