"""What the browser tests share: Debian's Chromium found (never ``playwright install``), its
launch flags (the ``browser`` fixture in conftest.py uses them), and a ``rapidds`` server in a
subprocess."""

from __future__ import annotations

import os
import queue
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from cli_helpers import cli_cmd

ROOT = Path(__file__).resolve().parents[1]


def _chromium() -> str | None:
    for cand in (os.environ.get("RAPIDDS_CHROMIUM"), shutil.which("chromium"),
                 shutil.which("chromium-browser"), "/usr/bin/chromium"):
        if cand and Path(cand).is_file() and os.access(cand, os.X_OK):
            return cand
    return None


CHROMIUM = _chromium()
NEEDS_CHROMIUM = [
    pytest.mark.slow,
    pytest.mark.skipif(CHROMIUM is None, reason="no Chromium found: install Debian's with "
                       "'apt-get install chromium' (or set RAPIDDS_CHROMIUM); never "
                       "'playwright install'"),
]
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic"]
SHOTS = os.environ.get("RAPIDDS_SCREENSHOTS") == "1"


def open_page(browser: Any, url: str | None = None, *, width: int = 1040,
              height: int = 820) -> Any:
    """A new page (at ``url``) whose uncaught script errors collect in ``page.errors``.
    bypass_csp: the pages forbid eval, which Playwright's wait_for_function uses."""
    page = browser.new_page(viewport={"width": width, "height": height}, bypass_csp=True)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.errors = errors
    if url is not None:
        page.goto(url)
    return page


class CliServer:
    """``rapidds ARGS`` in a subprocess (this checkout's sources first on the path); stdout lines
    arrive in ``lines`` (those read are kept in ``out_lines``), stderr in ``err``."""

    def __init__(self, *args: str):
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT / "src"),
                                                          env.get("PYTHONPATH")]))
        self.name = "rapidds " + " ".join(args[:2])
        self.proc = subprocess.Popen(
            cli_cmd(*args),
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        self.lines: queue.Queue[str] = queue.Queue()
        self.err: list[str] = []
        self.out_lines: list[str] = []
        self._pumps = [threading.Thread(target=self._pump, args=args, daemon=True)
                       for args in ((self.proc.stdout, self.lines.put),
                                    (self.proc.stderr, self.err.append))]
        for t in self._pumps:
            t.start()

    @staticmethod
    def _pump(stream: Any, put: Any) -> None:
        for line in stream:
            put(line)

    def wait_for(self, found: Callable[[str], bool], timeout: float = 120) -> str:
        """The first stdout line that ``found`` accepts; the server is killed if none comes."""
        end = time.monotonic() + timeout
        while True:
            try:
                line = self.lines.get(timeout=max(0.1, end - time.monotonic()))
            except queue.Empty:
                self.proc.kill()
                raise AssertionError(f"{self.name} printed no address: "
                                     + "".join(self.err)[-2000:]) from None
            self.out_lines.append(line)
            if found(line):
                return line

    def kill(self) -> None:
        """In a test's ``finally``: whatever failed, no server outlives it."""
        if self.proc.poll() is None:
            self.proc.kill()

    def stop(self, sig: int = signal.SIGINT, timeout: float = 60) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        rc = self.proc.wait(timeout)
        for t in self._pumps:  # until the pipes' ends: every line printed is in out_lines
            t.join(timeout)
        while not self.lines.empty():
            self.out_lines.append(self.lines.get())
        return rc


def close_and_stop(page: Any, server: CliServer) -> None:
    """The end of a browser test: the page saw no script error, and the server stops on Ctrl-C
    with exit 0 (what a person's Ctrl-C does)."""
    assert page.errors == []
    page.close()
    assert server.stop(signal.SIGINT) == 0
