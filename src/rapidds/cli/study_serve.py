"""``rapidds study serve DIR``: run a designed user study with real people in the browser.

fastapi, uvicorn and torch are imported inside the command, so ``rapidds --help`` stays light.
"""

from __future__ import annotations

import contextlib
import json
import logging
import secrets
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

import typer

from rapidds.cli import fail
from rapidds.cli._options import HOST_HELP, POLICY, PORT_HELP
from rapidds.cli.study import study_app


def _announce(as_json: bool, url: str, overview: str, store: Path, participants: int,
              waiting: int, host: str, hosts: Sequence[str]) -> None:
    """Say where the study is served: the experimenter's overview (with its token) and the
    participants' address; a bind beyond loopback also says which names reach it."""
    from rapidds.web.server import reach_line

    if as_json:
        typer.echo(json.dumps({"url": url, "overview": overview, "study": str(store),
                               "participants": participants, "unfinished": waiting}))
    else:
        typer.echo(f"rapidds study serve: the experimenter's overview is {overview} "
                   f"(participants open {url}p/ID, no link leads there; "
                   f"{participants} participants, {waiting} unfinished; Ctrl-C stops, "
                   f"every submit is kept in {store})")
    reach = reach_line(host, hosts)
    if reach:
        typer.echo(f"rapidds study serve: {reach}", err=True)
    sys.stdout.flush()


@study_app.command("serve")
def serve_cmd(
    folder: Path = typer.Argument(..., help="The study's folder (from 'rapidds study design')."),
    host: str = typer.Option("127.0.0.1", help=f"{HOST_HELP} The overview needs the "
                             "experimenter's address printed at start."),
    port: int = typer.Option(8000, min=0, max=65535, help=PORT_HELP),
    policy: Path | None = POLICY,
    threads: int = typer.Option(1, min=1, max=256, help="Torch CPU threads."),
    as_json: bool = typer.Option(False, "--json", help="Print the address (and at the end what "
                                 "was stored) as JSON lines."),
    verbose: bool = typer.Option(False, help="Log every request that failed."),
) -> None:
    """Serve the study in FOLDER in a browser: the robot's plan of each round, what the person
    did (tracker file, simulated cell, durations typed in, or on fetch the round played in the
    browser game), the survey after each system, the ranking and the demographics form. Every
    submit is stored at once; stop with Ctrl-C and start again to continue where each
    participant stopped."""
    from rapidds.cli.run import set_threads
    from rapidds.experiments.study.store import STORE_NAME, study_path
    from rapidds.web.server import allowed_hosts, listen, served_url
    from rapidds.web.study.app import StudyWorker, create_study_app
    from rapidds.web.study.runner import StudySession

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, stream=sys.stderr,
                        format="rapidds study serve: %(levelname)s: %(message)s")
    if not study_path(folder).is_file():
        fail(f"{folder} holds no study ({STORE_NAME}); create one with 'rapidds study design "
             f"--out {folder}'")
    sock = listen(host, port)  # first: a taken port is said before seconds of loading
    with contextlib.closing(sock):
        set_threads(threads)
        worker = StudyWorker(lambda: StudySession(folder, policy_path=policy))
        try:
            import uvicorn

            url = served_url(sock)
            key = secrets.token_urlsafe(18)  # the overview's: new at every start
            overview = f"{url}?token={key}"
            steps = worker.run(lambda s: s.store.progress())
            worker.background(lambda s: s.prior())  # while the experimenter opens the page
            waiting = sum(s.kind != "done" for s in steps.values())

            hosts = allowed_hosts(str(sock.getsockname()[0]))
            app = create_study_app(worker, hosts, token=key)
            server = uvicorn.Server(uvicorn.Config(
                app, log_level="warning", lifespan="on", timeout_graceful_shutdown=3,
                access_log=False))

            # Ctrl-C or SIGTERM (a service manager's stop): the normal stop, exit 0 with the
            # summary. The handler only asks the server to exit, so a stop that comes before
            # uvicorn's own handlers are in place (from the announcement on) ends the server
            # as one during serving does; raising KeyboardInterrupt there instead could land
            # in a task that swallows it, and the server would never stop. uvicorn hands the
            # signal back to this handler when it has shut down.
            def stop(signum: int, frame: object) -> None:
                server.should_exit = True

            before = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
            try:
                _announce(as_json, url, overview, study_path(folder), len(steps), waiting,
                          host, hosts)
                server.run(sockets=[sock])
            finally:
                for sig, handler in before.items():
                    signal.signal(sig, handler)
            final = worker.run(lambda s: s.store.progress())
        finally:
            worker.close()
    left = {pid: step.describe() for pid, step in final.items() if step.kind != "done"}
    if as_json:
        typer.echo(json.dumps({"stopped": True, "study": str(study_path(folder)),
                               "participants": len(final), "next": left}))
    else:
        typer.echo(f"stopped: {len(final) - len(left)} of {len(final)} participants finished; "
                   f"the study is in {study_path(folder)}")
