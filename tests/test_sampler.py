"""The cheaper sampler option (issue 36 item 3): DPM-Solver++ (2M, SDE) at few steps on the same
network, for sampling and SVDD steering; the paper's DDIM stays the default and a run without
``--sampler`` stores exactly what it stored before."""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import run_main
from diffusers import DPMSolverMultistepScheduler

from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.loop.run import load_policy
from rapidds.motion.config import ConfigError, DiffusionConfig
from rapidds.motion.demos import two_route_demos
from rapidds.motion.steering import SteerRequest, steer
from rapidds.motion.train import train_policy
from rapidds.store import RunStore
from rapidds.worlds.registry import make_world


@pytest.fixture(scope="module")
def policy():
    demos, _ = two_route_demos(n_per_route=16, seed=0)
    cfg = DiffusionConfig(horizon=16, state_dim=2, task_names=demos.task_names,
                          down_dims=(16, 32), step_embed_dim=16, num_train_timesteps=50,
                          num_inference_steps=8, steps=150, batch_size=32, lr=3e-3,
                          lr_warmup_steps=5, device="cpu")
    return train_policy(demos, cfg)[0]


def test_another_sampler_shares_the_network(policy):
    assert policy.with_sampler() is policy and policy.with_sampler("ddim") is policy
    dpm = policy.with_sampler("dpm", steps=4)
    assert dpm.model is policy.model and dpm.normalizer is policy.normalizer
    assert isinstance(dpm.noise_scheduler, DPMSolverMultistepScheduler)
    assert dpm.config.sampler == "dpm" and dpm.config.num_inference_steps == 4
    assert policy.config.sampler == "ddim"  # the original is untouched
    assert len(dpm.timesteps()) == 4
    with pytest.raises(ConfigError, match="sampler"):
        policy.with_sampler("euler")
    with pytest.raises(ConfigError, match="num_inference_steps"):
        policy.with_sampler("dpm", steps=51)


def test_dpm_samples_the_task_at_four_steps(policy):
    dpm = policy.with_sampler("dpm", steps=4)
    mixed = dpm.sample(["right", "up"] * 16, 32, generator=0)
    assert np.isfinite(mixed).all() and np.abs(mixed).max() < 2.0
    assert np.array_equal(mixed, dpm.sample(["right", "up"] * 16, 32, generator=0))
    assert not np.array_equal(mixed, dpm.sample(["right", "up"] * 16, 32, generator=1))
    ends = mixed[:, -1]  # 'right' ends near (1, 0), 'up' near (0, 1)
    assert np.mean(ends[0::2, 0] > ends[0::2, 1]) > 0.8
    assert np.mean(ends[1::2, 1] > ends[1::2, 0]) > 0.8


def test_dpm_steering_keeps_each_particle_in_its_row(policy):
    """The solver remembers the previous step's prediction per row: with one candidate,
    steering is plain sampling (the same draws), and with several it steers."""
    dpm = policy.with_sampler("dpm", steps=5)

    def height(xi: np.ndarray) -> np.ndarray:
        return xi[:, :, 1].mean(axis=1)  # lower is better: the 'right' route, low

    plain = steer(dpm, SteerRequest("right", 8), height, num_candidates=1, generator=4)
    assert np.array_equal(plain.trajectories, dpm.sample("right", 8, generator=4))
    steered = steer(dpm, SteerRequest("right", 8), height, num_candidates=8, generator=4)
    assert steered.values.mean() < plain.values.mean() - 0.01


def test_a_run_without_a_sampler_stores_no_sampler_and_resumes(tmp_path):
    world = make_world("fetch")
    base = dict(world="fetch", cycles=2, population=4, generations=2, samples=4, particles=1,
                candidates=2)
    assert "sampler" not in RunConfig(**base).model_dump()
    assert RunConfig(**base, sampler="dpm").model_dump()["sampler"] == "dpm"
    policy = load_policy(world, device="cpu")
    with RunStore(tmp_path / "run.sqlite") as store:
        run = AdaptiveRun(RunConfig(**base), policy, store, world=world)
        assert run.policy is policy
        run.step()
        stored = store.run_config(run.config.run_id)
        assert stored is not None and "sampler" not in stored
    with RunStore(tmp_path / "run.sqlite") as store:
        again = AdaptiveRun(RunConfig(**base), policy, store, world=world)
        assert again.next_cycle == 1
    fast = AdaptiveRun(RunConfig(**base, sampler="dpm", steps=4), policy, world=world)
    assert fast.policy.config.sampler == "dpm" and fast.policy.model is policy.model
    rec = fast.step().record
    assert np.isfinite(rec.realised.cost)


def test_an_unknown_sampler_is_one_line_exit_2(capsys, tmp_path):
    code, _, err = run_main(capsys, "run", "fetch", "--sampler", "euler", "--out",
                            str(tmp_path / "r"))
    assert code == 2 and err.count("\n") == 1 and "--sampler" in err, err
    assert not (tmp_path / "r").exists()
