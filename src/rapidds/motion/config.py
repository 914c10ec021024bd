"""Configuration of the trajectory diffusion policy: network, noise schedule, sampler, training.

One frozen dataclass, validated on construction, stored as JSON inside every checkpoint so a
policy is always rebuilt with the settings it was trained with.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Literal

import torch

from rapidds.errors import ConfigError

BETA_SCHEDULES = ("linear", "scaled_linear", "squaredcos_cap_v2")
SAMPLERS = ("ddim", "ddpm")
DEVICES = ("auto", "cpu", "cuda")


@dataclass(frozen=True)
class DiffusionConfig:
    """Everything needed to rebuild, train and sample a trajectory diffusion policy.

    Trajectory shape
        horizon: H, points per trajectory. A multiple of 8 and divisible by
            2 ** (len(down_dims) - 1) so every U-Net down-sampling halves it exactly.
        state_dim: d, dimension of one point (2 for a planar robot, 7 for joint angles).
        task_names: the tasks the policy is conditioned on, in one-hot order. Non-empty, unique.
        start_conditioned: also condition on the start pose (d values), for tasks whose start
            varies between demonstrations.

    Network (1-D temporal U-Net with FiLM)
        down_dims: channels at each U-Net level; len(down_dims) - 1 down-samplings.
        kernel_size: temporal convolution width, odd so padding keeps the length.
        n_groups: GroupNorm groups; must divide every entry of down_dims.
        step_embed_dim: width of the sinusoidal diffusion-step embedding, even.

    Noise schedule and sampler (``diffusers``)
        num_train_timesteps: T, diffusion steps of the forward (noising) process.
        beta_schedule: one of "linear", "scaled_linear", "squaredcos_cap_v2".
        beta_start, beta_end: first and last beta of the linear schedules (ignored by the cosine
            schedule); 0 < beta_start < beta_end < 1.
        sampler: "ddim" or "ddpm" reverse kernel used by sampling and by steering.
        num_inference_steps: reverse steps at sampling time, 1..num_train_timesteps.
        ddim_eta: DDIM stochasticity in [0, 1]; 0 is deterministic DDIM, which plain sampling
            accepts but SVDD steering refuses (all candidates would be identical).
        clip_sample: clip predicted clean trajectories to the normalised range [-1, 1].

    Training
        lr: AdamW learning rate (> 0).
        weight_decay: AdamW weight decay (>= 0).
        batch_size: trajectories per optimiser step (>= 1; capped at the number of demos).
        steps: optimiser steps (>= 1); ignored when ``epochs`` is set.
        epochs: passes over the demonstrations; when set, steps = epochs * batches per epoch.
        lr_warmup_steps: linear warm-up steps before the cosine decay (>= 0).
        use_ema: keep an exponential moving average of the weights and ship it as the policy.
        ema_decay: EMA decay in [0, 1); warmed up as min(decay, (1 + k) / (10 + k)) at step k
            so short runs are not dominated by the random initialisation.
        seed: seeds weight initialisation, batch order and training noise; equal seeds give
            bit-identical policies on CPU.
        device: "auto" (CUDA when present, else CPU), "cpu" or "cuda".
        cpu_threads: torch threads while training on CPU; 0 leaves torch's setting. Networks
            this small run fastest on one thread, and several threads on a busy machine were
            measured 50x slower.
    """

    horizon: int = 16
    state_dim: int = 2
    task_names: tuple[str, ...] = ("task",)
    start_conditioned: bool = False
    down_dims: tuple[int, ...] = (32, 64, 128)
    kernel_size: int = 5
    n_groups: int = 8
    step_embed_dim: int = 64
    num_train_timesteps: int = 100
    beta_schedule: str = "squaredcos_cap_v2"
    beta_start: float = 1e-4
    beta_end: float = 0.02
    sampler: Literal["ddim", "ddpm"] = "ddim"
    num_inference_steps: int = 20
    ddim_eta: float = 1.0
    clip_sample: bool = True
    lr: float = 1e-3
    weight_decay: float = 1e-6
    batch_size: int = 64
    steps: int = 2000
    epochs: int | None = None
    lr_warmup_steps: int = 50
    use_ema: bool = True
    ema_decay: float = 0.995
    seed: int = 0
    device: Literal["auto", "cpu", "cuda"] = "auto"
    cpu_threads: int = 1

    def __post_init__(self) -> None:
        # Lists from JSON become tuples so a config read back compares equal to the original.
        for name in ("task_names", "down_dims"):
            if isinstance(getattr(self, name), str | bytes | int):
                raise ConfigError(f"DiffusionConfig: {name} must be a list, got "
                                  f"{getattr(self, name)!r}")
        object.__setattr__(self, "task_names", tuple(self.task_names))
        object.__setattr__(self, "down_dims", tuple(self.down_dims))
        self._check()

    def _check(self) -> None:
        def bad(msg: str) -> ConfigError:
            return ConfigError(f"DiffusionConfig: {msg}")

        def is_int(v: Any) -> bool:
            return isinstance(v, int) and not isinstance(v, bool)

        def is_num(v: Any) -> bool:
            return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)

        for name in ("horizon", "state_dim", "kernel_size", "n_groups", "step_embed_dim",
                     "num_train_timesteps", "num_inference_steps", "batch_size", "steps",
                     "lr_warmup_steps", "seed", "cpu_threads"):
            if not is_int(getattr(self, name)):
                raise bad(f"{name} must be an integer, got {getattr(self, name)!r}")
        for name in ("beta_start", "beta_end", "ddim_eta", "lr", "weight_decay", "ema_decay"):
            if not is_num(getattr(self, name)):
                raise bad(f"{name} must be a finite number, got {getattr(self, name)!r}")
        for name in ("start_conditioned", "clip_sample", "use_ema"):
            if not isinstance(getattr(self, name), bool):
                raise bad(f"{name} must be true or false, got {getattr(self, name)!r}")

        if not self.down_dims or not all(is_int(c) and c > 0 for c in self.down_dims):
            raise bad(f"down_dims must be a non-empty list of positive integers, got "
                      f"{list(self.down_dims)}")
        if self.horizon < 8 or self.horizon % 8:
            raise bad(f"horizon must be a positive multiple of 8, got {self.horizon}")
        levels = 2 ** (len(self.down_dims) - 1)
        if self.horizon % levels:
            raise bad(f"horizon {self.horizon} is not divisible by 2**(len(down_dims)-1) = "
                      f"{levels}; use fewer U-Net levels or a longer horizon")
        if self.state_dim < 1:
            raise bad(f"state_dim must be >= 1, got {self.state_dim}")
        if not self.task_names:
            raise bad("task_names must name at least one task")
        if not all(isinstance(t, str) and t.strip() for t in self.task_names):
            raise bad(f"task_names must be non-empty strings, got {list(self.task_names)}")
        if len(set(self.task_names)) != len(self.task_names):
            dup = sorted({t for t in self.task_names if self.task_names.count(t) > 1})
            raise bad(f"task_names must be unique, repeated: {', '.join(dup)}")
        if self.kernel_size < 1 or self.kernel_size % 2 == 0:
            raise bad(f"kernel_size must be a positive odd integer, got {self.kernel_size}")
        if self.n_groups < 1 or any(c % self.n_groups for c in self.down_dims):
            raise bad(f"n_groups ({self.n_groups}) must be >= 1 and divide every down_dims "
                      f"entry {list(self.down_dims)}")
        if self.step_embed_dim < 2 or self.step_embed_dim % 2:
            raise bad(f"step_embed_dim must be an even integer >= 2, got {self.step_embed_dim}")
        if self.num_train_timesteps < 2:
            raise bad(f"num_train_timesteps must be >= 2, got {self.num_train_timesteps}")
        if self.beta_schedule not in BETA_SCHEDULES:
            raise bad(f"beta_schedule must be one of {', '.join(BETA_SCHEDULES)}, got "
                      f"{self.beta_schedule!r}")
        if not 0 < self.beta_start < self.beta_end < 1:
            raise bad(f"need 0 < beta_start < beta_end < 1, got {self.beta_start}, "
                      f"{self.beta_end}")
        if self.sampler not in SAMPLERS:
            raise bad(f"sampler must be one of {', '.join(SAMPLERS)}, got {self.sampler!r}")
        if not 1 <= self.num_inference_steps <= self.num_train_timesteps:
            raise bad(f"num_inference_steps must be in 1..num_train_timesteps "
                      f"({self.num_train_timesteps}), got {self.num_inference_steps}")
        if not 0 <= self.ddim_eta <= 1:
            raise bad(f"ddim_eta must be in [0, 1], got {self.ddim_eta}")
        if self.lr <= 0:
            raise bad(f"lr must be > 0, got {self.lr}")
        if self.weight_decay < 0:
            raise bad(f"weight_decay must be >= 0, got {self.weight_decay}")
        if self.batch_size < 1:
            raise bad(f"batch_size must be >= 1, got {self.batch_size}")
        if self.steps < 1:
            raise bad(f"steps must be >= 1, got {self.steps}")
        if self.epochs is not None and (not is_int(self.epochs) or self.epochs < 1):
            raise bad(f"epochs must be a positive integer or null, got {self.epochs!r}")
        if self.lr_warmup_steps < 0:
            raise bad(f"lr_warmup_steps must be >= 0, got {self.lr_warmup_steps}")
        if not 0 <= self.ema_decay < 1:
            raise bad(f"ema_decay must be in [0, 1), got {self.ema_decay}")
        if self.seed < 0:
            raise bad(f"seed must be >= 0, got {self.seed}")
        if self.cpu_threads < 0:
            raise bad(f"cpu_threads must be >= 0, got {self.cpu_threads}")
        if self.device not in DEVICES:
            raise bad(f"device must be one of {', '.join(DEVICES)}, got {self.device!r}")

    # -- derived ----------------------------------------------------------------------------
    @property
    def num_tasks(self) -> int:
        return len(self.task_names)

    @property
    def cond_dim(self) -> int:
        """Width of the conditioning vector: task one-hot, then the start pose if used."""
        return self.num_tasks + (self.state_dim if self.start_conditioned else 0)

    def replace(self, **changes: Any) -> DiffusionConfig:
        """A copy with ``changes`` applied and validated again."""
        return dataclasses.replace(self, **changes)

    # -- JSON -------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (tuples become lists)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> DiffusionConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error (they usually are typos)."""
        if not isinstance(data, dict):
            raise ConfigError(f"DiffusionConfig: expected a JSON object, got {type(data).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        extra = sorted(set(data) - known)
        if extra:
            raise ConfigError(f"DiffusionConfig: unknown field(s): {', '.join(extra)}")
        return cls(**data)


@contextmanager
def cpu_threads(n: int) -> Iterator[None]:
    """Run the block with ``n`` torch intra-op threads (0: unchanged), then restore."""
    if n <= 0:
        yield
        return
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def resolve_device(device: str | torch.device | None, default: str = "auto") -> torch.device:
    """Turn "auto" / "cpu" / "cuda" (or a torch.device) into a device that exists here."""
    if isinstance(device, torch.device):
        name = device.type
    else:
        name = default if device is None else str(device)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    kind = name.split(":")[0]
    if kind not in ("cpu", "cuda"):
        raise ConfigError(f"device must be one of {', '.join(DEVICES)}, got {name!r}")
    if kind == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device 'cuda' requested but no CUDA GPU is available here")
    return device if isinstance(device, torch.device) else torch.device(name)
