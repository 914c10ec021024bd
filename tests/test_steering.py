"""SVDD-PM steering (its acceptance checks): it lowers V against unsteered sampling on the same
seeds, moves samples off a route covered by a person's spatial cost while plain sampling keeps
both routes, prefers the quicker route when V is completion time only (gamma = 0), and costs M
network passes per step, all candidates in one batch.

The policy is trained here, on toy two-route demonstrations (short route below the line, long
route above), in about 10-20 s on one busy core."""

from __future__ import annotations

import json
from collections.abc import Callable

import numpy as np
import pytest
from typer.testing import CliRunner

from rapidds.cli import _register, app
from rapidds.motion.config import DiffusionConfig
from rapidds.motion.demos import two_route_demos
from rapidds.motion.policy import DiffusionPolicy, make_noise_scheduler
from rapidds.motion.steering import (
    SteerRequest,
    completion_index,
    proximity_cost,
    steer,
    value_function,
)
from rapidds.motion.train import train_policy

B, M = 64, 8
TOL = 0.15  # arrival tolerance of the completion index (routes are about 1.2 and 1.9 long)
# A person on the short route, from its peak up to the straight line (so that cutting between
# the routes does not pay either). beta = 2 makes the cost felt half a unit away: SVDD scores
# blurry early x0 estimates, and a broad cost tells the routes apart while the route is still
# being decided (with beta = 5 about 20 % of particles commit before the cost is felt).
PERSON = np.stack([np.full(7, 0.5), np.linspace(-0.3, 0.0, 7)], axis=-1)
BETA, GAMMA = 2.0, 20.0


@pytest.fixture(scope="module")
def policy() -> DiffusionPolicy:
    demos, _ = two_route_demos(n_per_route=32, seed=0)
    cfg = DiffusionConfig(horizon=16, state_dim=2, task_names=demos.task_names,
                          down_dims=(32, 64), step_embed_dim=32, num_train_timesteps=50,
                          num_inference_steps=10, steps=300, batch_size=64, lr=4e-3,
                          device="cpu")
    policy, _ = train_policy(demos, cfg)
    return policy


def long_route(trajs: np.ndarray) -> np.ndarray:
    """(N,) True where a path of task 'right' takes the long route (peak y about 0.75)."""
    return trajs[:, :, 1].max(axis=1) > 0.4


def short_route(trajs: np.ndarray) -> np.ndarray:
    """(N,) True where a path of task 'right' takes the short route (low point y about -0.3)."""
    return trajs[:, :, 1].min(axis=1) < -0.15


def blocked_short_route() -> Callable[[np.ndarray], np.ndarray]:
    """V = completion + gamma * S, S the proximity cost of the person on the short route."""
    return value_function([proximity_cost(PERSON, BETA)], GAMMA, tol=TOL)


def test_steering_lowers_the_value(policy):
    value = blocked_short_route()
    plain = policy.sample("right", B, generator=1)
    steered = steer(policy, SteerRequest("right", B), value, num_candidates=M, generator=1)
    assert steered.trajectories.shape == (B, 16, 2) and steered.values.shape == (B,)
    assert np.allclose(steered.values, value(steered.trajectories))
    assert steered.values.mean() < 0.85 * value(plain).mean()


def test_cost_over_one_route_switches_samples_to_the_other(policy):
    plain = policy.sample("right", B, generator=2)
    steered = steer(policy, SteerRequest("right", B), blocked_short_route(),
                    num_candidates=M, generator=2)
    # plain sampling keeps both routes; steered samples leave the blocked one for the other
    assert long_route(plain).mean() >= 0.2 and short_route(plain).mean() >= 0.2
    assert long_route(steered.trajectories).mean() >= 0.85
    assert short_route(steered.trajectories).mean() <= 0.15


def test_gamma_zero_prefers_the_quickest_completion(policy):
    completion_only = value_function([proximity_cost(PERSON, BETA)], gamma=0.0, tol=TOL)
    plain = policy.sample("right", B, generator=3)
    steered = steer(policy, SteerRequest("right", B), completion_only,
                    num_candidates=M, generator=3)
    plain_done = completion_index(plain, TOL)
    assert np.array_equal(steered.values, completion_index(steered.trajectories, TOL))
    assert steered.values.mean() <= plain_done.mean() - 1.0
    # the quick (short) route wins although the person is on it: gamma = 0 ignores them
    quick = short_route(steered.trajectories).mean()
    assert quick >= 0.75 and quick >= short_route(plain).mean() + 0.25


def test_a_step_costs_m_network_passes_in_one_batch(policy, monkeypatch):
    rows: list[int] = []
    net = policy.denoiser()

    def counting(x, t, cond):
        rows.append(x.shape[0])
        return net(x, t, cond)

    monkeypatch.setattr(policy, "denoiser", lambda: counting)
    calls = {"n": 0, "rows": 0}

    def value(trajs: np.ndarray) -> np.ndarray:
        calls["n"] += 1
        calls["rows"] += len(trajs)
        return trajs[:, :, 1].sum(axis=1)

    result = steer(policy, SteerRequest("right", 5), value, num_candidates=4, generator=0)
    steps = policy.config.num_inference_steps
    assert rows == [5] + [5 * 4] * (steps - 1)  # x_T once, then B*M rows per step
    assert result.stats.rows_per_call == rows
    assert result.stats.network_passes == 1 + 4 * (steps - 1) <= 4 * steps
    assert calls == {"n": steps, "rows": steps * 5 * 4}
    assert result.stats.value_calls == steps and len(result.stats.kept_value) == steps


def test_fewer_steps_cost_proportionally_fewer_passes(policy):
    value = blocked_short_route()
    result = steer(policy, SteerRequest("right", 5), value,
                   num_candidates=4, generator=0, num_steps=4)
    assert result.stats.rows_per_call == [5] + [5 * 4] * 3
    assert result.stats.num_steps == 4 and result.stats.value_calls == 4
    with pytest.raises(ValueError, match="num_steps"):
        steer(policy, SteerRequest("right", 5), value, num_candidates=4, num_steps=0)


def test_fast_network_steers_like_the_reference_network(policy):
    value = blocked_short_route()
    fast = steer(policy, SteerRequest("right", 16), value, num_candidates=M, generator=11)
    policy.fast_inference = False
    try:
        ref = steer(policy, SteerRequest("right", 16), value, num_candidates=M, generator=11)
    finally:
        policy.fast_inference = True
    # float32 rounding apart, the same candidates win: the same paths and values
    assert np.allclose(fast.trajectories, ref.trajectories, atol=1e-4)
    assert np.allclose(fast.values, ref.values, atol=1e-4)
    again = steer(policy, SteerRequest("right", 16), value, num_candidates=M, generator=11)
    assert np.array_equal(fast.trajectories, again.trajectories)


def test_one_candidate_is_plain_sampling(policy):
    steered = steer(policy, SteerRequest("up", 6), lambda t: np.zeros(len(t)),
                    num_candidates=1, generator=9)
    assert np.array_equal(steered.trajectories, policy.sample("up", 6, generator=9))


def test_steering_is_seeded_and_any_callable_works(policy):
    # a value that is no spatial cost at all: prefer paths that end far to the right
    def prefer_right(t):
        return -t[:, -1, 0]

    a = steer(policy, SteerRequest("up", 8), prefer_right,
              num_candidates=4, alpha=0.05, generator=5)
    b = steer(policy, SteerRequest("up", 8), prefer_right,
              num_candidates=4, alpha=0.05, generator=5)
    assert np.array_equal(a.trajectories, b.trajectories)
    plain = policy.sample("up", 8, generator=5)
    assert a.values.mean() < prefer_right(plain).mean()


def test_nan_values_are_never_preferred(policy):
    def nan_below(t):
        v = t[:, :, 1].sum(axis=1)
        return np.where(t[:, :, 1].min(axis=1) < -0.1, np.nan, 0.0 * v)

    result = steer(policy, SteerRequest("right", 16), nan_below, num_candidates=M, generator=4)
    assert np.isfinite(result.values).mean() >= 0.9


def test_bad_steering_requests(policy):
    value = blocked_short_route()
    with pytest.raises(ValueError, match="shape"):
        steer(policy, SteerRequest("right", 4), lambda t: np.zeros((len(t), 2)), num_candidates=2)
    with pytest.raises(ValueError, match="num_candidates"):
        steer(policy, SteerRequest("right", 4), value, num_candidates=0)
    with pytest.raises(ValueError, match="alpha"):
        steer(policy, SteerRequest("right", 4), value, alpha=-1.0)
    deterministic = DiffusionPolicy(policy.config.replace(ddim_eta=0.0), policy.model,
                                    make_noise_scheduler(policy.config), policy.normalizer)
    with pytest.raises(ValueError, match="eta"):
        steer(deterministic, SteerRequest("right", 4), value, num_candidates=2)


def test_ddpm_kernel_steers_too(policy):
    cfg = policy.config.replace(sampler="ddpm")
    ddpm = DiffusionPolicy(cfg, policy.model, make_noise_scheduler(cfg), policy.normalizer)
    steered = steer(ddpm, SteerRequest("right", 32), blocked_short_route(),
                    num_candidates=M, generator=6)
    assert long_route(steered.trajectories).mean() >= 0.85


def test_value_function_pieces():
    still = np.zeros((1, 8, 2))
    walk = np.concatenate([np.linspace(0, 1, 5), np.ones(3)])[None, :, None] * [[[1.0, 0.0]]]
    assert completion_index(still, 0.01).tolist() == [0]
    assert completion_index(walk, 0.01).tolist() == [4]
    assert completion_index(walk, 0.3).tolist() == [3]  # 0.75 is within 0.3 of the end
    assert completion_index(walk, 0.3).dtype.kind == "i"
    person = proximity_cost(np.array([[1.0, 0.0]]), beta=2.0)
    assert np.allclose(person(np.concatenate([still, walk])), [np.exp(-2.0), 1.0])
    value = value_function([person], gamma=3.0, tol=0.01, dt=0.5)
    assert np.allclose(value(walk), 4 * 0.5 + 3.0)


def test_cli_sample_steered(tmp_path, policy):
    ckpt = policy.save(tmp_path / "policy")
    _register()
    result = CliRunner().invoke(app, [
        "sample", "--policy", str(ckpt), "--task", "right", "-n", "16", "--seed", "2",
        "--steer-cost", ";".join(f"{x},{y}" for x, y in PERSON), "--gamma", str(GAMMA),
        "--beta", str(BETA), "--tol", str(TOL),
        "--json", "--out", str(tmp_path / "steered.png")])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    trajs = np.array(report["trajectories"])
    assert report["steered"] and report["network_passes"] == 1 + M * 9
    same = steer(policy, SteerRequest("right", 16), blocked_short_route(),
                 num_candidates=M, generator=2)
    assert np.array_equal(trajs, same.trajectories)  # the CLI runs exactly the library's SVDD
    assert np.allclose(report["values"], same.values)
    assert (tmp_path / "steered.png").stat().st_size > 1000


def test_a_temperature_per_particle_matches_the_uniform_ones(policy):
    value = value_function([proximity_cost(np.array([[0.5, 0.5]]), BETA)], GAMMA, tol=0.1)
    greedy = steer(policy, SteerRequest("up", 4), value, num_candidates=4, alpha=0.0, generator=3)
    same = steer(policy, SteerRequest("up", 4), value,
                 num_candidates=4, alpha=[0.0] * 4, generator=3)
    np.testing.assert_array_equal(greedy.trajectories, same.trajectories)
    soft = steer(policy, SteerRequest("up", 4), value, num_candidates=4, alpha=0.7, generator=3)
    same = steer(policy, SteerRequest("up", 4), value,
                 num_candidates=4, alpha=np.full(4, 0.7), generator=3)
    np.testing.assert_array_equal(soft.trajectories, same.trajectories)
    with pytest.raises(ValueError, match="one per particle"):
        steer(policy, SteerRequest("up", 4), value, alpha=[0.0, 1.0], generator=3)
    with pytest.raises(ValueError, match="alpha"):
        steer(policy, SteerRequest("up", 2), value, alpha=[0.0, -1.0], generator=3)


def test_particle_temperatures_keep_greedy_particles_first():
    from rapidds.motion.steering import particle_temperatures

    assert particle_temperatures(1, 0.5).tolist() == [0.0]  # one particle stays greedy
    assert particle_temperatures(2, 0.5).tolist() == [0.0, 1.0]
    assert particle_temperatures(4, 0.5).tolist() == [0.0, 0.0, 1.0, 0.5]
    assert particle_temperatures(4, 0.0).tolist() == [0.0] * 4  # the authors' SVDD-PM
    assert particle_temperatures(4, 1.0).tolist()[0] == 0.0  # at least one greedy particle
