"""Shared fixtures: the fetch world and its bundled policy, small search settings, and the
tiny test world (``tests/tinyworld.py``) registered by name."""

from __future__ import annotations

import pytest
import torch

from rapidds.loop.run import load_policy
from rapidds.motion.policy import DiffusionPolicy
from rapidds.worlds.fetch import FetchWorld
from rapidds.worlds.registry import make_world

torch.set_num_threads(1)  # the networks are small; threads only fight on 2 cores

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
