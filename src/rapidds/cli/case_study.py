"""``rapidds case-study painting``: the paper's robot case study, its four settings each one
resumable run of the loop, and the table and pictures of every cycle
(:mod:`rapidds.experiments.painting`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from rapidds.cli import app, fail
from rapidds.cli._options import POLICY, THREADS, deprecated, run_settings

if TYPE_CHECKING:
    from rich.console import Console

    from rapidds.experiments.painting import Setting
    from rapidds.motion.policy import DiffusionPolicy
    from rapidds.record import CycleRecord

_STUDIES = ("painting",)
_SETTINGS = "unconstrained-g12,constrained-g12,unconstrained-g25,unconstrained-g85"


@app.command("case-study")
@run_settings("world", "human", "seed", "device", defaults={"world": ..., "human": "left-slow"})
def case_study_cmd(
    settings: dict[str, Any],
    out: Path = typer.Option(..., help="Folder: one sub-folder per setting (run.sqlite, Gantt "
                             "charts, maps, frames, GIF), table.md and table.csv; rerunning "
                             "with the same folder resumes unfinished runs."),
    cycles: int = typer.Option(7, min=1, max=1000, help="Cycles per setting (the paper's 7)."),
    cases: str = typer.Option(_SETTINGS, "--settings", help="The paper's settings to run, "
                              "comma-separated."),
    gif: bool = typer.Option(True, help="Animate the last cycle of each setting (GIF)."),
    executions: str = typer.Option("planned", "--execution", help="Executions each setting "
                                   "runs under, comma-separated: planned (the paper's), or "
                                   "planned,reactive to add a reactive run of each (folder "
                                   "<setting>-reactive) to the table's reactive columns."),
    reactive: bool | None = typer.Option(None, "--reactive", hidden=True),
    as_json: bool = typer.Option(False, "--json", help="One JSON object on stdout (table rows "
                                 "and behaviours); cycle rows go to stderr."),
    threads: int = THREADS,
    policy: Path | None = POLICY,
) -> None:
    """Run the paper's painting settings (unconstrained gamma 12, constrained gamma 12,
    unconstrained gamma 25 and 85) with full adaptation and write the per-cycle table and the
    pictures of each."""
    world, human, seed = (settings[k] for k in ("world", "human", "seed"))
    device = settings["device"]
    if reactive is not None:
        deprecated("--reactive", "--execution planned,reactive")
        executions = "planned,reactive" if reactive else "planned"
    from rapidds.execution.registry import parse_execution

    try:
        entries = [parse_execution(e.strip()) for e in executions.split(",") if e.strip()]
    except ValueError as exc:
        fail(f"--execution: {exc}")
    # the table has the paper's columns and one pair for an execution inside the cycle
    if not entries or entries[0].in_cycle or len(entries) > 2 or not all(
            e.in_cycle for e in entries[1:]):
        fail(f"--execution is planned, or planned and one execution inside the cycle (e.g. "
             f"planned,reactive), got {executions!r}")
    inside = entries[1].kind if len(entries) == 2 else None
    if world not in _STUDIES:
        fail(f"no case study for world {world!r}; case studies: {', '.join(_STUDIES)}")
    from rich.console import Console

    from rapidds.cli.run import console, set_threads
    from rapidds.experiments.painting import (
        check_setting_names,
        table_markdown,
        table_rows,
        write_tables,
    )
    from rapidds.loop.run import load_policy
    from rapidds.worlds.registry import make_world

    chosen = check_setting_names([s.strip() for s in cases.split(",") if s.strip()])
    if not chosen:
        fail("--settings names no setting")
    w = make_world(world)
    if human not in w.teammate_names:
        fail(f"unknown teammate {human!r} for world {world!r}; teammates are "
             f"{', '.join(w.teammate_names)}")
    con = Console(stderr=True, soft_wrap=True) if as_json else console()
    set_threads(threads)
    net = load_policy(w, policy, device)
    runs, reacted = {}, {}
    behaviours = {}
    for setting in chosen:
        runs[setting], behaviours[setting.name] = _run_setting(
            setting, world, human, seed, cycles, out / setting.name, net, gif, con)
        if inside is not None:
            name = f"{setting.name}-{inside}"
            reacted[setting], behaviours[name] = _run_setting(
                setting, world, human, seed, cycles, out / name, net, gif, con,
                execution=inside)
    rows = table_rows(w, human, runs, reacted if inside is not None else None)
    md, cs = write_tables(out, rows)
    if as_json:
        print(json.dumps({"rows": rows, "behaviours": behaviours}), flush=True)
        return
    con.print(table_markdown(rows), highlight=False, markup=False)
    for name, found in behaviours.items():
        for b in found:
            con.print(f"{name}: {b['belief']}: {b['behaviour']}: "
                      f"{'holds' if b['holds'] else 'does not hold'} "
                      f"(shown in cycles {b['shown'] or '-'} of {b['tested']})", highlight=False)
    con.print(f"wrote {md}, {cs} and one folder per setting in {out}", highlight=False)


def _run_setting(setting: Setting, world: str, human: str, seed: int, cycles: int, sub: Path,
                 policy: DiffusionPolicy, gif: bool, con: Console, execution: str = "planned"
                 ) -> tuple[list[CycleRecord], list[dict[str, Any]]]:
    """Run (or resume) one setting under ``execution`` in its folder ``sub`` and draw its last
    cycle; its records and the paper's behaviours tested on them."""
    from rapidds.cli.run import execute
    from rapidds.experiments.painting import save_cycle_gif, save_frames, setting_behaviours
    from rapidds.store import RunStore
    from rapidds.worlds.registry import make_world

    cfg = setting.config(human, seed, cycles, execution)
    rid = cfg.resolved(make_world(world, setting.variant)).run_id
    resume = False
    if (sub / "run.sqlite").exists():
        with RunStore.open_readonly(sub / "run.sqlite") as st:
            resume = st.last_cycle(rid) is not None
    run = execute(cfg, policy, sub, resume, False, con,
                  title=f"{setting.name}{f', {cfg.execution}' * cfg.execution.in_cycle}, "
                        f"teammate {human}, seed {seed}")
    assert run.store is not None
    # closed here, not when the run is collected: its folder lock must go before a rerun in
    # this process (the cycle objects' callbacks keep the run alive until a collection)
    with run.store as store:
        records = store.cycle_records(rid)
        last = records[-1]
        arrays = store.arrays(rid, last.cycle)
    behaviours = [{"behaviour": b.name, "belief": b.belief, "tested": list(b.cycles),
                   "shown": list(b.shown), "holds": b.holds}
                  for b in setting_behaviours(run.world, setting, human, records)]
    save_frames(run.world, last, arrays, sub / rid)
    if gif:
        save_cycle_gif(run.world, last, arrays, sub / f"{rid}-cycle-{last.cycle:02d}.gif")
    return records, behaviours
