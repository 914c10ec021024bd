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
from rapidds.cli._options import AS_JSON, POLICY, RUN_OUT_HELP, THREADS, run_settings
from rapidds.loop.config import RunConfig

if TYPE_CHECKING:
    from rich.console import Console

    from rapidds.loop.run import AdaptiveRun, CycleResult
    from rapidds.motion.policy import DiffusionPolicy
    from rapidds.record import CycleRecord

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


_RUN_SETTINGS = tuple(name for name, field in RunConfig.flat_fields().items()
                      if not (isinstance(field.json_schema_extra, dict)
                              and field.json_schema_extra.get("cli") is False))


@app.command("run")
@run_settings(*_RUN_SETTINGS)
def run_cmd(
    settings: dict[str, Any],
    out: Path | None = typer.Option(None, help=RUN_OUT_HELP),
    resume: bool = typer.Option(False, help="Continue the run stored in --out."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object per cycle on "
                                 "stdout."),
    policy: Path | None = POLICY,
    threads: int = THREADS,
) -> None:
    """Run the adaptive loop with a simulated teammate: plan, deploy, learn, every cycle."""
    if resume and out is None:
        fail("--resume needs --out (the folder of the run to continue)")
    cfg = RunConfig(**settings)
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
    as_json: bool = AS_JSON,
) -> None:
    """List the registered worlds with their variants, teammates, tasks, capabilities and the
    policies they ship (--policy NAME)."""
    from rapidds.worlds.base import shipped_policies
    from rapidds.worlds.capabilities import capabilities
    from rapidds.worlds.registry import make_world, world_names

    info = {}
    for name in world_names():
        w = make_world(name)
        info[name] = {"variants": list(w.variants), "teammates": list(w.teammate_names),
                      "tasks": list(w.task_ids), "workspace_dim": w.workspace_dim,
                      "robot_dim": w.state_dim, "views": list(w.views),
                      "capabilities": list(capabilities(w)),
                      "policies": list(shipped_policies(w))}
    if as_json:
        typer.echo(json.dumps(info))
        return
    for name, d in info.items():
        typer.echo(f"{name}: {d['robot_dim']}-D robot in a {d['workspace_dim']}-D workspace")
        typer.echo(f"  variants:  {', '.join(d['variants'])}")
        typer.echo(f"  teammates: {', '.join(d['teammates'])}")
        typer.echo(f"  tasks:     {', '.join(d['tasks'])}")
        typer.echo(f"  can:       {', '.join(d['capabilities']) or '(the contract only)'}")
        typer.echo(f"  policies:  {', '.join(d['policies']) or '(none shipped: train-policy)'}")


@app.command("demo")
@run_settings("world", "human", "cycles", "seed", aliases={"--world": "world"})
def demo_cmd(
    settings: dict[str, Any],
    out: Path = typer.Option(Path("rapidds-demo"), help="Folder for the results."),
    threads: int = THREADS,
) -> None:
    """Show adaptation in a few minutes on a laptop CPU: one teammate (fast-middle in fetch),
    full adaptation against none, what was learned, what it cost, and the pictures."""
    import numpy as np
    from rich.table import Table

    from rapidds.loop.model import prior_model
    from rapidds.loop.run import load_policy
    from rapidds.store import RunStore
    from rapidds.worlds.registry import make_world

    world, human, cycles, seed = (settings[k] for k in ("world", "human", "cycles", "seed"))
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
