"""Configuration of the trajectory diffusion policy: network, noise schedule, sampler, training.

One frozen settings model, validated on construction, stored as JSON inside every checkpoint so a
policy is always rebuilt with the settings it was trained with.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Annotated, Any, ClassVar, Literal

import torch
from pydantic import Field, field_validator, model_validator

from rapidds.errors import ConfigError
from rapidds.settings import Flag, Int, Real, Settings

BETA_SCHEDULES = ("linear", "scaled_linear", "squaredcos_cap_v2")
SAMPLERS = ("ddim", "ddpm", "dpm")
DEVICES = ("auto", "cpu", "cuda")


class DiffusionConfig(Settings):
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
        sampler: the reverse kernel of sampling and steering: "ddim", "ddpm", or "dpm"
            (DPM-Solver++ 2M, SDE form: second order from the previous step's prediction,
            stochastic as steering needs; meant for few steps, e.g. 5). The same forward
            process trains all three, so a policy trained with one samples with any other
            (:meth:`~rapidds.motion.policy.DiffusionPolicy.with_sampler`).
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

    label: ClassVar[str] = "DiffusionConfig"

    horizon: Annotated[Int, Field(ge=8, multiple_of=8)] = 16
    state_dim: Annotated[Int, Field(ge=1)] = 2
    task_names: Annotated[tuple[str, ...], Field(min_length=1)] = ("task",)
    start_conditioned: Flag = False
    down_dims: Annotated[tuple[Annotated[Int, Field(gt=0)], ...], Field(min_length=1)] = (
        32, 64, 128)
    kernel_size: Annotated[Int, Field(ge=1)] = 5
    n_groups: Annotated[Int, Field(ge=1)] = 8
    step_embed_dim: Annotated[Int, Field(ge=2, multiple_of=2)] = 64
    num_train_timesteps: Annotated[Int, Field(ge=2)] = 100
    beta_schedule: Literal["linear", "scaled_linear", "squaredcos_cap_v2"] = "squaredcos_cap_v2"
    beta_start: Annotated[Real, Field(gt=0, lt=1)] = 1e-4
    beta_end: Annotated[Real, Field(gt=0, lt=1)] = 0.02
    sampler: Literal["ddim", "ddpm", "dpm"] = "ddim"
    num_inference_steps: Annotated[Int, Field(ge=1)] = 20
    ddim_eta: Annotated[Real, Field(ge=0, le=1)] = 1.0
    clip_sample: Flag = True
    lr: Annotated[Real, Field(gt=0)] = 1e-3
    weight_decay: Annotated[Real, Field(ge=0)] = 1e-6
    batch_size: Annotated[Int, Field(ge=1)] = 64
    steps: Annotated[Int, Field(ge=1)] = 2000
    epochs: Annotated[Int, Field(ge=1)] | None = None
    lr_warmup_steps: Annotated[Int, Field(ge=0)] = 50
    use_ema: Flag = True
    ema_decay: Annotated[Real, Field(ge=0, lt=1)] = 0.995
    seed: Annotated[Int, Field(ge=0)] = 0
    device: Literal["auto", "cpu", "cuda"] = "auto"
    cpu_threads: Annotated[Int, Field(ge=0)] = 1

    @field_validator("task_names", "down_dims", mode="before")
    @classmethod
    def _a_list(cls, v: Any) -> Any:
        # A string is a sequence to Python but never the list these fields mean.
        if isinstance(v, str | bytes | int):
            raise ValueError(f"must be a list, got {v!r}")
        return v

    @field_validator("task_names")
    @classmethod
    def _task_names(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        if not all(t.strip() for t in v):
            raise ValueError(f"must be non-empty strings, got {list(v)}")
        if len(set(v)) != len(v):
            dup = sorted({t for t in v if v.count(t) > 1})
            raise ValueError(f"must be unique, repeated: {', '.join(dup)}")
        return v

    @field_validator("kernel_size")
    @classmethod
    def _odd(cls, v: int) -> int:
        if v % 2 == 0:
            raise ValueError(f"must be a positive odd integer, got {v}")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> DiffusionConfig:
        """The checks that involve two fields."""
        levels = 2 ** (len(self.down_dims) - 1)
        if self.horizon % levels:
            raise ValueError(f"horizon {self.horizon} is not divisible by 2**(len(down_dims)-1) "
                             f"= {levels}; use fewer U-Net levels or a longer horizon")
        if any(c % self.n_groups for c in self.down_dims):
            raise ValueError(f"n_groups ({self.n_groups}) must divide every down_dims entry "
                             f"{list(self.down_dims)}")
        if not self.beta_start < self.beta_end:
            raise ValueError(f"need 0 < beta_start < beta_end < 1, got {self.beta_start}, "
                             f"{self.beta_end}")
        if self.num_inference_steps > self.num_train_timesteps:
            raise ValueError(f"num_inference_steps must be in 1..num_train_timesteps "
                             f"({self.num_train_timesteps}), got {self.num_inference_steps}")
        return self

    # -- derived ----------------------------------------------------------------------------
    @property
    def num_tasks(self) -> int:
        return len(self.task_names)

    @property
    def cond_dim(self) -> int:
        """Width of the conditioning vector: task one-hot, then the start pose if used."""
        return self.num_tasks + (self.state_dim if self.start_conditioned else 0)

    # -- JSON -------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (tuples become lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> DiffusionConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error (they usually are typos)."""
        if not isinstance(data, dict):
            raise ConfigError(f"DiffusionConfig: expected a JSON object, got {type(data).__name__}")
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
