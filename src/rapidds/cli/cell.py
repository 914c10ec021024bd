"""``rapidds deploy`` (the planner as the hub of a live cell), ``rapidds sim-robot`` and
``rapidds sim-human`` (the reference nodes a lab replaces with its robot driver and tracker).

Zenoh, MuJoCo and torch are imported inside the commands, so ``--help`` stays fast.
"""

from __future__ import annotations

import json
import logging
import os
import sys
from pathlib import Path

import typer

from rapidds.cli import app, fail
from rapidds.cli._device import DeviceOption
from rapidds.loop.config import ADAPT_LEVELS, RunConfig

_D = RunConfig.model_fields
_ENDPOINT = "tcp/127.0.0.1:7447"


def _logging(quiet: bool) -> None:
    """One line per dropped message or fault on stderr; RAPIDDS_LOG=info adds every event."""
    level = "ERROR" if quiet else os.environ.get("RAPIDDS_LOG", "WARNING").upper()
    logging.basicConfig(level=getattr(logging, level, logging.WARNING), stream=sys.stderr,
                        format="rapidds %(name)s: %(message)s")


@app.command("deploy")
def deploy_cmd(
    world: str = typer.Argument(..., help="World of the cell (see 'rapidds worlds')."),
    bridge: str = typer.Option("zenoh", help="The link to the cell: zenoh."),
    listen: str = typer.Option(_ENDPOINT, help="Endpoint the hub listens on, PROTO/HOST:PORT "
                               "(the nodes' --connect)."),
    cycles: int = typer.Option(_D["cycles"].default, min=1, help="Cycles I."),
    out: Path = typer.Option(..., help="Folder for run.sqlite."),
    resume: bool = typer.Option(False, help="Continue the run stored in --out (after a stop)."),
    as_json: bool = typer.Option(False, "--json", help="Print each cycle's record as one JSON "
                                 "line, as 'rapidds run --json' does, with its 'live' object."),
    variant: str | None = typer.Option(None, help="Variant of the world's job."),
    adapt: str = typer.Option(_D["adapt"].default, help=f"Adaptation: {', '.join(ADAPT_LEVELS)}."),
    seed: int = typer.Option(_D["seed"].default, help="Seed; the same seed plans the same."),
    policy: Path | None = typer.Option(None, help="Policy checkpoint (default: bundled)."),
    population: int = typer.Option(_D["population"].default, help="GA population C."),
    generations: int = typer.Option(_D["generations"].default, help="GA generations G."),
    samples: int = typer.Option(_D["samples"].default, help="Monte-Carlo duration samples K."),
    particles: int = typer.Option(_D["particles"].default, help="Steered samples per request."),
    candidates: int = typer.Option(_D["candidates"].default, help="SVDD candidates M per step."),
    execution: str = typer.Option("planned", help="planned: the robot follows its plan; "
                                  "reactive: the hub monitors speed and separation and sends "
                                  "the robot a speed scaling on /rapidds/robot/speed_scaling."),
    time_scale: float = typer.Option(1.0, help="Cell seconds per wall second, sent to the "
                                     "nodes (> 1 runs simulated nodes faster; a real cell: 1)."),
    robot_timeout: float = typer.Option(2.0, help="Wall seconds without joint states before "
                                        "the robot counts as silent."),
    startup_timeout: float = typer.Option(60.0, help="Wall seconds to wait for the nodes."),
    cycle_timeout: float = typer.Option(120.0, help="Cell seconds a cycle may take."),
    threads: int = typer.Option(1, min=1, max=256, help="Torch CPU threads."),
    device: DeviceOption = "auto",
    quiet: bool = typer.Option(False, help="Log faults only, not dropped messages."),
) -> None:
    """Run the adaptive loop in a live cell: this process is the hub the nodes connect to; each
    cycle is planned here, executed by the robot and the person, observed, learned, recorded.

    Start 'rapidds sim-robot' and 'rapidds sim-human' (or a real robot driver and tracker) with
    --connect to this hub's --listen. A cycle stopped by a fault (a silent robot, an overrun) is
    not recorded and the hub exits with code 3; --resume continues the run."""
    if bridge != "zenoh":
        fail(f"unknown --bridge {bridge!r}; the live link is zenoh")
    if execution not in ("planned", "reactive"):
        fail(f"unknown --execution {execution!r}; one of planned, reactive")
    if not (time_scale > 0 and robot_timeout > 0 and startup_timeout > 0 and cycle_timeout > 0):
        fail("--time-scale and the timeouts must be > 0")
    from rapidds.bridge.cell import CellFault, CellOptions, LinkTeammate, LiveCell, hub_topics
    from rapidds.bridge.link import Link, check_endpoint
    from rapidds.cli.run import set_threads
    from rapidds.loop.run import AdaptiveRun, CycleResult, load_policy
    from rapidds.store import RunStore
    from rapidds.worlds.base import body_point_names
    from rapidds.worlds.registry import make_world

    check_endpoint(listen)
    _logging(quiet)
    set_threads(threads)
    cfg = RunConfig(world=world, variant=variant, human="live", adapt=adapt, cycles=cycles,
                    seed=seed, population=population, generations=generations,
                    samples=samples, particles=particles, candidates=candidates,
                    execution=execution, device=device)
    w = make_world(cfg.world, cfg.variant)
    store = RunStore(out / "run.sqlite", lock_as="rapidds deploy")
    run = AdaptiveRun(cfg, load_policy(w, policy, cfg.device), store, world=w,
                      teammate=LinkTeammate())
    if run.next_cycle and not resume:
        fail(f"{out} already holds run '{run.config.run_id}' ({run.next_cycle} cycles); pass "
             "--resume to continue it or choose another --out")
    if run.finished:
        typer.echo(f"run '{run.config.run_id}' in {out} is already finished "
                   f"({run.config.cycles} cycles); nothing to run", err=True)
        return
    options = CellOptions(time_scale=time_scale, robot_timeout=robot_timeout,
                          startup_timeout=startup_timeout, cycle_timeout=cycle_timeout,
                          execution=execution)

    def on_cycle(res: CycleResult, live: dict) -> None:
        rec = res.record
        if as_json:
            print(json.dumps(rec.to_json(), allow_nan=False), flush=True)  # its "live" included
        else:
            robot = ", ".join(f"{t} {d:.2f} s" for t, d in live["robot_durations"].items())
            human = ", ".join(f"{t} {d:.2f} s" for t, d in rec.observed.items())
            typer.echo(f"cycle {rec.cycle}: makespan {rec.realised.makespan:.2f} s; "
                       f"person {human}; robot {robot}; contacts {len(live['contacts'])}")

    with Link(hub_topics(body_point_names(w)), listen=listen) as link:
        try:
            LiveCell(run, link, options).run_all(on_cycle)
        except CellFault as exc:
            typer.echo(f"rapidds: error: {exc}", err=True)
            raise typer.Exit(3) from None


@app.command("sim-robot")
def sim_robot_cmd(
    world: str = typer.Argument(..., help="World whose robot to simulate (painting)."),
    connect: str = typer.Option(_ENDPOINT, help="The hub's endpoint (rapidds deploy --listen)."),
    rate: float = typer.Option(100.0, min=1.0, help="Joint states per simulated second."),
    quiet: bool = typer.Option(False, help="Log faults only."),
) -> None:
    """The reference robot: runs received joint trajectories in MuJoCo under physics, publishes
    joint states, its task events and touches on the person. Waits for the hub, follows it
    across restarts, runs until stopped."""
    from rapidds.bridge.link import Link
    from rapidds.bridge.nodes.sim_robot import SimRobot
    from rapidds.worlds.base import body_point_names
    from rapidds.worlds.registry import make_world

    _logging(quiet)
    w = make_world(world)
    if getattr(w, "physics_model", None) is None:  # before waiting for the hub
        fail(f"world {w.name} has no physics model; sim-robot runs a world that offers one "
             "(painting)")
    with Link(SimRobot.topics(body_point_names(w)), connect=connect) as link:
        SimRobot(w, link, rate=rate).spin()


@app.command("sim-human")
def sim_human_cmd(
    world: str = typer.Argument(..., help="World of the cell (see 'rapidds worlds')."),
    human: str = typer.Option(..., help="Simulated teammate, by the world's name for it."),
    connect: str = typer.Option(_ENDPOINT, help="The hub's endpoint (rapidds deploy --listen)."),
    seed: int = typer.Option(0, help="Seed of the person's draws (with the cycle)."),
    quiet: bool = typer.Option(False, help="Log faults only."),
) -> None:
    """The reference person: does their tasks of each received plan in real time, publishing
    task events and tracked body points. Waits for the hub, follows it across restarts, runs
    until stopped."""
    from rapidds.bridge.link import Link
    from rapidds.bridge.nodes.sim_human import SimHuman
    from rapidds.worlds.registry import make_world

    _logging(quiet)
    w = make_world(world)
    if human not in w.teammate_names:
        fail(f"unknown human '{human}' for world {w.name}; one of {', '.join(w.teammate_names)}")
    with Link(SimHuman.topics(), connect=connect) as link:
        SimHuman(w, w.teammate(human), link, seed=seed).spin()
