"""``rapidds export`` (a stored run's cycles as an MCAP rosbag2 bag) and ``rapidds observe`` (a
cycle recorded in a real cell, from a bag, learned and recorded as the run's next cycle).

The messages and the contract are :mod:`rapidds.bridge`'s; README, "In a real cell".
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from rapidds.cli import app, fail
from rapidds.cli._device import DeviceOption
from rapidds.cli._options import AS_JSON, POLICY, ROBOT, RUN_ID, THREADS
from rapidds.errors import RapiddsError

if TYPE_CHECKING:
    from rapidds.record import CycleRecord

STORE = "run.sqlite"
_EPOCH = "Unix seconds or ISO 8601 with a zone."


def log_to_stderr() -> None:
    """The bridge's one-line warnings (dropped messages) on stderr, as ``rapidds: warning``."""
    logger = logging.getLogger("rapidds.bridge")
    if not logger.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("rapidds: warning: %(message)s"))
        logger.addHandler(handler)
        logger.propagate = False


@app.command("export")
def export_cmd(
    run_dir: Annotated[Path, typer.Argument(help="Folder of a stored run (its run.sqlite).")],
    out: Annotated[Path, typer.Option("--out", help="MCAP file to write (not overwritten).")],
    cycle: Annotated[int | None, typer.Option(help="Export this cycle only.",
                                              show_default="every stored cycle")] = None,
    run: str | None = RUN_ID,
    robot: str = ROBOT,
    epoch: Annotated[str | None, typer.Option(
        help=f"Bag time of the first exported cycle's start: {_EPOCH}",
        show_default="the run's recorded wall-clock start")] = None,
    as_json: bool = AS_JSON,
) -> None:
    """Write a stored run's cycles as ROS 2 messages in an MCAP rosbag2 bag: each robot task's
    JointTrajectory (cut to its task, time-parameterized within the robot's limits), the
    schedule, the person's paths and the learned spatial costs."""
    from rapidds.bridge.export import export_run, parse_epoch
    from rapidds.bridge.profiles import robot_profile
    from rapidds.store import RunStore
    from rapidds.worlds.registry import make_world

    try:
        profile = robot_profile(robot)
        epoch_ns = None if epoch is None else parse_epoch(epoch)
        with RunStore.open_readonly(run_dir / STORE) as store:
            rid = store.pick_run(run)
            cfg = store.run_config(rid) or {}
            world = make_world(cfg["world"], cfg.get("variant"))
            cycles = None if cycle is None else [cycle]
            path, count = export_run(store, rid, world, out, cycles, epoch_ns, profile)
    except RapiddsError as exc:
        fail(str(exc))
        return
    if as_json:
        typer.echo(json.dumps({"out": str(path), "run": rid, "messages": count,
                               "cycles": cycles}))
    else:
        typer.echo(f"wrote {path}: {count} messages of run '{rid}'"
                   + ("" if cycle is None else f", cycle {cycle}"))


def _new_config(config: Path) -> Any:
    """The RunConfig of a YAML or JSON file of its fields."""
    from rapidds.loop.config import RunConfig
    from rapidds.settings import read_yaml

    return RunConfig(**read_yaml(config, "--config"))


def observe_cycle(run_dir: Path, bag: Path, mapping: Path | None, config: Path | None,
                  run_id: str | None, policy: Path | None,
                  comfort: int | None = None, body_id: str | None = None,
                  device: str = "auto") -> CycleRecord:
    """Plan the run's next cycle, realise it with what the bag recorded (and the person's
    ``comfort`` answer, 1-7), learn and record it; the cycle's record."""
    from rapidds.bridge.recorded import (
        BagSource,
        RecordedTeammate,
        default_mapping,
        load_mapping,
        read_cycle,
    )
    from rapidds.loop.config import RunConfig
    from rapidds.loop.run import AdaptiveRun, load_policy
    from rapidds.store import RunStore
    from rapidds.worlds.registry import make_world

    path = run_dir / STORE
    ids: list[str] = []
    if path.exists():
        with RunStore.open_readonly(path) as store:
            ids = store.run_ids()
            stored = store.run_config(store.pick_run(run_id)) if ids else None
    if not ids and config is None:
        raise RapiddsError(f"{run_dir} holds no run; start one with --config RUN.yaml "
                           "(run settings: world, cycles, seed, ...)")
    # --config names the run (a new one, or the stored one with the same settings: the run
    # checks them when it attaches to the store)
    cfg = _new_config(config) if config is not None else RunConfig(**(stored or {}))
    world = make_world(cfg.world, cfg.variant)
    if ids and (rid := cfg.resolved(world).run_id) not in ids:
        raise RapiddsError(f"{run_dir} holds run(s) {', '.join(ids)}, not '{rid}' of --config; "
                           "observe into another folder")
    maps = default_mapping(world) if mapping is None else load_mapping(mapping).check(world)
    if body_id is not None:
        maps = maps.replace(body_id=body_id)
    recorded = read_cycle(bag, world, maps)
    waiting = set() if maps.boundaries is None else maps.boundaries.unordered()
    if "human" not in waiting and not any(a == "human" for a, _, _ in recorded.tasks.values()):
        raise RapiddsError(f"{bag}: no complete human task (start and end events on "
                           "/rapidds/events, or by the mapping's boundaries) to learn from")
    # the store is written only now, with a usable bag in hand
    with RunStore(path, lock_as="rapidds observe") as store:
        run = AdaptiveRun(cfg, load_policy(world, policy, device), store, world,
                          teammate=RecordedTeammate())
        return run.step(BagSource(recorded, world, maps, comfort)).record


@app.command("observe")
def observe_cmd(
    run_dir: Annotated[Path, typer.Argument(help="Folder of the run (its run.sqlite); the "
                                            "bag becomes its next cycle.")],
    bag: Annotated[Path, typer.Option("--bag", help="Bag of one cycle: a rosbag2 folder, an "
                                      ".mcap or .db3 file, or a ROS 1 .bag.")],
    mapping: Annotated[Path | None, typer.Option(
        help="YAML: tracked frames or topics -> the world's body points, the TF root frame and "
        "its transform into the world frame, task boundary rules.", show_default="the world's")
    ] = None,
    body_id: Annotated[str | None, typer.Option(
        "--body-id", help="The ROS4HRI body whose frames fill {body} in the mapping.",
        show_default="the mapping's, else the first tracked")] = None,
    config: Annotated[Path | None, typer.Option(
        help="YAML of run settings (world, cycles, seed, ...) to start a new run in RUN_DIR.")
    ] = None,
    run: str | None = RUN_ID,
    policy: Path | None = POLICY,
    comfort: Annotated[int | None, typer.Option(
        min=1, max=7, help="The person's agreement with 'the robot came too close to me' "
        "after the cycle (1-7); their 'too close' signals come from the bag "
        "(/rapidds/human/too_close).")] = None,
    threads: int = THREADS,
    device: DeviceOption = "auto",
    as_json: Annotated[bool, typer.Option("--json", help="Print the cycle's record as JSON.")
                       ] = False,
) -> None:
    """Learn from a cycle recorded in a real cell: plan the run's next cycle as usual, realise
    it with the person's task events and tracked body points from a rosbag2 bag, learn and
    record it as a simulated cycle is."""
    import torch

    torch.set_num_threads(threads)
    log_to_stderr()
    try:
        rec = observe_cycle(run_dir, bag, mapping, config, run, policy, comfort, body_id,
                            device)
    except RapiddsError as exc:
        fail(str(exc))
        return
    if as_json:
        typer.echo(json.dumps(rec.to_json(), allow_nan=False))
    else:
        observed = ", ".join(f"{t} {d:.2f} s" for t, d in rec.observed.items())
        typer.echo(f"cycle {rec.cycle} recorded in {run_dir / STORE}: makespan "
                   f"{rec.realised.makespan:.2f} s, observed {observed}")


@app.command("plan-next")
def plan_next_cmd(
    run_dir: Annotated[Path, typer.Argument(help="Folder of the run (its run.sqlite; only "
                                            "read).")],
    out: Annotated[Path, typer.Option("--out", help="MCAP file to write the plan to (not "
                                      "overwritten).")],
    config: Annotated[Path | None, typer.Option(
        help="YAML of run settings, to plan the first cycle of a new run in RUN_DIR.")] = None,
    run: str | None = RUN_ID,
    policy: Path | None = POLICY,
    robot: str = ROBOT,
    epoch: Annotated[str | None, typer.Option(
        help=f"Bag time of the cycle's start: {_EPOCH}",
        show_default="now")] = None,
    threads: int = THREADS,
    as_json: Annotated[bool, typer.Option("--json", help="Print the plan as JSON.")] = False,
) -> None:
    """Plan a run's next cycle before it runs, for a cell without the live link: write the
    plan and the robot's trajectories (cut to their tasks, time-parameterized within the
    robot's limits) to a bag. Execute it, record the cycle, and give the bag to 'rapidds
    observe', which plans the same cycle and learns it."""
    import time

    import torch

    from rapidds.bridge.export import parse_epoch
    from rapidds.bridge.plan_first import plan_next
    from rapidds.bridge.profiles import robot_profile

    torch.set_num_threads(threads)
    log_to_stderr()
    try:
        profile = robot_profile(robot)
        epoch_ns = time.time_ns() if epoch is None else parse_epoch(epoch)
        cfg = None if config is None else _new_config(config)
        done = plan_next(run_dir, out, profile, epoch_ns, cfg, run, policy)
    except RapiddsError as exc:
        fail(str(exc))
        return
    if as_json:
        typer.echo(json.dumps({"out": str(done.out), "run": done.run_id, "cycle": done.cycle,
                               "messages": done.messages, "plan": done.payload},
                              allow_nan=False))
    else:
        order = done.payload["order"]
        typer.echo(f"wrote {done.out}: cycle {done.cycle} of run '{done.run_id}'; person "
                   f"{', '.join(order['human'])}; robot {', '.join(order['robot'])}; record "
                   f"it and give the bag to 'rapidds observe {run_dir}'")
