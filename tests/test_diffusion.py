"""Trajectory diffusion policy: config validation, normaliser, U-Net, demonstrations, training,
seeded sampling, checkpoints (bit-identical round trip; every kind of damage is one clear
CheckpointError), and the ``train-policy`` / ``sample`` commands."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file
from typer.testing import CliRunner

from rapidds.cli import _register, app
from rapidds.errors import CheckpointError, RapiddsError
from rapidds.motion.config import ConfigError, DiffusionConfig
from rapidds.motion.cuda_graphs import Replayed
from rapidds.motion.demos import DemonstrationError, Demonstrations, two_route_demos
from rapidds.motion.inference import FastUnet, mish
from rapidds.motion.normalizer import MinMaxNormalizer
from rapidds.motion.policy import CONFIG_FILE, WEIGHTS_FILE, DiffusionPolicy
from rapidds.motion.train import check_compatible, total_steps, train_policy
from rapidds.motion.unet import TemporalUnet1d

# Small enough to train in about a second on one busy core.
TINY = dict(down_dims=(16, 32), step_embed_dim=16, num_train_timesteps=50,
            num_inference_steps=8, batch_size=32, lr=3e-3, lr_warmup_steps=5, device="cpu")


def tiny_config(demos: Demonstrations, **changes) -> DiffusionConfig:
    fields = dict(TINY, horizon=demos.horizon, state_dim=demos.state_dim,
                  task_names=demos.task_names)
    fields.update(changes)
    return DiffusionConfig(**fields)


@pytest.fixture(scope="module")
def demos() -> Demonstrations:
    return two_route_demos(n_per_route=16, seed=0)[0]


@pytest.fixture(scope="module")
def trained(demos):
    """A tiny policy trained for 150 steps, and its history."""
    return train_policy(demos, tiny_config(demos, steps=150))


# -- config ---------------------------------------------------------------------------------
def test_config_defaults_are_valid_and_survive_json():
    cfg = DiffusionConfig(task_names=("a", "b"), start_conditioned=True)
    back = DiffusionConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert back == cfg
    assert isinstance(back.down_dims, tuple) and isinstance(back.task_names, tuple)
    assert cfg.cond_dim == 2 + cfg.state_dim


@pytest.mark.parametrize("field, value", [
    ("horizon", 12), ("horizon", 0), ("horizon", True), ("state_dim", 0),
    ("task_names", ()), ("task_names", ("a", "a")), ("task_names", ("a", " ")),
    ("task_names", "ab"), ("down_dims", ()), ("down_dims", (32, -64)),
    ("kernel_size", 4), ("n_groups", 3), ("step_embed_dim", 15),
    ("num_train_timesteps", 1), ("beta_schedule", "cosine"), ("beta_start", 0.5),
    ("sampler", "euler"), ("num_inference_steps", 0), ("num_inference_steps", 101),
    ("ddim_eta", -0.1), ("ddim_eta", 1.5), ("lr", 0.0), ("lr", float("nan")),
    ("weight_decay", -1.0), ("batch_size", 0), ("steps", 0), ("epochs", 0),
    ("lr_warmup_steps", -1), ("ema_decay", 1.0), ("seed", -1), ("device", "tpu"),
    ("cpu_threads", -2), ("use_ema", "yes"),
])
def test_config_rejects_bad_values(field, value):
    with pytest.raises(ConfigError, match=field) as info:
        DiffusionConfig(**{field: value})
    assert isinstance(info.value, ValueError) and isinstance(info.value, RapiddsError)
    assert "\n" not in str(info.value)


def test_config_horizon_must_fit_the_unet_levels():
    with pytest.raises(ConfigError, match="divisible"):
        DiffusionConfig(horizon=8, down_dims=(8, 16, 32, 64, 128))
    DiffusionConfig(horizon=16, down_dims=(8, 16, 32, 64, 128))


def test_config_from_dict_rejects_unknown_fields():
    with pytest.raises(ConfigError, match="hroizon"):
        DiffusionConfig.from_dict({"hroizon": 16})


# -- normaliser -----------------------------------------------------------------------------
def test_normaliser_maps_to_unit_box_and_back():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 16, 3)) * [1.0, 10.0, 0.01] + [5.0, -3.0, 100.0]
    norm = MinMaxNormalizer.fit(pts)
    n = norm.normalize(pts)
    assert np.allclose(n.reshape(-1, 3).min(0), -1) and np.allclose(n.reshape(-1, 3).max(0), 1)
    assert np.allclose(norm.unnormalize(n), pts)
    t = torch.as_tensor(pts, dtype=torch.float32)
    assert torch.allclose(norm.unnormalize(norm.normalize(t)), t, atol=1e-4)


def test_normaliser_constant_dimension_maps_to_zero_and_back():
    pts = np.stack([np.linspace(0, 1, 20), np.full(20, 3.5)], axis=-1)
    norm = MinMaxNormalizer.fit(pts)
    n = norm.normalize(pts)
    assert np.all(np.isfinite(n)) and np.all(n[:, 1] == 0)
    assert np.array_equal(norm.unnormalize(n)[:, 1], pts[:, 1])


def test_normaliser_state_round_trip_is_exact():
    norm = MinMaxNormalizer.fit(np.random.default_rng(1).normal(size=(30, 2)) / 3)
    back = MinMaxNormalizer.from_state_dict(json.loads(json.dumps(norm.state_dict())))
    assert back == norm and np.array_equal(back.half_range, norm.half_range)
    other = MinMaxNormalizer(np.zeros(2), np.ones(2))
    other.load_state_dict(norm.state_dict())
    assert other == norm
    with pytest.raises(ValueError, match="d=2"):
        norm.normalize(np.zeros((4, 3)))


# -- U-Net ----------------------------------------------------------------------------------
@pytest.mark.parametrize("horizon, d, dims, start", [
    (16, 2, (16, 32), False), (32, 7, (16, 32, 64), True), (8, 1, (8,), False),
])
def test_unet_maps_trajectories_to_noise_of_the_same_shape(horizon, d, dims, start):
    cfg = DiffusionConfig(horizon=horizon, state_dim=d, down_dims=dims, n_groups=8,
                          task_names=("a", "b", "c"), start_conditioned=start,
                          step_embed_dim=16)
    net = TemporalUnet1d(cfg)
    x = torch.randn(5, horizon, d)
    out = net(x, torch.randint(0, 100, (5,)), torch.randn(5, cfg.cond_dim))
    assert out.shape == (5, horizon, d)
    with pytest.raises(ValueError, match="cond"):
        net(x, torch.zeros(5, dtype=torch.long), torch.randn(5, cfg.cond_dim + 1))


def test_unet_output_depends_on_step_and_condition():
    torch.manual_seed(0)
    cfg = DiffusionConfig(down_dims=(16, 32), step_embed_dim=16, task_names=("a", "b"))
    net = TemporalUnet1d(cfg).eval()
    x = torch.randn(1, 16, 2)
    a, b = torch.tensor([[1.0, 0.0]]), torch.tensor([[0.0, 1.0]])
    t3, t40 = torch.tensor([3]), torch.tensor([40])
    assert not torch.allclose(net(x, t3, a), net(x, t3, b))
    assert not torch.allclose(net(x, t3, a), net(x, t40, a))


# -- inference copy of the U-Net -------------------------------------------------------------
def test_fast_mish_is_mish_everywhere():
    x = torch.cat([torch.linspace(-200.0, 200.0, 40001), torch.randn(10000) * 3])
    fast = mish(x)
    assert torch.isfinite(fast).all()
    assert torch.allclose(fast, torch.nn.functional.mish(x), rtol=1e-6, atol=2e-6)
    assert torch.equal(x, torch.cat([torch.linspace(-200.0, 200.0, 40001), x[40001:]]))


@pytest.mark.parametrize("horizon, d, dims, start, kernel", [
    (16, 2, (16, 32), False, 5), (32, 7, (16, 32, 64), True, 3), (8, 1, (8,), False, 5),
    (64, 2, (16, 32, 64), False, 5),
])
def test_fast_unet_computes_the_training_network(horizon, d, dims, start, kernel):
    cfg = DiffusionConfig(horizon=horizon, state_dim=d, down_dims=dims, n_groups=8,
                          task_names=("a", "b", "c"), start_conditioned=start,
                          step_embed_dim=16, kernel_size=kernel)
    torch.manual_seed(1)
    net = TemporalUnet1d(cfg).eval()
    with torch.no_grad():  # non-zero biases everywhere, so none of them can be dropped silently
        for p in net.parameters():
            p.add_(0.1 * torch.randn_like(p))
    fast = FastUnet(net)
    native = FastUnet(net, native_mish=True)  # a GPU's choice, computed here on the CPU
    assert fast.act is mish and native.act is torch.nn.functional.mish
    assert FastUnet(copy.deepcopy(net).to("meta")).act is torch.nn.functional.mish  # off the CPU
    x, cond = torch.randn(6, horizon, d), torch.randn(6, cfg.cond_dim)
    with torch.no_grad():
        for t in (torch.randint(0, 100, (6,)), torch.full((6,), 37), torch.tensor(5)):
            ref = net(x, t, cond)
            assert torch.allclose(fast(x, t, cond), ref, rtol=1e-5, atol=1e-5)
            assert torch.allclose(native(x, t, cond), ref, rtol=1e-5, atol=1e-5)
        one = fast(x[:1], torch.tensor([9]), cond[:1])
        assert torch.allclose(one, net(x[:1], torch.tensor([9]), cond[:1]), atol=1e-5)
    with pytest.raises(ValueError, match="cond"):
        fast(x, torch.zeros(6, dtype=torch.long), torch.randn(6, cfg.cond_dim + 1))
    with pytest.raises(TypeError, match="TemporalUnet1d"):
        FastUnet(torch.nn.Linear(2, 2))


def test_a_sampling_pass_is_one_a_cuda_graph_can_capture():
    """What capture needs, checked where there is no GPU: on the meta device (shapes, no
    data) a pass whose batch shares one step, as sampling's do, reads nothing back to the host
    and makes no tensor of host data, either of which would fail here as it fails capture. A
    per-row step is read on the host, so sampling passes one step for the batch."""
    cfg = DiffusionConfig(horizon=16, state_dim=2, down_dims=(16, 32), task_names=("a", "b"),
                          step_embed_dim=16)
    net = TemporalUnet1d(cfg).eval().to("meta")
    x, cond = torch.empty(6, 16, 2, device="meta"), torch.empty(6, cfg.cond_dim, device="meta")
    step = torch.full((), 5, dtype=torch.long, device="meta")
    for native in (False, True):
        out = FastUnet(net, native_mish=native)(x, step, cond)
        assert out.shape == x.shape and out.device.type == "meta"
    with pytest.raises(RuntimeError, match="meta"):
        FastUnet(net)(x, torch.full((6,), 5, dtype=torch.long, device="meta"), cond)


def test_replayed_passes_off_a_gpu_are_the_networks(trained):
    policy, _ = trained
    ref = policy.sample(["right", "up"] * 4, 8, generator=3)
    assert policy.cuda_graphs  # the default: only a GPU captures, the CPU runs the passes
    try:
        assert np.array_equal(policy.sample(["right", "up"] * 4, 8, generator=3), ref)
        assert policy.with_sampler("ddpm").cuda_graphs  # a sampler is a run setting, this isn't
        replayed = Replayed(policy.denoiser(), capture_at=1)
        x, t, cond = torch.randn(4, 16, 2), torch.tensor(20), policy.condition("right", 4)
        for _ in range(3):
            assert torch.equal(replayed(x, t, cond), policy.denoiser()(x, t, cond))
        assert replayed.graphs == {} and replayed.seen and replayed.note == ""
        with pytest.raises(ValueError, match="cond"):
            replayed(x, t, cond[:, :-1])
        assert policy.graph_notes == {}
        policy.cuda_graphs = False
        assert np.array_equal(policy.sample(["right", "up"] * 4, 8, generator=3), ref)
        assert not policy.with_sampler("ddpm").cuda_graphs
    finally:
        policy.cuda_graphs = True


def test_policy_denoiser_follows_the_weights(trained):
    policy, _ = trained
    copy = DiffusionPolicy.from_config(policy.config, policy.normalizer)
    copy.model.load_state_dict(policy.model.state_dict())
    x, t = torch.randn(4, 16, 2), torch.full((4,), 20)
    cond = copy.condition("right", 4)
    first = copy.denoiser()
    assert isinstance(first, FastUnet) and copy.denoiser() is first  # built once, then reused
    before = first(x, t, cond)
    with torch.no_grad():  # an in-place change, as an optimiser step makes
        next(copy.model.parameters()).mul_(1.5)
    after = copy.denoiser()
    assert after is not first and not torch.allclose(after(x, t, cond), before)
    with torch.no_grad():
        assert torch.allclose(after(x, t, cond), copy.model(x, t, cond), atol=1e-5)
    copy.model.load_state_dict(policy.model.state_dict())  # copies in place: rebuilt again
    assert torch.allclose(copy.denoiser()(x, t, cond), before)
    assert copy.denoiser().act is mish
    copy.native_mish = True  # rebuilt with PyTorch's Mish, the same function
    assert copy.denoiser().act is torch.nn.functional.mish
    assert torch.allclose(copy.denoiser()(x, t, cond), before, atol=1e-5)
    copy.fast_inference = False
    assert copy.denoiser() is copy.model


def test_fast_sampling_matches_the_reference_network(trained):
    policy, _ = trained
    fast = policy.sample(["right", "up"] * 4, 8, generator=3)
    policy.fast_inference = False
    try:
        ref = policy.sample(["right", "up"] * 4, 8, generator=3)
    finally:
        policy.fast_inference = True
    assert np.allclose(fast, ref, atol=1e-4) and not np.array_equal(fast, ref)


def test_sampling_steps_can_be_overridden(trained):
    policy, _ = trained
    assert len(policy.timesteps(3)) == 3 and len(policy.timesteps()) == 8
    assert not np.allclose(policy.sample("right", 4, generator=1, num_steps=3),
                           policy.sample("right", 4, generator=1))
    for bad in (0, 51, 2.5, True):
        with pytest.raises(ValueError, match="num_steps"):
            policy.sample("right", 2, num_steps=bad)


# -- demonstrations -------------------------------------------------------------------------
def test_demonstrations_round_trip_and_resample(tmp_path, demos):
    path = demos.save(tmp_path / "demos.npz")
    back = Demonstrations.load(path)
    assert np.array_equal(back.trajectories, demos.trajectories)
    assert np.array_equal(back.task_index, demos.task_index)
    assert back.task_names == ("right", "up") and back.start is None
    longer = Demonstrations.load(path, horizon=32)
    assert longer.horizon == 32
    assert np.allclose(longer.trajectories[:, [0, -1]], demos.trajectories[:, [0, -1]])


def _write_npz(path: Path, **arrays) -> Path:
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize("change, message", [
    ({"trajectories": np.zeros((4, 12, 2))}, "multiple of 8"),
    ({"trajectories": np.full((4, 16, 2), np.nan)}, "NaN"),
    ({"trajectories": np.zeros((4, 16))}, r"\(N, H, d\)"),
    ({"task_index": np.array([0, 1, 2, 0])}, "0..1"),
    ({"task_index": np.array([0, 1])}, "shape"),
    ({"task_names": np.array(["a", "a"])}, "unique"),
    ({"start": np.zeros((4, 3))}, "start"),
    ({"extra": np.zeros(3)}, "unknown"),
])
def test_bad_demonstrations_raise_one_clear_line(tmp_path, change, message):
    arrays = {"trajectories": np.zeros((4, 16, 2)), "task_index": np.array([0, 1, 0, 1]),
              "task_names": np.array(["a", "b"])}
    arrays.update(change)
    path = _write_npz(tmp_path / "d.npz", **arrays)
    with pytest.raises(DemonstrationError, match=message) as info:
        Demonstrations.load(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_unreadable_demonstration_files(tmp_path):
    with pytest.raises(DemonstrationError, match="does not exist"):
        Demonstrations.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip at all")
    with pytest.raises(DemonstrationError, match="readable"):
        Demonstrations.load(tmp_path / "junk.npz")
    partial = _write_npz(tmp_path / "p.npz", trajectories=np.zeros((2, 16, 2)))
    with pytest.raises(DemonstrationError, match="missing"):
        Demonstrations.load(partial)


# -- training -------------------------------------------------------------------------------
def test_training_reduces_the_loss(trained):
    _, history = trained
    assert history.steps == len(history.loss) == 150
    assert history.mean_loss(last=15) < 0.5 * history.mean_loss(first=15)


def test_training_is_deterministic_with_the_seed(demos):
    cfg = tiny_config(demos, steps=4)
    a, _ = train_policy(demos, cfg)
    b, _ = train_policy(demos, cfg)
    c, _ = train_policy(demos, cfg.replace(seed=1))
    sa, sb, sc = (p.model.state_dict() for p in (a, b, c))
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert not all(torch.equal(sa[k], sc[k]) for k in sa)


def test_training_checks_the_demonstrations_fit_the_config(demos):
    with pytest.raises(ConfigError, match="horizon"):
        check_compatible(demos, tiny_config(demos, horizon=32))
    with pytest.raises(ConfigError, match="task"):
        train_policy(demos, tiny_config(demos, task_names=("up", "right")))
    assert total_steps(len(demos), tiny_config(demos, epochs=3)) == 3 * 2  # 64 demos, batch 32


def _teacher_gap(student: DiffusionPolicy, teacher: DiffusionPolicy, demos) -> float:
    """Mean squared gap between the two networks' noise predictions on noisy demonstrations
    drawn apart from training's (another seed)."""
    batch = {"trajectory": torch.as_tensor(demos.trajectories, dtype=torch.float32),
             "task_index": torch.as_tensor(demos.task_index)}
    gen = torch.Generator().manual_seed(123)
    with torch.no_grad():
        return float(student.compute_loss(batch, generator=gen, teacher=teacher.model))


def test_a_distilled_student_learns_its_teachers_function(demos, trained):
    teacher, _ = trained
    small = tiny_config(demos, down_dims=(8, 16), steps=150)
    student, history = train_policy(demos, small, teacher=teacher)
    scratch, _ = train_policy(demos, small)
    assert student.config.down_dims == (8, 16)
    assert np.array_equal(student.normalizer.low, teacher.normalizer.low)
    assert history.mean_loss(last=15) < 0.5 * history.mean_loss(first=15)
    # the same steps with the drawn noise as target (the same seed: the same batches, noise
    # and init, so a teacher left unused would give this very network) end further from it
    assert _teacher_gap(student, teacher, demos) < _teacher_gap(scratch, teacher, demos)


def test_a_teacher_of_another_forward_process_is_refused(demos, trained):
    teacher, _ = trained
    with pytest.raises(ConfigError, match="teacher has num_train_timesteps 50, the student 60"):
        train_policy(demos, tiny_config(demos, num_train_timesteps=60, steps=2), teacher=teacher)


def test_start_conditioned_policy_trains_and_needs_a_start(demos):
    starts = demos.trajectories[:, 0] + np.random.default_rng(0).normal(0, 0.05, (len(demos), 2))
    with_start = Demonstrations(demos.trajectories, demos.task_index, demos.task_names, starts)
    policy, history = train_policy(with_start, tiny_config(demos, steps=3,
                                                           start_conditioned=True))
    assert np.isfinite(history.loss).all()
    out = policy.sample("right", 3, start=np.array([0.0, 0.0]), generator=0)
    assert out.shape == (3, 16, 2)
    per_sample = policy.sample("right", 2, start=np.zeros((2, 2)), generator=0)
    assert per_sample.shape == (2, 16, 2)
    with pytest.raises(CheckpointError, match="start"):
        policy.sample("right", 3, generator=0)


# -- sampling -------------------------------------------------------------------------------
def test_sampling_is_deterministic_with_a_seed(trained):
    policy, _ = trained
    a = policy.sample("right", 6, generator=7)
    assert a.shape == (6, 16, 2) and a.dtype == np.float64
    assert np.array_equal(a, policy.sample("right", 6, generator=7))
    assert np.array_equal(a, policy.sample("right", 6, generator=torch.Generator().manual_seed(7)))
    assert not np.allclose(a, policy.sample("right", 6, generator=8))


def test_sampling_is_conditioned_on_the_task(trained):
    policy, _ = trained
    mixed = policy.sample(["right", "up"] * 16, 32, generator=0)
    ends = mixed[:, -1]
    # 'right' ends near (1, 0), 'up' near (0, 1): the one-hot steers the goal.
    assert np.mean(ends[0::2, 0] > ends[0::2, 1]) > 0.8
    assert np.mean(ends[1::2, 1] > ends[1::2, 0]) > 0.8


def test_sampling_rejects_unknown_tasks_and_stray_starts(trained):
    policy, _ = trained
    with pytest.raises(CheckpointError, match="does not know task 'left'"):
        policy.sample("left", 2)
    with pytest.raises(CheckpointError, match="not start-conditioned"):
        policy.sample("right", 2, start=np.zeros(2))
    with pytest.raises(CheckpointError, match="3 task names for 2"):
        policy.sample(["right", "up", "up"], 2)


def test_ddpm_sampler_gives_valid_trajectories(trained):
    policy, _ = trained
    ddpm = DiffusionPolicy.from_config(policy.config.replace(sampler="ddpm"), policy.normalizer)
    ddpm.model.load_state_dict(policy.model.state_dict())
    out = ddpm.sample("right", 8, generator=0)
    assert np.isfinite(out).all() and np.array_equal(out, ddpm.sample("right", 8, generator=0))
    assert np.abs(out).max() < 2.0  # within the clipped, un-normalised workspace


# -- checkpoints ----------------------------------------------------------------------------
def test_checkpoint_round_trip_is_bit_identical(tmp_path, trained):
    policy, _ = trained
    policy.save(tmp_path / "ckpt")
    back = DiffusionPolicy.load(tmp_path / "ckpt", device="cpu")
    assert back.config == policy.config and back.normalizer == policy.normalizer
    sa, sb = policy.model.state_dict(), back.model.state_dict()
    assert sa.keys() == sb.keys()
    assert all(torch.equal(sa[k], sb[k]) and sa[k].dtype == sb[k].dtype for k in sa)
    assert np.array_equal(policy.sample("up", 5, generator=3), back.sample("up", 5, generator=3))
    meta = json.loads((tmp_path / "ckpt" / CONFIG_FILE).read_text())
    assert meta["format_version"] == 1 and len(meta["weights"]["sha256"]) == 64


@pytest.fixture
def ckpt(tmp_path, trained) -> Path:
    return trained[0].save(tmp_path / "ckpt")


def _edit_meta(ckpt: Path, edit) -> None:
    meta = json.loads((ckpt / CONFIG_FILE).read_text())
    edit(meta)
    (ckpt / CONFIG_FILE).write_text(json.dumps(meta))


def _load_error(path: Path) -> str:
    with pytest.raises(CheckpointError) as info:
        DiffusionPolicy.load(path, device="cpu")
    message = str(info.value)
    assert "\n" not in message
    return message


def test_missing_checkpoint_parts(tmp_path, ckpt):
    assert "does not exist" in _load_error(tmp_path / "nowhere")
    (tmp_path / "file").write_text("x")
    assert "not a directory" in _load_error(tmp_path / "file")
    (ckpt / WEIGHTS_FILE).unlink()
    assert f"missing {WEIGHTS_FILE}" in _load_error(ckpt)
    (ckpt / CONFIG_FILE).unlink()
    assert f"missing {CONFIG_FILE}" in _load_error(ckpt)


def test_corrupt_json(ckpt):
    (ckpt / CONFIG_FILE).write_text('{"format": "rapidds.diffusion_policy", ')
    assert "corrupt JSON" in _load_error(ckpt)


def test_unknown_format_and_version(ckpt):
    _edit_meta(ckpt, lambda m: m.update(format_version=2))
    assert "unknown checkpoint format version 2" in _load_error(ckpt)
    _edit_meta(ckpt, lambda m: m.update(format="something.else"))
    assert "not a rapidds diffusion policy" in _load_error(ckpt)


def test_invalid_config_inside_checkpoint(ckpt):
    _edit_meta(ckpt, lambda m: m["config"].update(horizon=12))
    assert "horizon" in _load_error(ckpt)
    _edit_meta(ckpt, lambda m: m["config"].update(horizon=16))
    _edit_meta(ckpt, lambda m: m.pop("normalizer"))
    assert "normalizer" in _load_error(ckpt)


def test_truncated_weights_fail_the_checksum(ckpt):
    w = ckpt / WEIGHTS_FILE
    w.write_bytes(w.read_bytes()[:-100])
    assert "checksum mismatch" in _load_error(ckpt)


def test_flipped_byte_fails_the_checksum(ckpt):
    w = ckpt / WEIGHTS_FILE
    data = bytearray(w.read_bytes())
    data[-5] ^= 0xFF
    w.write_bytes(bytes(data))
    assert "checksum mismatch" in _load_error(ckpt)


def _rehash(ckpt: Path) -> None:
    import hashlib

    digest = hashlib.sha256((ckpt / WEIGHTS_FILE).read_bytes()).hexdigest()
    _edit_meta(ckpt, lambda m: m["weights"].update(sha256=digest))


def test_corrupt_safetensors_with_matching_checksum(ckpt):
    w = ckpt / WEIGHTS_FILE
    w.write_bytes(w.read_bytes()[:-100])
    _rehash(ckpt)
    assert "corrupt safetensors" in _load_error(ckpt)


def test_weights_that_do_not_fit_the_config(ckpt):
    _edit_meta(ckpt, lambda m: m["config"].update(kernel_size=3))
    assert "shape mismatch" in _load_error(ckpt)
    _edit_meta(ckpt, lambda m: m["config"].update(kernel_size=5))
    tensors = load_file(str(ckpt / WEIGHTS_FILE))
    tensors.pop(sorted(tensors)[0])
    save_file(tensors, str(ckpt / WEIGHTS_FILE))
    _rehash(ckpt)
    assert "do not fit the config" in _load_error(ckpt)


# -- command line ---------------------------------------------------------------------------
def _cli(*args: str):
    _register()
    return CliRunner().invoke(app, list(args))


def test_cli_trains_and_samples(tmp_path, demos):
    demo_file = demos.save(tmp_path / "demos.npz")
    cfg_file = tmp_path / "small.json"
    cfg_file.write_text(json.dumps({k: v for k, v in TINY.items() if k != "device"}))
    out = tmp_path / "policy"
    result = _cli("train-policy", "--demos", str(demo_file), "--out", str(out), "--steps", "6",
                  "--config", str(cfg_file), "--device", "cpu")
    assert result.exit_code == 0, result.output
    assert f"wrote policy to {out}" in result.stdout
    policy = DiffusionPolicy.load(out)
    assert policy.config.steps == 6 and policy.config.down_dims == (16, 32)

    result = _cli("sample", "--policy", str(out), "--task", "up", "-n", "3", "--seed", "4",
                  "--json", "--out", str(tmp_path / "s.png"))
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert np.array_equal(np.array(report["trajectories"]), policy.sample("up", 3, generator=4))
    assert not report["steered"] and (tmp_path / "s.png").stat().st_size > 1000

    text = _cli("sample", "--policy", str(out), "--task", "up", "-n", "2")
    assert text.exit_code == 0 and "samples of task 'up'" in text.stdout


def test_cli_distils_a_teacher_into_a_smaller_network(tmp_path, demos, ckpt):
    demo_file = demos.save(tmp_path / "demos.npz")
    (tmp_path / "small.json").write_text(json.dumps({"down_dims": [8, 16]}))
    out = tmp_path / "student"
    result = _cli("train-policy", "--demos", str(demo_file), "--out", str(out), "--steps", "3",
                  "--teacher", str(ckpt), "--config", str(tmp_path / "small.json"))
    assert result.exit_code == 0, result.output
    student, teacher = DiffusionPolicy.load(out), DiffusionPolicy.load(ckpt)
    assert student.config.down_dims == (8, 16) and student.config.steps == 3
    assert student.config.num_train_timesteps == teacher.config.num_train_timesteps == 50

    other = _cli("train-policy", "--demos", str(demo_file), "--out", str(tmp_path / "x"),
                 "--teacher", str(ckpt), "--horizon", "32")
    assert other.exit_code == 2
    assert "teacher has horizon" in other.stderr and len(other.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("args, message", [
    (["sample", "--policy", "/nonexistent/ckpt", "--task", "up"], "does not exist"),
    (["train-policy", "--demos", "/nonexistent.npz", "--out", "x"], "does not exist"),
    (["sample", "--policy", "{ckpt}", "--task", "left"], "does not know task"),
    (["sample", "--policy", "{ckpt}", "--task", "up", "--steer-cost", "1,2,3"], "2 finite"),
])
def test_cli_bad_input_is_one_line_and_exit_2(ckpt, args, message):
    result = _cli(*[a.replace("{ckpt}", str(ckpt)) for a in args])
    assert result.exit_code == 2
    assert message in result.stderr and len(result.stderr.strip().splitlines()) == 1
