"""The device option: one definition shared by every command that loads a policy, checked
before anything loads; the device is a run setting that is never stored, so records, stored
settings and ``--resume`` do not depend on it."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from cli_helpers import run_main

from rapidds.loop.config import DEVICE_HELP, RunConfig
from rapidds.loop.run import AdaptiveRun, load_policy
from rapidds.store import RunStore
from rapidds.worlds.registry import make_world

# every command that loads a policy, with the arguments it needs to get as far as its options
COMMANDS = [
    ["run", "fetch", "--cycles", "1"],
    ["ablation", "--out", "{tmp}/ab", "--trials", "1", "--workers", "1"],
    ["case-study", "painting", "--out", "{tmp}/cs"],
    ["play"],
    ["study", "simulate", "--out", "{tmp}/st"],
    ["deploy", "painting", "--out", "{tmp}/dp"],
    ["observe", "{tmp}/ob", "--bag", "{tmp}/bag"],
    # the two whose default is the config's or checkpoint's own device: checked as early
    ["train-policy", "--world", "painting", "--out", "{tmp}/tp", "--steps", "1"],
    ["sample", "--policy", "{tmp}/none", "--task", "x"],
]


def _one_line(code: int, err: str, *needles: str) -> None:
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("rapidds: error: "), err
    assert "Traceback" not in err
    for n in needles:
        assert n in err, err


@pytest.mark.parametrize("args", COMMANDS, ids=lambda a: a[0] + (a[1] if a[0] == "study" else ""))
def test_an_unknown_device_is_one_line_exit_2(capsys, tmp_path, args):
    code, _, err = run_main(capsys, *[a.format(tmp=tmp_path) for a in args], "--device", "tpu")
    _one_line(code, err, "--device", "one of auto, cpu, cuda")
    assert not any(tmp_path.iterdir())  # refused before any folder was made


@pytest.mark.parametrize("args", COMMANDS, ids=lambda a: a[0] + (a[1] if a[0] == "study" else ""))
def test_cuda_without_a_gpu_is_one_line_exit_2(capsys, tmp_path, args):
    from rapidds.cli._device import check_device

    if torch.cuda.is_available():  # a machine with a GPU: the option is accepted
        assert check_device("cuda") == "cuda"
        return
    code, _, err = run_main(capsys, *[a.format(tmp=tmp_path) for a in args], "--device", "cuda")
    _one_line(code, err, "--device", "no CUDA GPU")
    assert not any(tmp_path.iterdir())


def test_the_device_is_a_setting_never_stored():
    cfg = RunConfig(world="fetch", device="cpu")
    assert cfg.device == "cpu" and "device" not in cfg.model_dump()
    resolved = cfg.resolved(make_world("fetch"))
    assert resolved.device == "cpu"  # replace() keeps a field the dumps leave out
    assert RunConfig(**resolved.model_dump()).device == "auto"
    assert RunConfig.model_fields["device"].description == DEVICE_HELP  # the CLI's help too


def test_a_run_resumes_on_another_device(tmp_path):
    """Stored on one device, continued on another: the stored settings hold no device, so the
    resume is not refused and the cycle count carries on."""
    world = make_world("fetch")
    policy = load_policy(world, device="cpu")
    assert policy.device.type == "cpu"
    base = dict(world="fetch", cycles=2, population=4, generations=2, samples=4, particles=1,
                candidates=2)
    with RunStore(tmp_path / "run.sqlite") as store:
        run = AdaptiveRun(RunConfig(**base, device="auto"), policy, store, world=world)
        run.step()
        stored = store.run_config(run.config.run_id)
        assert stored is not None and "device" not in stored
    with RunStore(tmp_path / "run.sqlite") as store:
        again = AdaptiveRun(RunConfig(**base, device="cpu"), policy, store, world=world)
        assert again.next_cycle == 1 and again.config.device == "cpu"


def test_a_run_resumes_only_with_the_network_it_began_with(tmp_path, capsys):
    """A stored run keeps its network's fingerprint (weights and normaliser): another network
    is refused (one line, exit 2, at the CLI) and nothing is written; the same one, loaded
    anew, resumes."""
    from rapidds.errors import StateError

    world = make_world("fetch")
    policy = load_policy(world, device="cpu")
    other = load_policy(world, device="cpu")
    with torch.no_grad():
        next(other.model.parameters()).add_(1e-3)
    mine = policy.fingerprint()
    assert other.fingerprint() != mine == load_policy(world, device="cpu").fingerprint()
    assert policy.with_sampler("ddpm").fingerprint() == mine  # the sampler is a run setting
    base = dict(world="fetch", cycles=2, population=4, generations=2, samples=4, particles=1,
                candidates=2)
    out = tmp_path / "out"
    out.mkdir()
    with RunStore(out / "run.sqlite") as store:
        AdaptiveRun(RunConfig(**base), policy, store, world=world).step()
    with RunStore(out / "run.sqlite") as store:
        with pytest.raises(StateError, match=f"another network \\(fingerprint {mine}"):
            AdaptiveRun(RunConfig(**base), other, store, world=world)
        assert store.last_cycle(RunConfig(**base).resolved(world).run_id) == 0
    other.save(tmp_path / "other")
    flags = [f"--{k}={v}" for k, v in base.items() if k != "world"]
    code, _, err = run_main(capsys, "run", "fetch", *flags, "--out", str(out), "--resume",
                            "--policy", str(tmp_path / "other"))
    _one_line(code, err, "planned with another network", mine)
    with RunStore(out / "run.sqlite") as store:
        assert AdaptiveRun(RunConfig(**base), policy, store, world=world).next_cycle == 1


# -- steering and training on the device: what the CPU can check ------------------------------
@pytest.fixture(scope="module")
def toy() -> tuple:
    """A tiny two-route policy trained in float32 and in bfloat16 autocast (the GPU's mixed
    precision, run here on the CPU), with their histories."""
    from rapidds.motion.config import DiffusionConfig
    from rapidds.motion.demos import two_route_demos
    from rapidds.motion.train import train_policy

    demos, _ = two_route_demos(n_per_route=32, seed=0)
    cfg = DiffusionConfig(horizon=16, state_dim=2, task_names=demos.task_names,
                          down_dims=(32, 64), step_embed_dim=32, num_train_timesteps=50,
                          num_inference_steps=10, steps=200, batch_size=64, lr=4e-3,
                          device="cpu")
    fp32 = train_policy(demos, cfg)
    bf16 = train_policy(demos, cfg, mixed_precision=True)
    return fp32, bf16


def test_steering_on_the_device_chooses_as_on_the_host(toy):
    """The paper's V as a tensor value (computed where the policy is, no host copy inside the
    loop) steers to the same trajectories as the same V on numpy arrays, on the same seed."""
    from rapidds.motion.steering import (
        SteerRequest,
        TensorValue,
        proximity_cost,
        steer,
        value_function,
    )

    (policy, _), _ = toy
    person = np.stack([np.full(7, 0.5), np.linspace(-0.3, 0.0, 7)], axis=-1)
    on_device = value_function([proximity_cost(person, 2.0)], 20.0, tol=0.15)
    assert isinstance(on_device, TensorValue)

    def on_host(xi: np.ndarray) -> np.ndarray:
        assert isinstance(xi, np.ndarray)
        return on_device(xi)

    a = steer(policy, SteerRequest("right", 16), on_device,
              num_candidates=4, alpha=[0.0] * 8 + [0.7] * 8, generator=3)
    b = steer(policy, SteerRequest("right", 16), on_host,
              num_candidates=4, alpha=[0.0] * 8 + [0.7] * 8, generator=3)
    assert np.array_equal(a.trajectories, b.trajectories)
    np.testing.assert_allclose(a.values, b.values, rtol=1e-12)
    assert a.stats.kept_value == pytest.approx(b.stats.kept_value, rel=1e-12)
    torch_values = on_device(torch.as_tensor(a.trajectories))
    np.testing.assert_allclose(torch_values.numpy(), a.values, rtol=1e-12)


def test_a_tensor_value_of_the_wrong_shape_is_refused(toy):
    from rapidds.motion.steering import SteerRequest, steer, tensor_value

    (policy, _), _ = toy
    with pytest.raises(ValueError, match="shape"):
        steer(policy, SteerRequest("right", 4), tensor_value(lambda xi: xi.sum(dim=1)),
              num_candidates=2, generator=0)


def test_mixed_precision_training_keeps_the_checkpoint_and_the_loss(toy, tmp_path):
    """bfloat16 autocast (mixed_precision) trains to a loss no worse than float32's at equal
    steps (within a quarter), and writes the same float32 checkpoint, which loads."""
    from rapidds.motion.policy import DiffusionPolicy

    (_, h32), (p16, h16) = toy
    assert h16.steps == h32.steps == len(h16.loss) == 200
    assert h16.mean_loss(last=40) <= 1.25 * h32.mean_loss(last=40)
    assert h16.mean_loss(last=40) < 0.5 * h16.mean_loss(first=20)
    p16.save(tmp_path / "p")
    back = DiffusionPolicy.load(tmp_path / "p", device="cpu")
    assert all(v.dtype == torch.float32 for v in back.model.state_dict().values())
    assert all(torch.equal(v, p16.model.state_dict()[k])
               for k, v in back.model.state_dict().items())
    assert back.sample("right", 2, generator=0).shape == (2, 16, 2)


def test_a_captured_training_step_is_a_gpu_matter_only():
    """``cuda_graph`` asks for a captured optimiser step on a GPU; on the CPU it changes
    nothing (the same bits), and the history says no graph ran."""
    from rapidds.motion.config import DiffusionConfig
    from rapidds.motion.demos import two_route_demos
    from rapidds.motion.train import train_policy

    demos, _ = two_route_demos(n_per_route=8, seed=0)
    cfg = DiffusionConfig(horizon=16, state_dim=2, task_names=demos.task_names,
                          down_dims=(8, 16), step_embed_dim=8, num_train_timesteps=20,
                          num_inference_steps=5, steps=6, batch_size=8, device="cpu")
    (plain, hp), (asked, ha) = train_policy(demos, cfg), train_policy(demos, cfg,
                                                                      cuda_graph=True)
    assert hp.loss == ha.loss
    assert not ha.cuda_graph and ha.graph_note == ""
    assert all(torch.equal(v, asked.model.state_dict()[k])
               for k, v in plain.model.state_dict().items())


def test_a_tensor_value_sees_tensors_and_a_diverged_policy_still_stops(toy):
    """On the device path the value gets tensors (never a host array), and samples holding NaN
    stop the steering as on the host path: checked once, after the loop."""
    import copy

    from rapidds.errors import CheckpointError
    from rapidds.motion.steering import SteerRequest, steer, tensor_value

    (policy, _), _ = toy
    seen: list[type] = []

    def value(xi: torch.Tensor) -> torch.Tensor:
        seen.append(type(xi))
        return xi[:, -1, 0]

    steer(policy, SteerRequest("right", 4), tensor_value(value), num_candidates=2, generator=0)
    assert seen and all(t is torch.Tensor for t in seen)
    broken = copy.deepcopy(policy)
    with torch.no_grad():
        next(iter(broken.model.parameters())).fill_(float("nan"))
    with pytest.raises(CheckpointError, match="non-finite"):
        steer(broken, SteerRequest("right", 4), tensor_value(value), num_candidates=2, generator=0)


@pytest.mark.parametrize("on_device", [None, True], ids=["host path", "device path"])
def test_the_warm_up_leaves_the_records_as_they_were(fetch_policy, monkeypatch, on_device):
    """A run made on a GPU steers one tiny batch first, so the first cycle does not load the
    kernels while the person waits. Forced here on the CPU (where a run does not warm up),
    under the monitor so that the hold's terms warm up too: the records are a cold run's."""
    from conftest import SMALL_SEARCH
    from record_helpers import decided

    from rapidds.motion.diffusion_motion import DiffusionMotion

    monkeypatch.setattr(DiffusionMotion, "default_on_device", on_device)
    cfg = RunConfig(human="slow-middle", cycles=2, seed=3, execution="reactive",
                    **SMALL_SEARCH)
    cold = AdaptiveRun(cfg, fetch_policy).run()
    calls = []
    real = DiffusionMotion.plan

    def counted(self, requests):
        calls.append(list(requests))
        return real(self, requests)

    monkeypatch.setattr(DiffusionMotion, "plan", counted)
    warm = AdaptiveRun(cfg, fetch_policy)
    warm.warm_up()
    assert len(calls) == 1 and calls[0][0][1]  # one request, beside a person's task
    assert [decided(r) for r in warm.run()] == [decided(r) for r in cold]
