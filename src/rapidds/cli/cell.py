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
from typing import TYPE_CHECKING, Any

import typer

from rapidds.cli import app, fail
from rapidds.cli._options import POLICY, ROBOT, SEARCH, THREADS, run_settings
from rapidds.loop.config import RunConfig

if TYPE_CHECKING:
    from rapidds.bridge.cell import CellOptions
    from rapidds.bridge.link import Link
    from rapidds.bridge.profiles import RobotProfile
    from rapidds.bridge.wire import Wire
    from rapidds.bridge.zenoh_config import LinkConfig
    from rapidds.worlds.base import World

_ENDPOINT = "tcp/127.0.0.1:7447"
_CONNECT = typer.Option(_ENDPOINT, help="The hub's endpoint (rapidds deploy --listen).")


def _logging(quiet: bool) -> None:
    """One line per dropped message or fault on stderr; RAPIDDS_LOG=info adds every event."""
    level = "ERROR" if quiet else os.environ.get("RAPIDDS_LOG", "WARNING").upper()
    logging.basicConfig(level=getattr(logging, level, logging.WARNING), stream=sys.stderr,
                        format="rapidds %(name)s: %(message)s")


def _zenoh_config_option() -> Any:
    return typer.Option(None, "--zenoh-config", help="Zenoh config file (JSON5, Zenoh's keys): "
                        "mutual TLS (transport/link/tls) and, on the hub, access control; "
                        "README 'In a real cell'. Default: plain TCP, localhost.")


def _wire_option() -> Any:
    return typer.Option("ros2dds", "--wire", help="Keys and framing on the link: ros2dds "
                        "(zenoh-bridge-ros2dds's keys) or rmw-zenoh (rmw_zenoh's keys, "
                        "attachments and liveliness tokens, domain ROS_DOMAIN_ID).")


def _wire(name: str, node: str) -> Wire:
    from rapidds.bridge.wire import make_wire

    return make_wire(name, node)


def _link_config(path: Path | None, role: str, endpoint: str) -> LinkConfig | None:
    from rapidds.bridge.zenoh_config import checked_link_config

    return checked_link_config(path, role, endpoint)


@app.command("deploy")
@run_settings("world", "variant", "adapt", "cycles", "seed", *SEARCH, "execution", "device",
              defaults={"world": ...})
def deploy_cmd(
    settings: dict[str, Any],
    bridge: str = typer.Option("zenoh", help="The link to the cell: zenoh."),
    listen: str = typer.Option(_ENDPOINT, help="Endpoint the hub listens on, PROTO/HOST:PORT "
                               "(the nodes' --connect)."),
    out: Path = typer.Option(..., help="Folder for run.sqlite."),
    resume: bool = typer.Option(False, help="Continue the run stored in --out (after a stop)."),
    as_json: bool = typer.Option(False, "--json", help="Print each cycle's record as one JSON "
                                 "line, as 'rapidds run --json' does, with its 'live' object."),
    policy: Path | None = POLICY,
    time_scale: float = typer.Option(1.0, help="Cell seconds per wall second, sent to the "
                                     "nodes (> 1 runs simulated nodes faster; a real cell: 1)."),
    robot_timeout: float = typer.Option(2.0, help="Wall seconds without joint states before "
                                        "the robot counts as silent."),
    startup_timeout: float = typer.Option(60.0, help="Wall seconds to wait for the nodes."),
    cycle_timeout: float = typer.Option(120.0, help="Cell seconds a cycle may take."),
    threads: int = THREADS,
    robot: str = ROBOT,
    quiet: bool = typer.Option(False, help="Log faults only, not dropped messages."),
    zenoh_config: Path | None = _zenoh_config_option(),
    wire: str = _wire_option(),
) -> None:
    """Run the adaptive loop in a live cell: this process is the hub the nodes connect to; each
    cycle is planned here, executed by the robot and the person, observed, learned, recorded.

    Start 'rapidds sim-robot' and 'rapidds sim-human' (or a real robot driver and tracker) with
    --connect to this hub's --listen. A cycle stopped by a fault (a silent robot, an overrun) is
    not recorded and the hub exits with code 3; --resume continues the run."""
    if bridge != "zenoh":
        fail(f"unknown --bridge {bridge!r}; the live link is zenoh")
    if not (time_scale > 0 and robot_timeout > 0 and startup_timeout > 0 and cycle_timeout > 0):
        fail("--time-scale and the timeouts must be > 0")
    from rapidds.bridge.cell import CellOptions, hub_topics
    from rapidds.bridge.link import Link, check_endpoint
    from rapidds.bridge.profiles import robot_profile
    from rapidds.cli.run import set_threads
    from rapidds.errors import RapiddsError
    from rapidds.worlds.base import body_point_names
    from rapidds.worlds.registry import make_world

    check_endpoint(listen)
    config = _link_config(zenoh_config, "hub", listen)
    hub_wire = _wire(wire, "rapidds_hub")
    _logging(quiet)
    set_threads(threads)
    cfg = RunConfig(**settings, human="live")
    w = make_world(cfg.world, cfg.variant)
    try:
        profile = robot_profile(robot)
        profile.limits(w)  # one that does not fit the world: one line before anything starts
    except RapiddsError as exc:
        fail(str(exc))
    # the link first: a busy port is said before the store exists (no empty run.sqlite)
    with Link(hub_topics(body_point_names(w)), listen=listen, watch=True,
              config=config, wire=hub_wire) as link:
        _deploy(cfg, w, link, out, policy, resume, as_json, CellOptions(
            time_scale=time_scale, robot_timeout=robot_timeout, startup_timeout=startup_timeout,
            cycle_timeout=cycle_timeout), profile)


def _deploy(cfg: RunConfig, w: World, link: Link, out: Path, policy: Path | None, resume: bool,
            as_json: bool, options: CellOptions, profile: RobotProfile) -> None:
    """The hub's run on an open ``link``: the store, the loop, a line or a record per cycle."""
    from rapidds.bridge.cell import CellFault, LinkTeammate, LiveCell
    from rapidds.loop.run import AdaptiveRun, CycleResult, load_policy
    from rapidds.store import RunStore

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

    def on_cycle(res: CycleResult, live: dict) -> None:
        rec = res.record
        if as_json:
            print(json.dumps(rec.to_json(), allow_nan=False), flush=True)  # its "live" included
        else:
            robot = ", ".join(f"{t} {d:.2f} s" for t, d in live["robot_durations"].items())
            human = ", ".join(f"{t} {d:.2f} s" for t, d in rec.observed.items())
            typer.echo(f"cycle {rec.cycle}: makespan {rec.realised.makespan:.2f} s; "
                       f"person {human}; robot {robot}; contacts {len(live['contacts'])}")

    try:
        LiveCell(run, link, options, profile).run_all(on_cycle)
    except CellFault as exc:
        typer.echo(f"rapidds: error: {exc}", err=True)
        raise typer.Exit(3) from None


@app.command("sim-robot")
def sim_robot_cmd(
    world: str = typer.Argument(..., help="World whose robot to simulate (painting)."),
    connect: str = _CONNECT,
    rate: float = typer.Option(100.0, min=1.0, help="Joint states per simulated second."),
    robot: str = typer.Option("reference", "--robot", help="Robot profile whose driver it "
                              "plays: joint names and offsets on the wire."),
    quiet: bool = typer.Option(False, help="Log faults only."),
    zenoh_config: Path | None = _zenoh_config_option(),
    wire: str = _wire_option(),
) -> None:
    """The reference robot: runs received joint trajectories in MuJoCo under physics, publishes
    joint states, its task events and touches on the person. Waits for the hub, follows it
    across restarts, runs until stopped."""
    from rapidds.bridge.link import Link
    from rapidds.bridge.nodes.sim_robot import SimRobot
    from rapidds.bridge.profiles import robot_profile
    from rapidds.errors import RapiddsError
    from rapidds.worlds.base import body_point_names
    from rapidds.worlds.capabilities import capability, lacks
    from rapidds.worlds.registry import make_world

    _logging(quiet)
    w = make_world(world)
    if capability(w, "physics") is None:  # before waiting for the hub
        fail(lacks(w, "physics"))
    try:
        profile = robot_profile(robot)
        profile.joint_names(w)
    except RapiddsError as exc:
        fail(str(exc))
    with Link(SimRobot.topics(body_point_names(w)), connect=connect, alive="robot",
              config=_link_config(zenoh_config, "node", connect),
              wire=_wire(wire, "rapidds_robot")) as link:
        SimRobot(w, link, rate=rate, profile=profile).spin()


@app.command("sim-human")
def sim_human_cmd(
    world: str = typer.Argument(..., help="World of the cell (see 'rapidds worlds')."),
    human: str = typer.Option(..., help="Simulated teammate, by the world's name for it."),
    connect: str = _CONNECT,
    seed: int = typer.Option(0, help="Seed of the person's draws (with the cycle)."),
    quiet: bool = typer.Option(False, help="Log faults only."),
    zenoh_config: Path | None = _zenoh_config_option(),
    wire: str = _wire_option(),
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
    with Link(SimHuman.topics(), connect=connect, alive="person",
              config=_link_config(zenoh_config, "node", connect),
              wire=_wire(wire, "rapidds_person")) as link:
        SimHuman(w, w.teammate(human), link, seed=seed).spin()
