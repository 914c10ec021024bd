"""``rapidds play``: the fetch game in a browser, with rapidds learning the person who plays.

fastapi, uvicorn and torch are imported inside the command, so ``rapidds --help`` stays light.
"""

from __future__ import annotations

import contextlib
import logging
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from rapidds.cli import app, fail
from rapidds.cli._options import (
    HOST_HELP,
    POLICY,
    PORT_HELP,
    RUN_OUT_HELP,
    SEARCH,
    THREADS,
    run_settings,
)
from rapidds.loop.config import RunConfig

if TYPE_CHECKING:
    from rapidds.loop.run import AdaptiveRun, CycleResult
    from rapidds.web.session import PlaySession

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,39}")


@app.command("play")
@run_settings("world", "human", "adapt", "cycles", "seed", "gamma", "gamma_prior", "gamma_plan",
              "execution", "lam", *SEARCH, "device", defaults={"cycles": 10, "human": "player"},
              aliases={"--player": "human"})
def play_cmd(
    settings: dict[str, Any],
    port: int = typer.Option(8765, min=0, max=65535, help=PORT_HELP),
    host: str = typer.Option("127.0.0.1", help=HOST_HELP),
    out: Path = typer.Option(Path("runs/play"), help=RUN_OUT_HELP),
    resume: bool = typer.Option(False, help="Continue the run stored in --out with its learned "
                                "models."),
    ask_comfort: bool = typer.Option(False, help="Ask after every cycle how close the robot came "
                                     "(1-7); always with --gamma learn."),
    policy: Path | None = POLICY,
    speed: float = typer.Option(4.5, min=0.5, max=10.0, help="The avatar's speed, m/s."),
    hz: int = typer.Option(60, min=10, max=240, help="Game ticks (state updates) per second."),
    threads: int = THREADS,
    verbose: bool = typer.Option(False, help="Log every connection and refused message."),
) -> None:
    """Play the fetch game in a browser: rapidds plans the robot, learns your timing and your
    routes, and re-plans every cycle. Prints the address to open."""
    player = str(settings["human"])
    _check_args(settings["world"], settings["adapt"], player)
    cfg = RunConfig(**settings)
    cycles = cfg.cycles

    from rapidds.web.server import allowed_hosts, listen, reach_line, serve, served_url
    from rapidds.web.session import STORE_NAME

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, stream=sys.stderr,
                        format="rapidds play: %(levelname)s: %(message)s")
    sock = listen(host, port)  # first: a taken port is said before seconds of loading
    with contextlib.closing(sock):
        session = _session(cfg, out, policy, player, hz, speed, resume, threads,
                           ask_comfort or cfg.gamma_learn)
        try:
            session.open()
            url = served_url(sock)
            reach = reach_line(host, allowed_hosts(sock.getsockname()[0]))

            def ready() -> None:
                typer.echo(f"rapidds play: open {url} (run {session.run_id}, cycle "
                           f"{session.stored + 1} of {cycles}; Ctrl-C stops, finished cycles "
                           f"are kept in {out / STORE_NAME})")
                if reach:
                    typer.echo(f"rapidds play: {reach}", err=True)
                sys.stdout.flush()

            # uvicorn re-raises Ctrl-C once it has shut down cleanly: that is the normal stop
            with contextlib.suppress(KeyboardInterrupt):
                serve(session, sock, on_ready=ready)
        finally:
            session.stop()
    _say_stopped(session, out / STORE_NAME)


def _say_stopped(session: PlaySession, store: Path) -> None:
    n, cycles = session.stored, session.cycles
    typer.echo(f"stopped: {n} of {cycles} cycles of {session.run_id} stored in {store}"
               + ("" if n >= cycles else "; continue with --resume"))


def _check_args(world: str, adapt: str, player: str) -> None:
    """What a browser game refuses before loading a policy: one line and exit 2."""
    from rapidds.worlds.capabilities import capability, lacks
    from rapidds.worlds.registry import UnknownWorldError, make_world

    try:
        made = make_world(world)
    except UnknownWorldError as exc:
        fail(str(exc))
    if capability(made, "browser_play") is None:
        fail(lacks(made, "browser_play"))
    if adapt == "oracle":
        fail("--adapt oracle plans with a simulated teammate's true model; a person has none")
    if not _NAME.fullmatch(player):
        fail(f"--human {player!r}: use 1-40 letters, digits, '.', '_' or '-'")


def _session(cfg: RunConfig, out: Path, policy: Path | None, player: str, hz: int, speed: float,
             resume: bool, threads: int, ask: bool) -> PlaySession:
    """The person's run: the world, the policy, the player (asked about their comfort
    after every cycle with ``ask``); Gantt charts and the run's
    pictures drawn when the game stops, as ``rapidds run`` draws them."""
    from rapidds.cli.run import set_threads, write_pictures
    from rapidds.loop.run import load_policy
    from rapidds.web.player import BrowserPlayer
    from rapidds.web.session import PlaySession
    from rapidds.worlds.capabilities import capability
    from rapidds.worlds.registry import make_world

    set_threads(threads)
    world = capability(make_world(cfg.world), "browser_play")
    assert world is not None  # _check_args refused the others
    played: list[CycleResult] = []

    def on_cycle(run: AdaptiveRun, res: CycleResult) -> None:
        played.append(res)  # drawn when the game stops: matplotlib would delay the next plan
        real = res.record.realised
        typer.echo(f"cycle {res.record.cycle}: makespan {real.makespan:.2f} s, closest "
                   f"approach {real.min_separation:.2f} m, cost {real.cost:.2f}")

    def on_stop(run: AdaptiveRun) -> None:
        from rapidds.plots.gantt import save_gantt
        from rapidds.plots.run import gantt_path

        rid = run.config.run_id
        for res in played:
            c = res.record.cycle
            save_gantt(res.deployment.timeline, gantt_path(out, rid, c),
                       title=f"{rid} cycle {c} (realised)", pauses=res.deployment.pauses,
                       replans=res.deployment.replans)
        if run.next_cycle:
            write_pictures(run, out)

    return PlaySession(cfg, out, world=world, policy=load_policy(world, policy, cfg.device),
                       player=BrowserPlayer(world, player, hz=hz, speed=speed, ask_comfort=ask),
                       resume=resume,
                       on_cycle=on_cycle, on_stop=on_stop)
