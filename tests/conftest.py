"""Shared fixtures: the fetch world and its bundled policy, small search settings, a headless
Chromium for the browser tests, and the tiny test world (``tests/tinyworld.py``) registered by
name."""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import pytest
import torch

from rapidds.loop.run import load_policy
from rapidds.motion.policy import DiffusionPolicy
from rapidds.worlds.fetch import FetchWorld
from rapidds.worlds.registry import make_world

torch.set_num_threads(1)  # the networks are small; threads only fight on 2 cores


@pytest.fixture(scope="session", autouse=True)
def _own_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """The tests' own artefact cache (rapidds.cache), shared by the session and its
    subprocesses, so a test never reads or fills the user's ~/.cache."""
    old = os.environ.get("RAPIDDS_CACHE")
    os.environ["RAPIDDS_CACHE"] = str(tmp_path_factory.mktemp("rapidds-cache"))
    yield
    if old is None:
        os.environ.pop("RAPIDDS_CACHE", None)
    else:
        os.environ["RAPIDDS_CACHE"] = old



@pytest.fixture(scope="session", autouse=True)
def _fork_servers(_own_cache: None, tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Two fork servers for the CLI processes the tests start (tests/forkserver.py, used by
    ``cli_helpers.cli_cmd``); ``RAPIDDS_TEST_FORK=off`` starts plain interpreters instead."""
    import subprocess
    import sys
    from pathlib import Path

    from cli_helpers import FORK_SERVERS, HERE, fork_off

    if fork_off():
        yield
        return
    folder = tmp_path_factory.mktemp("fork")
    if len(str(folder / "a.sock")) > 100:  # a Unix socket's path has at most 107 bytes
        import tempfile

        folder = Path(tempfile.mkdtemp(prefix="rapidds-fork-", dir="/tmp"))
    src = str(HERE.parent / "src")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [
        src, os.environ.get("PYTHONPATH")]))}
    env.pop("PYTHONHASHSEED", None)  # each server its own hash seed
    for name in ("a", "b"):
        log = folder / f"{name}.log"
        with open(log, "wb") as out:
            proc = subprocess.Popen([sys.executable, str(HERE / "forkserver.py"),
                                     str(folder / f"{name}.sock")], stdout=out,
                                    stderr=subprocess.STDOUT, env=env, cwd=folder)
        FORK_SERVERS.append((str(folder / f"{name}.sock"), proc, Path(log)))
    yield
    for _, proc, _ in FORK_SERVERS:
        proc.terminate()
    for _, proc, _ in FORK_SERVERS:
        proc.wait(30)
    FORK_SERVERS.clear()


SMALL_SEARCH = dict(population=12, generations=10, samples=16, patience=4, particles=2,
                    candidates=4)
"""GA and steering settings small enough for tests, large enough to plan well on fetch."""


@pytest.fixture(scope="session")
def fetch_world() -> FetchWorld:
    world = make_world("fetch")
    assert isinstance(world, FetchWorld)
    return world


@pytest.fixture(scope="session")
def fetch_policy(fetch_world: FetchWorld) -> DiffusionPolicy:
    return load_policy(fetch_world)


@pytest.fixture()
def small() -> dict[str, int]:
    return dict(SMALL_SEARCH)


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """A headless Chromium of the system's packages, through Playwright's executable_path (the
    browser tests skip themselves, with the install command, where there is none)."""
    from browser_helpers import ARGS, CHROMIUM
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        yield b
        b.close()
