"""The artefact cache across runs (rapidds.cache): a hit gives the bits a build gives, a corrupt
entry is rebuilt with one line, an unwritable folder or ``RAPIDDS_CACHE=off`` only costs time,
two processes filling one entry leave a whole one; the spatial priors read through it."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rapidds.cache import cache_dir, cached_arrays, content_key
from rapidds.human.spatial import grid as grid_mod
from rapidds.human.spatial.config import SpatialConfig
from rapidds.human.spatial.grid import SpatialCostModel

SRC = Path(__file__).resolve().parents[1] / "src"


class _Builds:
    def __init__(self, seed: int = 0):
        self.calls, self.seed = 0, seed

    def __call__(self) -> dict[str, np.ndarray]:
        self.calls += 1
        rng = np.random.default_rng(self.seed)
        return {"a": rng.normal(size=5), "b": rng.integers(0, 9, size=(2, 3))}


@pytest.fixture()
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("RAPIDDS_CACHE", str(tmp_path / "c"))
    return tmp_path / "c"


def test_a_hit_gives_the_built_bits_without_building(cache: Path) -> None:
    build = _Builds()
    first = cached_arrays("k", content_key("x", 1.5), ("a", "b"), build)
    again = cached_arrays("k", content_key("x", 1.5), ("a", "b"), build)
    assert build.calls == 1
    for k in ("a", "b"):
        assert again[k].dtype == first[k].dtype
        assert again[k].tobytes() == first[k].tobytes()
    assert len(list((cache / "k").glob("*.npz"))) == 1
    cached_arrays("k", content_key("x", 1.25), ("a", "b"), build)  # another input: a miss
    assert build.calls == 2


def test_keys_follow_the_content() -> None:
    a = np.arange(6.0)
    assert content_key(a, 0.1) == content_key(a.copy(), 0.1)
    assert content_key(a, 0.1) != content_key(a.reshape(2, 3), 0.1)
    assert content_key(a, 0.1) != content_key(a.astype(np.float32), 0.1)
    b = a.copy()
    b[3] = np.nextafter(b[3], 9)
    assert content_key(a) != content_key(b)


@pytest.mark.parametrize("damage", [b"", b"not a zip", "truncate", "other names"])
def test_a_corrupt_entry_is_rebuilt_with_one_line(cache: Path, damage: object,
                                                  caplog: pytest.LogCaptureFixture) -> None:
    key = content_key("y")
    good = cached_arrays("k", key, ("a", "b"), _Builds())
    path = cache / "k" / f"{key}.npz"
    if damage == "truncate":
        path.write_bytes(path.read_bytes()[:-40])
    elif damage == "other names":
        np.savez(path, c=np.zeros(2))
    else:
        assert isinstance(damage, bytes)
        path.write_bytes(damage)
    build = _Builds()
    with caplog.at_level(logging.WARNING, "rapidds.cache"):
        got = cached_arrays("k", key, ("a", "b"), build)
    assert build.calls == 1
    assert got["a"].tobytes() == good["a"].tobytes()
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "is corrupt" in lines[0] and "\n" not in lines[0], lines
    cached_arrays("k", key, ("a", "b"), build)  # repaired: a hit again
    assert build.calls == 1


def test_off_or_unwritable_only_costs_time(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                           caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setenv("RAPIDDS_CACHE", "off")
    assert cache_dir() is None
    build = _Builds()
    cached_arrays("k", "0", ("a", "b"), build)
    cached_arrays("k", "0", ("a", "b"), build)
    assert build.calls == 2
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder would be")
    monkeypatch.setenv("RAPIDDS_CACHE", str(blocker))
    with caplog.at_level(logging.WARNING, "rapidds.cache"):
        cached_arrays("k", "1", ("a", "b"), build)
        cached_arrays("k", "2", ("a", "b"), build)
    assert build.calls == 4
    assert len(caplog.records) == 1 and "cannot write the cache" in caplog.records[0].message


def test_the_default_folder_follows_xdg(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("RAPIDDS_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_dir() == tmp_path / "rapidds"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/not/allowed")
    assert cache_dir() == Path.home() / ".cache" / "rapidds"


def test_two_processes_filling_one_entry_leave_a_whole_one(cache: Path) -> None:
    code = ("import numpy as np; from rapidds.cache import cached_arrays; "
            "cached_arrays('k', 'same', ('a',), lambda: {'a': np.arange(200_000.0)})")
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    procs = [subprocess.Popen([sys.executable, "-c", code], env=env) for _ in range(2)]
    assert [p.wait(timeout=60) for p in procs] == [0, 0]
    assert [p.name for p in (cache / "k").iterdir()] == ["same.npz"]  # no temporary left
    got = cached_arrays("k", "same", ("a",), lambda: pytest.fail("should be a hit"))
    assert np.array_equal(got["a"], np.arange(200_000.0))


def test_population_priors_are_the_same_bits_from_the_cache(
        cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    config = SpatialConfig.from_box([0, 0], [1, 1], beta=8.0, grid_points=12)
    rng = np.random.default_rng(3)
    paths = [rng.uniform(0, 1, (9, 2)) for _ in range(4)]
    monkeypatch.setenv("RAPIDDS_CACHE", "off")
    plain = SpatialCostModel.from_population(config, paths)
    monkeypatch.setenv("RAPIDDS_CACHE", str(cache))
    calls = []
    real = grid_mod.point_cost
    monkeypatch.setattr(grid_mod, "point_cost", lambda *a, **k: calls.append(1) or real(*a, **k))
    built = SpatialCostModel.from_population(config, paths)
    read = SpatialCostModel.from_population(config, paths)
    assert len(calls) == len(paths)  # the second one built nothing
    for m in (built, read):
        assert m.mean.tobytes() == plain.mean.tobytes()
        assert m.var.tobytes() == plain.var.tobytes()
    other = SpatialCostModel.from_population(config.replace(beta=9.0), paths)
    assert len(calls) == 2 * len(paths) and other.mean.tobytes() != plain.mean.tobytes()


def test_a_run_records_the_same_with_the_cache_off_cold_or_warm(
        cache: Path, monkeypatch: pytest.MonkeyPatch, fetch_policy) -> None:
    """The loop's prior and the oracle's truth through the cache: the records are the same
    bits whether built (cache off or empty) or read back."""
    from record_helpers import stored

    from rapidds.loop import AdaptiveRun, RunConfig

    cfg = RunConfig(human="slow-middle", cycles=1, population=4, generations=2, samples=4,
                    particles=1, candidates=2)

    def records() -> list:
        return [stored(r) for r in AdaptiveRun(cfg, fetch_policy).run()]

    monkeypatch.setenv("RAPIDDS_CACHE", "off")
    plain = records()
    monkeypatch.setenv("RAPIDDS_CACHE", str(cache))
    assert records() == plain  # cold: built and stored
    assert len(list((cache / "population-costs").glob("*.npz"))) > 0
    assert records() == plain  # warm: read back


def test_approach_speeds_are_the_same_bits_from_the_cache(
        cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The monitor's approach speeds (seconds at a monitored run's start) through the cache: a
    hit builds nothing and gives the bits a build gives; other reactions are another entry."""
    from rapidds.execution import slowdowns
    from rapidds.loop.config import RunConfig
    from rapidds.loop.model import prior_model
    from rapidds.worlds.reactions import cell_reactions
    from rapidds.worlds.registry import make_world

    world = make_world("fetch")
    spatial = prior_model(world, RunConfig().resolved(world)).spatial
    limits = cell_reactions(world)[1]
    monkeypatch.setenv("RAPIDDS_CACHE", "off")
    plain = slowdowns.approach_speeds(world, spatial, limits)
    monkeypatch.setenv("RAPIDDS_CACHE", str(cache))
    calls = []
    real = slowdowns._towards_point
    monkeypatch.setattr(slowdowns, "_towards_point",
                        lambda *a: calls.append(1) or real(*a))
    built = slowdowns.approach_speeds(world, spatial, limits)
    n = len(calls)
    read = slowdowns.approach_speeds(world, spatial, limits)
    assert n > 0 and len(calls) == n  # the second one built nothing
    for got in (built, read):
        assert list(got) == list(plain)
        assert all(got[t].tobytes() == plain[t].tobytes() for t in plain)
    slower = dataclasses.replace(limits, reaction_time=limits.reaction_time * 2)
    assert slowdowns.approach_speeds(world, spatial, slower) is not None and len(calls) > n


def test_painting_motions_are_the_same_bits_from_the_cache(
        cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The nominal motions' IK (0.7 s of every painting process) through the cache: a hit
    solves nothing and gives the joint vectors a solve gives; another layout (the bowl 2 cm
    farther) is another entry."""
    from rapidds.worlds.painting import motions
    from rapidds.worlds.painting.scene import LAYOUT, Box

    solve = motions.nominal_motion.__wrapped__  # past the per-process cache
    monkeypatch.setenv("RAPIDDS_CACHE", "off")
    plain = solve("mix_l", "avoidant")
    monkeypatch.setenv("RAPIDDS_CACHE", str(cache))
    calls = []
    real = motions.solve_ik
    monkeypatch.setattr(motions, "solve_ik", lambda *a, **k: calls.append(1) or real(*a, **k))
    built = solve("mix_l", "avoidant")
    n = len(calls)
    read = solve("mix_l", "avoidant")
    assert n == len(plain.waypoints) - 2 and len(calls) == n  # the second one solved nothing
    for got in (built, read):
        for field in ("waypoints", "stop", "dwell", "fixed"):
            assert getattr(got, field).tobytes() == getattr(plain, field).tobytes()
        assert got.pace == plain.pace
    bowl = LAYOUT.bowl
    moved = dataclasses.replace(LAYOUT, bowl=Box((bowl.center[0], bowl.center[1] + 0.02,
                                                  bowl.center[2]), bowl.half))
    other = solve("mix_l", "avoidant", moved)
    assert len(calls) > 2 * n and other.waypoints.tobytes() != plain.waypoints.tobytes()


def test_a_warm_painting_process_plans_without_compiling_mujoco(
        cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The arm's kinematics through the cache are the arrays the compiled model gives, and a
    painting process whose cache is warm plans a cycle without importing MuJoCo (its import
    and the scene's compile were 0.9 s of every such process); its record is the cold one's."""
    from rapidds.worlds.painting import kinematics
    from rapidds.worlds.painting.scene import load_model

    plain = kinematics.ArmKinematics.from_model(load_model())
    for _ in range(2):  # built, then read back
        got = kinematics.arm_kinematics.__wrapped__()
        for name in kinematics._ARM_FIELDS:
            assert getattr(got, name).tobytes() == getattr(plain, name).tobytes(), name
    code = ("import json, sys; from rapidds.loop import AdaptiveRun, RunConfig, load_policy; "
            "from rapidds.worlds.registry import make_world; "
            "cfg = RunConfig(world='painting', cycles=1, population=4, generations=2, "
            "samples=4, particles=1, candidates=2); "
            "rec = AdaptiveRun(cfg, load_policy(make_world('painting'), device='cpu')).step()"
            ".record.to_json(); rec.pop('seconds'); "
            "print(json.dumps({'mujoco': 'mujoco' in sys.modules, 'record': rec}))")
    env = {**os.environ, "PYTHONPATH": str(SRC)}

    def child() -> dict:
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                             text=True, timeout=300, check=True)
        return json.loads(out.stdout.strip().splitlines()[-1])

    cold, warm = child(), child()
    assert cold["mujoco"] and not warm["mujoco"]
    assert warm["record"] == cold["record"]
