"""Trajectory diffusion policy: a thin layer over an injected noise predictor, noise scheduler
and normaliser, with training loss, sampling, and a checked checkpoint format.

The policy owns no architecture decisions (the network and the ``diffusers`` scheduler are
passed in, as in Diffusion Policy); :meth:`DiffusionPolicy.from_config` builds the standard
ones. Everything the outside sees is in world units: trajectories are normalised on the way
in and un-normalised on the way out.

Checkpoint = a directory with ``model.safetensors`` (weights) and ``config.json`` (format name
and version, the :class:`DiffusionConfig`, the normaliser bounds and the SHA-256 of the weights
file). Loading checks all of it and raises :class:`~rapidds.errors.CheckpointError` with one
line on any mismatch, so a damaged file never turns into silently wrong motions.
"""

from __future__ import annotations

import hashlib
import json
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from diffusers import DDIMScheduler, DDPMScheduler
from safetensors.torch import load_file, save
from torch import Tensor, nn

from rapidds.errors import CheckpointError
from rapidds.fileio import atomic_write_bytes, atomic_write_text
from rapidds.motion.config import ConfigError, DiffusionConfig, resolve_device
from rapidds.motion.cuda_graphs import Replayed
from rapidds.motion.inference import FastUnet
from rapidds.motion.normalizer import MinMaxNormalizer
from rapidds.motion.unet import TemporalUnet1d

if TYPE_CHECKING:
    from typing import TypeAlias

    from diffusers import DPMSolverMultistepScheduler

    NoiseScheduler: TypeAlias = DDPMScheduler | DDIMScheduler | DPMSolverMultistepScheduler

FORMAT = "rapidds.diffusion_policy"
FORMAT_VERSION = 1
WEIGHTS_FILE = "model.safetensors"
CONFIG_FILE = "config.json"

GeneratorLike = torch.Generator | int | None
Denoiser = Callable[[Tensor, Tensor, Tensor], Tensor]
# DPM-Solver is imported where it is chosen: its module imports scipy.stats, 0.35-0.4 CPU s
# of every process that loads a policy
_DPM_MODULE = "diffusers.schedulers.scheduling_dpmsolver_multistep"


def _is_noise_scheduler(obj: object) -> bool:
    """Whether ``obj`` is one of the three schedulers (DPM-Solver only once its module is
    imported: nothing can be an instance of it before)."""
    dpm = sys.modules.get(_DPM_MODULE)
    return isinstance(obj, (DDPMScheduler, DDIMScheduler)) or (
        dpm is not None and isinstance(obj, dpm.DPMSolverMultistepScheduler))


def make_noise_scheduler(config: DiffusionConfig) -> NoiseScheduler:
    """The ``diffusers`` scheduler named by ``config.sampler``.

    DDPM and DDIM share the forward (noising) process, so the same object serves training
    (``add_noise``) and sampling (``step``). "trailing" spacing starts sampling at the last
    training step t = T-1, where the model saw pure noise.
    """
    kwargs: dict[str, Any] = dict(
        num_train_timesteps=config.num_train_timesteps,
        beta_schedule=config.beta_schedule,
        beta_start=config.beta_start,
        beta_end=config.beta_end,
        clip_sample=config.clip_sample,
        clip_sample_range=1.0,
        prediction_type="epsilon",
        timestep_spacing="trailing",
    )
    if config.sampler == "ddim":
        return DDIMScheduler(set_alpha_to_one=True, steps_offset=0, **kwargs)
    if config.sampler == "dpm":
        # DPM-Solver++(2M) in its SDE form: stochastic, so SVDD's candidates differ. Its one
        # step of memory (the previous prediction) stays right under steering, which keeps
        # each particle in its row. Thresholding with a maximum of 1 is clip_sample's clip of
        # the predicted clean sample to [-1, 1].
        from diffusers import DPMSolverMultistepScheduler

        clip = kwargs.pop("clip_sample")
        del kwargs["clip_sample_range"]
        return DPMSolverMultistepScheduler(
            algorithm_type="sde-dpmsolver++", solver_order=2, thresholding=clip,
            dynamic_thresholding_ratio=1.0, sample_max_value=1.0, **kwargs)
    return DDPMScheduler(variance_type="fixed_small", **kwargs)


def as_generator(generator: GeneratorLike, device: str | torch.device = "cpu"
                 ) -> torch.Generator | None:
    """A seed becomes a fresh generator on ``device`` (the CPU by default; the policy's device
    for sampling, so noise is drawn where it is used and never copied from the host); a
    generator or None passes through. The same seed gives the same numbers on the same
    device, other numbers on another."""
    if generator is None or isinstance(generator, torch.Generator):
        return generator
    if isinstance(generator, bool) or not isinstance(generator, int | np.integer):
        raise TypeError(f"generator must be a torch.Generator, an int seed or None, got "
                        f"{type(generator).__name__}")
    return torch.Generator(torch.device(device)).manual_seed(int(generator))


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


class DiffusionPolicy:
    """Samples robot trajectories xi ~ pi(task[, start]) of shape (H, d) in world units.

    config: the settings the components were built with (checked against them).
    model: noise predictor, forward(x (B, H, d), t (B,), cond (B, cond_dim)) -> (B, H, d).
    noise_scheduler: ``diffusers`` DDPMScheduler, DDIMScheduler or DPMSolverMultistepScheduler
    (epsilon prediction).
    normalizer: maps world units to the model's [-1, 1] and back.

    Sampling runs the network through :meth:`denoiser`: for a :class:`TemporalUnet1d` an
    inference copy (:class:`~rapidds.motion.inference.FastUnet`, the same function to float32
    rounding, 1.3x to 1.7x faster on CPU, more for larger batches). Set
    ``fast_inference = False`` to sample with ``model`` itself; training always uses ``model``.
    ``native_mish``: the copy's Mish (None: PyTorch's kernel off the CPU, the rewrite on it).
    ``cuda_graphs``: on a GPU, sampling's network passes (and the steering's on-device value)
    replay CUDA graphs (:class:`~rapidds.motion.cuda_graphs.Replayed`): on by default, since on
    an H200 they gave the eager records bit for bit and a steering batch in 0.053 s instead of
    0.093 (docs/benchmarks.md); nothing changes off a GPU. ``graph_notes``: why a capture
    failed, by what ("network", "value"), after which that part runs as it is.
    """

    def __init__(self, config: DiffusionConfig, model: nn.Module,
                 noise_scheduler: NoiseScheduler, normalizer: MinMaxNormalizer):
        if not _is_noise_scheduler(noise_scheduler):
            raise TypeError(f"noise_scheduler must be a diffusers DDPMScheduler, "
                            f"DDIMScheduler or DPMSolverMultistepScheduler, got "
                            f"{type(noise_scheduler).__name__}")
        sc = noise_scheduler.config
        if sc.num_train_timesteps != config.num_train_timesteps:
            raise ValueError(f"scheduler has {sc.num_train_timesteps} training steps, config "
                             f"{config.num_train_timesteps}")
        if sc.prediction_type != "epsilon":
            raise ValueError("the policy and SVDD steering need an epsilon-predicting scheduler")
        if normalizer.dim != config.state_dim:
            raise ValueError(f"normaliser has d={normalizer.dim}, config state_dim "
                             f"{config.state_dim}")
        self.config = config
        self.model = model
        self.noise_scheduler = noise_scheduler
        self.normalizer = normalizer
        self.fast_inference = True
        self.native_mish: bool | None = None
        self.cuda_graphs = True
        self.graph_notes: dict[str, str] = {}
        self._fast: tuple[tuple[object, ...], FastUnet] | None = None
        self._replayed: Replayed | None = None
        self._slots: tuple[nn.Module, list[tuple[dict[str, Any], str]]] | None = None

    @classmethod
    def from_config(cls, config: DiffusionConfig, normalizer: MinMaxNormalizer,
                    device: str | torch.device | None = None) -> DiffusionPolicy:
        """Standard components: :class:`TemporalUnet1d` initialised from ``config.seed`` (the
        global RNG is left untouched) and :func:`make_noise_scheduler`, on ``device`` (default
        ``config.device``)."""
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            model = TemporalUnet1d(config)
        policy = cls(config, model, make_noise_scheduler(config), normalizer)
        return policy.to(resolve_device(device, default=config.device))

    def with_sampler(self, sampler: str | None = None, steps: int | None = None
                     ) -> DiffusionPolicy:
        """This policy (the same network and weights, shared) sampling with another reverse
        kernel (``sampler``: "ddim", "ddpm" or "dpm"; None keeps its own) and, when given,
        ``steps`` reverse steps by default. The forward process is the one it was trained
        with, so any sampler applies; ``self`` when nothing changes."""
        if sampler is None and steps is None:
            return self
        changes: dict[str, Any] = {"sampler": sampler or self.config.sampler}
        if steps is not None:
            changes["num_inference_steps"] = steps
        try:
            config = DiffusionConfig.from_dict({**self.config.to_dict(), **changes})
        except (ConfigError, ValueError) as exc:
            raise ConfigError(f"sampler: {exc}") from None
        if config == self.config:
            return self
        other = DiffusionPolicy(config, self.model, make_noise_scheduler(config), self.normalizer)
        other.fast_inference, other.native_mish, other.cuda_graphs = (
            self.fast_inference, self.native_mish, self.cuda_graphs)
        return other

    # -- plumbing ----------------------------------------------------------------------------
    @property
    def device(self) -> torch.device:
        return next(self.model.parameters()).device

    def to(self, device: str | torch.device) -> DiffusionPolicy:
        self.model.to(resolve_device(device))
        return self

    @property
    def task_names(self) -> tuple[str, ...]:
        return self.config.task_names

    def condition(self, task: str | Sequence[str], n: int,
                  start: np.ndarray | Tensor | None = None) -> Tensor:
        """Conditioning vectors (n, cond_dim): task one-hot, then the normalised start pose.

        task: one name for all n, or n names. start: (d,) for all or (n, d), world units;
        required exactly when the policy is start-conditioned.
        """
        names = [task] * n if isinstance(task, str) else list(task)
        if len(names) != n:
            raise CheckpointError(f"got {len(names)} task names for {n} samples")
        known = self.config.task_names
        unknown = sorted({t for t in names if t not in known})
        if unknown:
            raise CheckpointError(f"policy does not know task {unknown[0]!r}; it was trained "
                                  f"on: {', '.join(known)}")
        idx = torch.tensor([known.index(t) for t in names], dtype=torch.long)
        cond = nn.functional.one_hot(idx, len(known)).float()
        d = self.config.state_dim
        if self.config.start_conditioned:
            if start is None:
                raise CheckpointError(f"policy is start-conditioned: give a start pose of "
                                      f"{d} values")
            s = (start.detach().float().cpu() if isinstance(start, Tensor)
                 else torch.as_tensor(np.asarray(start, dtype=np.float32)))
            if s.shape == (d,):
                s = s.expand(n, d)
            if s.shape != (n, d):
                raise CheckpointError(f"start must have shape ({d},) or ({n}, {d}), got "
                                      f"{tuple(s.shape)}")
            if not torch.isfinite(s).all():
                raise CheckpointError("start pose must be finite")
            cond = torch.cat([cond, self.normalizer.normalize(s)], dim=1)
        elif start is not None:
            raise CheckpointError("policy is not start-conditioned; do not give a start pose")
        return cond.to(self.device)

    # -- training ----------------------------------------------------------------------------
    def compute_loss(self, batch: Mapping[str, Tensor],
                     generator: torch.Generator | None = None,
                     teacher: Denoiser | None = None) -> Tensor:
        """Denoising loss: MSE between the true and predicted noise at random timesteps.

        batch: "trajectory" (B, H, d) world units, "task_index" (B,) long, and for
        start-conditioned policies optionally "start" (B, d) (default: first points).
        generator: CPU generator for the noise and timesteps (reproducible training).
        teacher: distillation: the target is this network's noise prediction for the same
        noisy input instead of the noise drawn (a target of lower variance, so a smaller
        network learns the teacher's function rather than the demonstrations afresh).
        Returns a scalar tensor with gradient.
        """
        traj = batch["trajectory"].to(self.device, torch.float32)
        b = traj.shape[0]
        x0 = self.normalizer.normalize(traj)
        idx = batch["task_index"].to(self.device, torch.long)
        cond = nn.functional.one_hot(idx, self.config.num_tasks).float()
        if self.config.start_conditioned:
            start = batch.get("start")
            start = traj[:, 0] if start is None else start.to(self.device, torch.float32)
            cond = torch.cat([cond, self.normalizer.normalize(start)], dim=1)
        gen_device = generator.device if generator is not None else self.device
        noise = torch.randn(x0.shape, generator=generator, device=gen_device).to(self.device)
        t = torch.randint(0, self.config.num_train_timesteps, (b,), generator=generator,
                          device=gen_device).to(self.device)
        x_t = self.noise_scheduler.add_noise(x0, noise, t)
        if teacher is not None:
            with torch.no_grad():
                noise = teacher(x_t, t, cond).float()
        return nn.functional.mse_loss(self.model(x_t, t, cond), noise)

    # -- sampling primitives (also used by SVDD steering) ------------------------------------
    def timesteps(self, num_steps: int | None = None) -> list[int]:
        """Reverse-process timesteps, noisiest first (sets the scheduler's schedule).

        num_steps: reverse steps, 1..num_train_timesteps; default ``config.num_inference_steps``.
        """
        n = self.config.num_inference_steps if num_steps is None else num_steps
        limit = self.config.num_train_timesteps
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= limit:
            raise ValueError(f"num_steps must be an integer in 1..{limit}, got {n!r}")
        self.noise_scheduler.set_timesteps(n)
        return [int(t) for t in self.noise_scheduler.timesteps]

    def initial_noise(self, n: int, generator: torch.Generator | None = None) -> Tensor:
        """x_T ~ N(0, I) of shape (n, H, d); drawn on the generator's device for
        reproducibility across devices, then moved to the policy's."""
        shape = (n, self.config.horizon, self.config.state_dim)
        gen_device = generator.device if generator is not None else self.device
        return torch.randn(shape, generator=generator, device=gen_device).to(self.device)

    def denoiser(self) -> Denoiser:
        """The network sampling calls: a :class:`FastUnet` copy of ``model``, built on first use
        and again whenever a weight of ``model`` changed (in place, as training and
        ``load_state_dict`` do, or by moving it), so it never goes stale; ``model`` itself when
        ``fast_inference`` is off or ``model`` is not a :class:`TemporalUnet1d`."""
        model = self.model
        if not self.fast_inference or not isinstance(model, TemporalUnet1d):
            return self.model
        if self._slots is None or self._slots[0] is not model:
            # Where every weight lives; walking the module tree on each call would cost more
            # than a small batch's network pass.
            self._slots = (model, [(mod._parameters, name) for mod in model.modules()
                                   for name in mod._parameters]
                           + [(mod._buffers, name) for mod in model.modules()
                              for name in mod._buffers])
        tensors = [table[name] for table, name in self._slots[1]]
        # A tensor changed in place has a new _version; a moved or replaced one a new address.
        key = (id(model), self.native_mish,
               *((t.data_ptr(), t._version) for t in tensors if t is not None))
        if self._fast is None or self._fast[0] != key:
            self._fast = (key, FastUnet(model, self.native_mish))
        return self._fast[1]

    def predict_noise(self, x_t: Tensor, t: int, cond: Tensor) -> Tensor:
        """eps_theta(x_t, t, cond): (B, H, d) -> (B, H, d); one network pass per row."""
        net: Denoiser = self.denoiser()
        # FastUnet takes one step for the whole batch (no per-row check, no device sync)
        shape = () if isinstance(net, FastUnet) else (x_t.shape[0],)
        step = torch.full(shape, t, dtype=torch.long, device=x_t.device)
        if (self.cuda_graphs and isinstance(net, FastUnet) and x_t.device.type == "cuda"
                and "network" not in self.graph_notes):
            if self._replayed is None or self._replayed.fn is not net:
                self._replayed = Replayed(net)  # a new copy's graphs start afresh
            try:
                return self._replayed(x_t, step, cond)
            finally:
                if self._replayed.note:
                    self.graph_notes["network"] = self._replayed.note
        return net(x_t, step, cond)

    def reverse_step(self, eps: Tensor, t: int, x_t: Tensor,
                     generator: torch.Generator | None = None) -> Tensor:
        """One draw x_{t-1} ~ p(x_{t-1} | x_t) of the scheduler's kernel, (B, H, d).

        Fresh noise per row, so repeating a row gives independent candidates (stochastic for
        DDPM and for DDIM with eta > 0)."""
        if isinstance(self.noise_scheduler, DDIMScheduler):
            out = self.noise_scheduler.step(eps, t, x_t, eta=self.config.ddim_eta,
                                            generator=generator)
        else:  # DDPM, or DPM-Solver, whose one step of memory is the batch's previous
            # prediction: one call per step, the same rows in the same order (as steering and
            # sample call it)
            out = self.noise_scheduler.step(eps, t, x_t, generator=generator)
        return out.prev_sample

    def predict_x0(self, x_t: Tensor, eps: Tensor, t: int) -> Tensor:
        """Tweedie's estimate x0_hat = (x_t - sqrt(1 - abar_t) eps) / sqrt(abar_t), clipped to
        [-1, 1] when the sampler clips; (B, H, d) normalised."""
        # a 0-dim CPU tensor joins device arithmetic as a scalar: no host-to-device copy
        abar = self.noise_scheduler.alphas_cumprod[t].to(dtype=x_t.dtype)
        x0 = (x_t - (1 - abar).sqrt() * eps) / abar.sqrt()
        return x0.clamp(-1.0, 1.0) if self.config.clip_sample else x0

    def to_world(self, x: Tensor) -> np.ndarray:
        """Normalised (B, H, d) tensor -> float64 numpy array in world units."""
        return self.normalizer.unnormalize(x.detach().to("cpu", torch.float64)).numpy()

    @torch.inference_mode()
    def sample(self, task: str | Sequence[str], n: int, start: np.ndarray | None = None,
               generator: GeneratorLike = None, num_steps: int | None = None) -> np.ndarray:
        """n trajectories (n, H, d), float64, world units.

        task: one name or n names; start: (d,) or (n, d) for start-conditioned policies;
        generator: seed or generator (same seed -> same samples on the same device);
        num_steps: reverse steps (default ``config.num_inference_steps``).
        """
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"n must be a positive integer, got {n!r}")
        gen = as_generator(generator, self.device)
        cond = self.condition(task, n, start)
        self.model.eval()
        x = self.initial_noise(n, gen)
        for t in self.timesteps(num_steps):
            x = self.reverse_step(self.predict_noise(x, t, cond), t, x, gen)
        return self.to_world(x)

    def fingerprint(self) -> str:
        """16 hex digits naming what the network computes: its weights and normaliser (not
        its sampler, a run's setting, nor its device), the same for a checkpoint wherever
        it is loaded, so a stored run can tell which network it planned with."""
        h = hashlib.sha256(json.dumps(self.normalizer.state_dict(), sort_keys=True).encode())
        for name, tensor in sorted(self.model.state_dict().items()):
            h.update(name.encode())
            h.update(tensor.detach().to("cpu", torch.float32).contiguous().numpy().tobytes())
        return h.hexdigest()[:16]

    # -- checkpoints -------------------------------------------------------------------------
    def save(self, directory: str | Path) -> Path:
        """Write ``model.safetensors`` and ``config.json`` into ``directory`` (created)."""
        directory = Path(directory)
        if directory.exists() and not directory.is_dir():
            raise CheckpointError(f"cannot save policy: {directory} exists and is not a directory")
        directory.mkdir(parents=True, exist_ok=True)
        tensors = {k: v.detach().to("cpu").contiguous() for k, v in
                   self.model.state_dict().items()}
        weights = directory / WEIGHTS_FILE
        atomic_write_bytes(weights, save(tensors, metadata={"format": "pt"}))
        meta = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "config": self.config.to_dict(),
            "normalizer": self.normalizer.state_dict(),
            "weights": {"file": WEIGHTS_FILE, "sha256": _sha256(weights)},
        }
        atomic_write_text(directory / CONFIG_FILE, json.dumps(meta, indent=2) + "\n")
        return directory

    @classmethod
    def load(cls, directory: str | Path,
             device: str | torch.device | None = None) -> DiffusionPolicy:
        """Read a checkpoint written by :meth:`save`, bit-identical, onto ``device`` (default
        "auto": CUDA when present, so a GPU-trained policy loads on a CPU machine too).
        Raises CheckpointError with one line on any problem."""
        directory = Path(directory)
        if not directory.exists():
            raise CheckpointError(f"checkpoint {directory} does not exist")
        if not directory.is_dir():
            raise CheckpointError(f"checkpoint {directory} is not a directory (expected one "
                                  f"holding {CONFIG_FILE} and {WEIGHTS_FILE})")
        cfg_path = directory / CONFIG_FILE
        if not cfg_path.is_file():
            raise CheckpointError(f"checkpoint {directory}: missing {CONFIG_FILE}")
        try:
            meta = json.loads(cfg_path.read_text("utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise CheckpointError(f"{cfg_path}: corrupt JSON ({exc})") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
            raise CheckpointError(f"{cfg_path}: not a rapidds diffusion policy (format {got!r})")
        version = meta.get("format_version")
        if version != FORMAT_VERSION:
            raise CheckpointError(f"{cfg_path}: unknown checkpoint format version {version!r} "
                                  f"(this rapidds reads version {FORMAT_VERSION})")
        try:
            config = DiffusionConfig.from_dict(meta["config"])
            normalizer = MinMaxNormalizer.from_state_dict(meta["normalizer"])
            expected_sha = str(meta["weights"]["sha256"])
        except ConfigError as exc:
            raise CheckpointError(f"{cfg_path}: {exc}") from None
        except (KeyError, TypeError, ValueError) as exc:
            raise CheckpointError(f"{cfg_path}: invalid checkpoint metadata "
                                  f"({type(exc).__name__}: {exc})") from None
        if normalizer.dim != config.state_dim:
            raise CheckpointError(f"{cfg_path}: normaliser has d={normalizer.dim} but the "
                                  f"config says state_dim={config.state_dim}")

        weights = directory / WEIGHTS_FILE
        if not weights.is_file():
            raise CheckpointError(f"checkpoint {directory}: missing {WEIGHTS_FILE}")
        if _sha256(weights) != expected_sha:
            raise CheckpointError(f"{weights}: checksum mismatch (changed or truncated since "
                                  f"it was saved)")
        try:
            tensors = load_file(str(weights), device="cpu")
        except Exception as exc:  # safetensors raises its own Rust-side error types
            raise CheckpointError(f"{weights}: corrupt safetensors file ({exc})") from None

        policy = cls.from_config(config, normalizer, device="cpu")
        expected = policy.model.state_dict()
        missing = sorted(set(expected) - set(tensors))
        unexpected = sorted(set(tensors) - set(expected))
        if missing or unexpected:
            what = (f"missing {missing[0]}" if missing else f"unexpected {unexpected[0]}")
            raise CheckpointError(f"{weights}: weights do not fit the config ({what}; "
                                  f"{len(missing)} missing, {len(unexpected)} unexpected)")
        for key, ref in expected.items():
            got = tensors[key]
            if got.shape != ref.shape or got.dtype != ref.dtype:
                raise CheckpointError(f"{weights}: shape mismatch for {key}: file has "
                                      f"{tuple(got.shape)} {got.dtype}, config needs "
                                      f"{tuple(ref.shape)} {ref.dtype}")
        policy.model.load_state_dict(tensors, strict=True)
        policy.model.eval()
        try:
            return policy.to(resolve_device(device, default="auto"))
        except ConfigError as exc:
            raise CheckpointError(f"cannot load {directory}: {exc}") from None
