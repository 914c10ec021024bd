"""The scheduler's motion interface backed by the bundled fetch policy and SVDD-PM steering."""

import numpy as np
import pytest
from cli_helpers import cli_cmd

from rapidds.human.spatial import SpatialConfig, SpatialModel
from rapidds.motion.diffusion_motion import DiffusionMotion, SteeringConfig
from rapidds.motion.interface import MotionModel, TrajectoryCache


@pytest.fixture(scope="module")
def world(fetch_world):
    return fetch_world


@pytest.fixture(scope="module")
def motion(world, fetch_policy):
    # A person known to take the middle route to t2: their cost covers the central corridor.
    paths = {"t2": [world.trajectory("human", "t2", "middle")]}
    lo, hi = world.bounds
    spatial = SpatialModel.from_population(
        SpatialConfig(bounds=tuple(zip(lo, hi, strict=True)), beta=1.0), paths)
    # gamma 5: V(middle) = 4.8 + 5 * 0.90 = 9.3 against V(outside) = 6.0 + 5 * 0.05 = 6.2 (at
    # gamma 1.75 the two differ by only 0.3 and greedy SVDD may settle on either)
    return DiffusionMotion(fetch_policy, world.completion_time, spatial.cost, gamma=5.0,
                           config=SteeringConfig(particles=8, candidates=8, seed=0))


def test_requests_answered_in_one_batch_and_avoid_the_person(world, motion):
    assert isinstance(motion, MotionModel)
    calls = motion.calls
    alone, beside = motion.plan([("t3", frozenset()), ("t3", frozenset({"t2"}))])
    assert motion.calls == calls + 1  # both requests went through one steering batch
    assert world.route_mode("t3", alone.trajectory) == "middle"  # fastest when nobody is there
    assert world.route_mode("t3", beside.trajectory) == "outside"  # away from the corridor
    assert beside.spatial_cost < 0.5 < float(motion.spatial_cost(["t2"], alone.trajectory[None])[0])
    for p in (alone, beside):
        assert p.duration == pytest.approx(world.completion_time("t3", p.trajectory[None])[0])
        assert p.duration < world.penalty
        assert not world.collides(p.trajectory[None])[0]
    assert alone.spatial_cost == 0.0 and alone.duration < beside.duration


def test_gamma_zero_takes_the_fastest_route(world, motion):
    fast = DiffusionMotion(motion.policy, world.completion_time, motion.spatial_cost, gamma=0.0,
                           config=SteeringConfig(particles=8, candidates=8, seed=0))
    (plan,) = fast.plan([("t3", frozenset({"t2"}))])
    assert world.route_mode("t3", plan.trajectory) == "middle"
    assert plan.spatial_cost > 0.5  # measured, though not weighed


def test_cache_plans_each_key_once(motion):
    cache = TrajectoryCache(motion)
    keys = [("t1", frozenset()), ("t0", frozenset({"t2"})), ("t1", frozenset())]
    first = cache.get_many(keys)
    calls = motion.calls
    again = cache.get_many(keys[:2])
    assert motion.calls == calls and cache.hits == 3 and cache.misses == 2
    assert first[0] is first[2] is again[0]
    assert np.array_equal(first[1].trajectory, again[1].trajectory)


def test_same_seed_same_motions(world, motion):
    a = DiffusionMotion(motion.policy, world.completion_time, motion.spatial_cost, 1.75,
                        SteeringConfig(particles=4, candidates=4, seed=5))
    b = DiffusionMotion(motion.policy, world.completion_time, motion.spatial_cost, 1.75,
                        SteeringConfig(particles=4, candidates=4, seed=5))
    key = [("t2", frozenset({"t2"}))]
    assert np.array_equal(a.plan(key)[0].trajectory, b.plan(key)[0].trajectory)


def test_bad_steering_config_rejected():
    with pytest.raises(ValueError, match="particles"):
        SteeringConfig(particles=0)
    with pytest.raises(ValueError, match="alpha"):
        SteeringConfig(alpha=float("nan"))
    with pytest.raises(ValueError, match="steps"):
        SteeringConfig(steps=0)


def test_steering_steps_reach_the_policy(world, motion, monkeypatch):
    five = DiffusionMotion(motion.policy, world.completion_time, motion.spatial_cost, 1.75,
                           SteeringConfig(particles=2, candidates=2, seed=3, steps=5))
    rows: list[int] = []
    net = motion.policy.denoiser()

    def counting(x, t, cond):
        rows.append(x.shape[0])
        return net(x, t, cond)

    monkeypatch.setattr(motion.policy, "denoiser", lambda: counting)
    five.plan([("t1", frozenset())])
    assert rows == [2] + [4] * 4  # x_T, then particles x candidates rows for 4 more steps


@pytest.mark.slow
def test_sample_in_world_cli_steers_and_draws(tmp_path):
    import json
    import subprocess

    import matplotlib.image as mpimg

    def cli(*args):
        return subprocess.run(cli_cmd("sample", "--world", "fetch", "--task", "t3", *args),
                              capture_output=True, text=True, timeout=120)

    r = cli("--concurrent", "t2", "--gamma", "5", "-n", "6", "--json",
            "--out", str(tmp_path / "s.png"))
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["routes"].count("outside") >= 5 and max(doc["spatial"]) < 0.3
    assert mpimg.imread(tmp_path / "s.png")[..., :3].std() > 0.05
    bad = cli("--concurrent", "t9")
    assert bad.returncode == 2 and "no spatial model" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1
