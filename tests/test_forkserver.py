"""The fork server the tests start their CLI processes from (tests/forkserver.py) behaves as a
fresh ``python -c 'from rapidds.cli import main; main()'``: the environment, folder and path
it is given, its exit code, its death by a signal, and a SIGKILL of the process a test holds
ends the run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from cli_helpers import FORK_SERVERS, HERE, cli_cmd, fork_off

from rapidds.store import RunStore

pytestmark = pytest.mark.skipif(
    fork_off(), reason="RAPIDDS_TEST_FORK=off: the CLI processes are plain interpreters")


def test_the_session_has_its_fork_servers() -> None:
    assert len(FORK_SERVERS) == 2 and cli_cmd("--help")[2].endswith("fork_client.py")

RUN = ("run", "--cycles", "40", "--population", "4", "--generations", "2", "--samples", "4",
       "--particles", "1", "--candidates", "2", "--json")


def _started(tmp_path: Path) -> subprocess.Popen[str]:
    """A long run, once its first cycle is out."""
    proc = subprocess.Popen(cli_cmd(*RUN, "--out", str(tmp_path / "run")), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.stdout is not None
    assert json.loads(proc.stdout.readline())["cycle"] == 0, proc.stderr
    return proc


def test_environment_folder_and_path_are_the_callers(tmp_path: Path) -> None:
    env = {**os.environ, "RAPIDDS_WORLDS": "tiny=tinyworld:TinyWorld", "PYTHONPATH": str(HERE)}
    out = subprocess.run(cli_cmd("worlds", "--json"), capture_output=True, text=True,
                         env=env, cwd=tmp_path, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "tiny" in json.loads(out.stdout)  # read from the environment, imported from the path
    bad = subprocess.run(cli_cmd("plan", "nowhere.yaml"), capture_output=True, text=True,
                         cwd=tmp_path, timeout=60)
    assert bad.returncode == 2 and "nowhere.yaml" in bad.stderr  # the exit code, as it is


def test_a_signal_reaches_the_run_and_its_end_is_the_callers(tmp_path: Path) -> None:
    """SIGTERM (no handler in the CLI: killed by it, as a plain interpreter is). Ctrl-C through
    the CLI's own handler is the browser tests' stop of every server (browser_helpers)."""
    proc = _started(tmp_path)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(60) == -signal.SIGTERM


def test_a_killed_client_ends_its_run(tmp_path: Path) -> None:
    proc = _started(tmp_path)
    proc.kill()
    proc.wait(30)
    time.sleep(1.0)  # the server kills the run at once; a live run stores a cycle in ~0.3 s
    with RunStore.open_readonly(tmp_path / "run" / "run.sqlite") as store:
        before = store.last_cycle(store.records()[0]["run_id"])
    time.sleep(1.5)
    with RunStore.open_readonly(tmp_path / "run" / "run.sqlite") as store:
        assert store.last_cycle(store.records()[0]["run_id"]) == before
