"""``rapidds play`` on the command line: light --help, and one clear line for bad input."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest
from cli_helpers import cli_cmd

HEAVY = ("torch", "fastapi", "uvicorn", "starlette", "websockets", "matplotlib")


def _rapidds(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cli_cmd(*argv),
                          capture_output=True, text=True, timeout=180)


def test_play_help_imports_no_heavy_library() -> None:
    code = ("import sys\nfrom rapidds.cli import main\ntry:\n    main()\nexcept SystemExit:\n"
            f"    pass\nprint('HEAVY', sorted(m for m in {HEAVY!r} if m in sys.modules), "
            "file=sys.stderr)")
    out = subprocess.run([sys.executable, "-c", code, "play", "--help"], capture_output=True,
                         text=True, timeout=120)
    assert "HEAVY []" in out.stderr, out.stderr[-2000:]
    assert "--resume" in out.stdout and "--host" in out.stdout


@pytest.mark.parametrize(("argv", "message"), [
    (["play", "painting"], "does not declare the browser_play capability"),
    (["play", "--adapt", "oracle"], "a person has none"),
    (["play", "--adapt", "sometimes"], "--adapt"),
    (["play", "--human", "../etc"], "--human"),
    (["play", "--cycles", "0"], "--cycles"),
    (["play", "--gamma", "lots"], "--gamma"),
    (["play", "--gamma", "learn", "--gamma-prior", "0:4"], "gamma"),
    (["play", "--execution", "sideways"], "--execution"),
])
def test_bad_options_are_one_line(argv: list[str], message: str) -> None:
    out = _rapidds(*argv)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], out.stderr


def test_a_taken_port_and_a_missing_run_are_one_line(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        out = _rapidds("play", "--port", str(port), "--out", str(tmp_path))
    assert out.returncode == 2 and out.stderr.count("\n") == 1
    assert f"cannot listen on 127.0.0.1:{port}" in out.stderr
    out = _rapidds("play", "--port", "0", "--out", str(tmp_path), "--resume")
    assert out.returncode == 2 and out.stderr.count("\n") == 1, out.stderr
    assert "no cycle of run 'fetch-player-full-s0' to resume" in out.stderr
