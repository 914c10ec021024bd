"""Running the CLI inside the test process, as the tests of its answers need it."""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
PLAIN = [sys.executable, "-c", "from rapidds.cli import main; main()"]
FORK_SERVERS: list[tuple[str, subprocess.Popen[bytes], Path]] = []
"""The session's fork servers (socket, process, log), started by conftest.py; none with
``RAPIDDS_TEST_FORK=off``."""
_turn = itertools.count()


def fork_off() -> bool:
    """``RAPIDDS_TEST_FORK=off`` (or 0, no, false): the tests start plain interpreters."""
    return os.environ.get("RAPIDDS_TEST_FORK", "").strip().lower() in ("off", "0", "no", "false")


def cli_cmd(*args: str) -> list[str]:
    """The command line of ``rapidds ARGS`` in a new process, on this interpreter (it reads the
    session's artefact cache, ``$RAPIDDS_CACHE``, conftest.py). The process is a child of one of
    the session's fork servers (tests/forkserver.py: the CLI's imports done once), in turn, so
    that two runs a test compares come from two interpreters with different hash seeds."""
    if not FORK_SERVERS:
        return [*PLAIN, *args]
    sock, proc, log = FORK_SERVERS[next(_turn) % len(FORK_SERVERS)]
    deadline = time.monotonic() + 180
    while not Path(sock).exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError(f"the fork server did not start: {log.read_text()[-2000:]}")
        time.sleep(0.05)
    return [sys.executable, "-S", str(HERE / "fork_client.py"), sock, *args]


def run_main(capsys: Any, *args: str) -> tuple[int, str, str]:
    """Run ``rapidds ARGS`` in this process: (exit code, stdout, stderr)."""
    from rapidds.cli import main

    old = sys.argv
    sys.argv = ["rapidds", *args]
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    finally:
        sys.argv = old
    out, err = capsys.readouterr()
    return code, out, err


def kill_run(cmd: list[str], db: Path, run_id: str, kill_at: int,
             env: dict[str, str], timeout: float = 240.0) -> int | None:
    """Start the ``rapidds run`` command ``cmd`` storing into ``db``, SIGKILL it once ``kill_at``
    cycles of ``run_id`` are stored (or it ended, or ``timeout`` s passed): its last stored
    cycle."""
    from rapidds.store import RunStore

    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None:
        if db.exists():
            with RunStore.open_readonly(db) as st:
                if (st.last_cycle(run_id) or -1) + 1 >= kill_at:
                    break
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with RunStore.open_readonly(db) as st:
        return st.last_cycle(run_id)


def resume_and_compare(cmd: list[str], full: Path, resumed: Path, env: dict[str, str],
                       timeout: float = 300.0
                       ) -> tuple[list[dict[str, Any]], list[dict[str, Any]], Any, Any]:
    """Run ``cmd`` (``rapidds run ... --resume`` on the store ``resumed``); the records of the
    uninterrupted store ``full`` and of the resumed one, and the last stored model of each."""
    from rapidds.loop import HumanModel
    from rapidds.store import RunStore

    done = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout)
    assert done.returncode == 0, done.stderr
    with RunStore.open_readonly(full) as a, RunStore.open_readonly(resumed) as b:
        ra, rb = a.records(), b.records()
        last = ra[-1]["cycle"]
        return (ra, rb, HumanModel.from_bytes(a.state(ra[-1]["run_id"], last)),
                HumanModel.from_bytes(b.state(rb[-1]["run_id"], last)))
