"""``rapidds run`` (the multi-cycle loop with a simulated teammate) and ``rapidds demo``."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from rapidds.bundled import fetch_policy_dir
from rapidds.cli import app, fail
from rapidds.errors import CheckpointError
from rapidds.loop import ADAPT_LEVELS, AdaptiveRun, CycleResult, RunConfig
from rapidds.motion.policy import DiffusionPolicy
from rapidds.store import RunStore
from rapidds.worlds.teammates import ARCHETYPES

_D = RunConfig()


def _console() -> Console:
    """stdout console; piped output gets a width that fits the tables instead of 80 columns."""
    probe = Console()
    return Console(soft_wrap=True, width=None if probe.is_terminal else 160)


def set_threads(threads: int) -> None:
    """The networks are small: one thread per process beats several fighting over 2 cores."""
    import torch

    if threads < 1:
        fail(f"--threads must be >= 1, got {threads}")
    torch.set_num_threads(threads)


def load_policy(path: Path | None) -> DiffusionPolicy:
    """The given checkpoint, or the bundled fetch policy."""
    directory = path or fetch_policy_dir()
    if path is None and not directory.is_dir():
        raise CheckpointError(
            "no bundled fetch policy in this install; train one with "
            "'rapidds train-policy --world fetch --out DIR' and pass --policy DIR"
        )
    return DiffusionPolicy.load(directory, device="cpu")


def _cycle_row(rec: dict[str, Any]) -> list[str]:
    routes = ",".join(f"{j}:{m[0]}" for j, m in sorted(rec["routes"].items()) if m != "direct")
    e, r = rec["expected"], rec["realised"]
    return [
        str(rec["cycle"]), f"{rec['lambda']:g}", " ".join(rec["human"]), " ".join(rec["robot"]),
        routes or "-", f"{e['makespan'] + rec['gamma'] * e['spatial']:.2f}",
        f"{r['makespan']:.2f}", f"{r['spatial']:.2f}", f"{r['cost']:.2f}",
        f"{r['min_separation']:.2f}", f"{rec['seconds']['total']:.1f}",
    ]


_HEADER = ["cycle", "λ", "human", "robot", "routes", "exp.cost", "makespan", "spatial",
           "cost", "min.sep", "s"]
_WIDTHS = [5, 4, 18, 18, 12, 8, 8, 7, 7, 7, 5]


def _line(cells: list[str]) -> str:
    return "  ".join(c.rjust(w) if k not in (2, 3, 4) else c.ljust(w)
                     for k, (c, w) in enumerate(zip(cells, _WIDTHS, strict=True)))


def write_pictures(run: AdaptiveRun, out: Path) -> list[Path]:
    """Cost curve over all stored cycles, and the map of the latest cycle."""
    from rapidds.plots.curves import plot_run_costs
    from rapidds.plots.run import save_cycle_map

    assert run.store is not None
    records = run.store.records(run.config.run_id)
    written = []
    if records:
        written.append(plot_run_costs(records, out / "cost.png", run.config.exploration_end))
        rec = records[-1]
        arrays = run.store.arrays(run.config.run_id, rec["cycle"])
        world = run.world
        written.append(save_cycle_map(
            run.model.spatial, out / "map.png",
            human_paths={k.split("/", 1)[1]: v for k, v in arrays.items()
                         if k.startswith("human/")},
            robot_paths={k.split("/", 1)[1]: v for k, v in arrays.items()
                         if k.startswith("robot/")},
            overlaps=rec["realised"]["overlaps"],
            walls=world.obstacles(), points=world.points_of_interest(),
            title=f"{run.config.run_id}, cycle {rec['cycle']}: learned spatial cost, "
                  "human (gold) and concurrent robot (blue) paths",
        ))
    return written


def execute(
    cfg: RunConfig, policy: DiffusionPolicy, out: Path | None, resume: bool, as_json: bool,
    console: Console, title: str | None = None,
) -> AdaptiveRun:
    """Run (or resume) one configuration, printing a row or a JSON line per cycle."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from rapidds.plots.gantt import save_gantt

    store = RunStore(out / "run.sqlite", lock_as="rapidds run") if out is not None else None
    if store is not None:
        done = store.last_cycle(cfg.run_id)
        if done is not None and not resume:
            fail(f"{out} already holds run '{cfg.run_id}' ({done + 1} cycles); "
                 "pass --resume to continue it or choose another --out")
    run = AdaptiveRun(cfg, policy, store)
    err = Console(stderr=True)
    if not as_json:
        console.print(f"[bold]{title or cfg.run_id}[/bold]")
        console.print(_line(_HEADER), highlight=False)
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("{task.fields[info]}"), console=err, transient=True,
                  disable=not err.is_terminal) as bar:
        task = bar.add_task(cfg.run_id, total=cfg.cycles, completed=run.next_cycle, info="")

        def on_cycle(res: CycleResult) -> None:
            rec = res.record
            if as_json:
                print(json.dumps(rec, allow_nan=False), flush=True)
            else:
                console.print(_line(_cycle_row(rec)), highlight=False)
            if out is not None:
                save_gantt(res.deployment.timeline, out / "gantt" / f"cycle-{rec['cycle']:02d}.png",
                           title=f"{cfg.run_id} cycle {rec['cycle']} (realised)")
            bar.update(task, advance=1, info=f"cost {rec['realised']['cost']:.2f}")

        try:
            run.run(on_cycle)
        except KeyboardInterrupt:
            err.print(f"interrupted after cycle {run.next_cycle - 1}; every finished cycle is "
                      f"stored{'; continue with --resume' if out else ''}")
            raise typer.Exit(130) from None
    if out is not None:
        write_pictures(run, out)
    return run


@app.command("run")
def run_cmd(
    world: str = typer.Argument("fetch", help="World to run in (bundled: fetch)."),
    human: str = typer.Option(_D.human, help=f"Teammate: {', '.join(ARCHETYPES)}."),
    cycles: int = typer.Option(_D.cycles, help="Cycles I."),
    adapt: str = typer.Option(_D.adapt, help=f"Adaptation: {', '.join(ADAPT_LEVELS)}."),
    seed: int = typer.Option(_D.seed, help="Seed; the same seed gives the same run."),
    gamma: float = typer.Option(_D.gamma, help="Proximity weight."),
    lam: float = typer.Option(_D.lam, help="Diversity weight for the first half of the cycles."),
    out: Path | None = typer.Option(None, help="Folder for run.sqlite and the pictures."),
    resume: bool = typer.Option(False, help="Continue the run stored in --out."),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per cycle on stdout."),
    policy: Path | None = typer.Option(None, help="Policy checkpoint (default: bundled)."),
    population: int = typer.Option(_D.population, help="GA population C."),
    generations: int = typer.Option(_D.generations, help="GA generations G."),
    samples: int = typer.Option(_D.samples, help="Monte-Carlo duration samples K."),
    particles: int = typer.Option(_D.particles, help="Steered samples per motion request."),
    candidates: int = typer.Option(_D.candidates, help="SVDD candidates M per step."),
    surrogate: bool = typer.Option(False, help="Evaluate spatial costs with the MLP surrogate."),
    threads: int = typer.Option(1, help="Torch CPU threads (1 is fastest on small machines)."),
) -> None:
    """Run the adaptive loop with a simulated teammate: plan, deploy, learn, every cycle."""
    if resume and out is None:
        fail("--resume needs --out (the folder of the run to continue)")
    cfg = RunConfig(human=human, adapt=adapt, cycles=cycles, gamma=gamma, lam=lam, seed=seed,
                    population=population, generations=generations, samples=samples,
                    particles=particles, candidates=candidates, surrogate=surrogate, world=world)
    console = _console()
    set_threads(threads)
    execute(cfg, load_policy(policy), out, resume, as_json, console)
    if out is not None and not as_json:
        console.print(f"wrote {out / 'run.sqlite'}, {out / 'cost.png'}, {out / 'map.png'}, "
                      f"{out / 'gantt'}/")


@app.command("demo")
def demo_cmd(
    out: Path = typer.Option(Path("rapidds-demo"), help="Folder for the results."),
    human: str = typer.Option("fast-middle", help=f"Teammate: {', '.join(ARCHETYPES)}."),
    cycles: int = typer.Option(16, help="Cycles per run."),
    seed: int = typer.Option(0, help="Seed."),
    threads: int = typer.Option(1, help="Torch CPU threads (1 is fastest on small machines)."),
) -> None:
    """Show adaptation in about a minute on a laptop CPU: one teammate, full adaptation against
    none, what was learned, what it cost, and the pictures."""
    from rapidds.loop import prior_model

    console = _console()
    set_threads(threads)
    policy = load_policy(None)
    runs = {}
    for level in ("full", "none"):
        cfg = RunConfig(human=human, adapt=level, cycles=cycles, seed=seed)
        sub = out / level
        resume = False
        if (sub / "run.sqlite").exists():
            with RunStore.open_readonly(sub / "run.sqlite") as st:
                resume = st.last_cycle(cfg.run_id) is not None
        runs[level] = execute(cfg, policy, sub, resume, False, console,
                              title=f"{human}, adaptation: {level}")

    full = runs["full"]
    prior = prior_model(full.world, full.problem, full.config).temporal.mean()
    learned = full.model.temporal.mean()
    truth = full.teammate.true_mean_durations()
    t = Table("task", "prior (population)", "learned", "true", "times observed",
              title=f"what full adaptation learned about {human}: mean duration [s]")
    assert full.store is not None
    recs = full.store.records(full.config.run_id)
    for k, task in enumerate(full.problem.ids):
        seen = sum(task in r["observed"] for r in recs)
        t.add_row(task, f"{prior[k]:.2f}", f"{learned[k]:.2f}", f"{truth[task]:.2f}", str(seen))
    console.print(t)

    t = Table("adaptation", "cost, first cycle", "median cost, last 4", "makespan, last 4",
              "spatial, last 4", "min separation, last 4", "robot routes, last 4",
              title=f"teammate {human}: realised cost (makespan + gamma x spatial)")
    for level, run in runs.items():
        assert run.store is not None
        recs = run.store.records(run.config.run_id)
        tail = recs[-min(4, len(recs)):]
        med = [float(np.median([r["realised"][k] for r in tail]))
               for k in ("cost", "makespan", "spatial", "min_separation")]
        routes = sorted({f"{j}:{m}" for r in tail for j, m in r["routes"].items()
                         if m != "direct"})
        t.add_row(level, f"{recs[0]['realised']['cost']:.2f}", *(f"{m:.2f}" for m in med),
                  " ".join(routes))
    console.print(t)
    console.print(f"pictures and runs in {out.resolve()}: "
                  + ", ".join(f"{lv}/cost.png {lv}/map.png {lv}/gantt/" for lv in runs))
    sys.stdout.flush()
