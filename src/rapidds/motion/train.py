"""Training a :class:`DiffusionPolicy` on demonstrations: AdamW, warm-up + cosine learning rate,
optional EMA of the weights. Kept apart from the policy so inference code never imports it.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from rapidds.motion.config import ConfigError, DiffusionConfig, cpu_threads, resolve_device
from rapidds.motion.demos import Demonstrations
from rapidds.motion.normalizer import MinMaxNormalizer
from rapidds.motion.policy import DiffusionPolicy

ProgressFn = Callable[[int, float], None]


@dataclass
class TrainHistory:
    """What a training run did. ``loss[k]`` is the batch loss of optimiser step k + 1."""

    loss: list[float] = field(default_factory=list)
    steps: int = 0
    seconds: float = 0.0
    device: str = "cpu"
    cuda_graph: bool = False
    """Whether the optimiser steps replayed a captured CUDA graph (else each was launched
    op by op); why not, when it was asked for and capture failed: ``graph_note``."""
    graph_note: str = ""

    def mean_loss(self, first: int | None = None, last: int | None = None) -> float:
        """Mean loss over the first or last ``n`` steps (all steps when neither is given)."""
        if not self.loss:
            return float("nan")
        part = self.loss[:first] if first else self.loss[-last:] if last else self.loss
        return float(np.mean(part))


class _Ema:
    """Exponential moving average of a model's parameters, with the usual warm-up
    decay_k = min(decay, (1 + k) / (10 + k)) so early steps are not frozen at the init."""

    def __init__(self, model: nn.Module, decay: float):
        self.decay = decay
        self.shadow = copy.deepcopy(model).eval().requires_grad_(False)
        self.updates = 0

        self._pairs = (list(self.shadow.parameters()), list(model.parameters()))

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        d = min(self.decay, (1 + self.updates) / (10 + self.updates))
        shadow, params = self._pairs
        # one multi-tensor call instead of a small kernel per parameter (the same per-tensor
        # lerp on the CPU, so the same bits)
        torch._foreach_lerp_(shadow, [p.detach() for p in params], 1.0 - d)
        for s, b in zip(self.shadow.buffers(), model.buffers(), strict=True):
            s.copy_(b)
        self.updates += 1


def check_compatible(demos: Demonstrations, config: DiffusionConfig) -> None:
    """Raise ConfigError when the demonstrations do not have the config's shape or tasks."""
    if demos.horizon != config.horizon:
        raise ConfigError(f"demonstrations have horizon {demos.horizon}, config {config.horizon}")
    if demos.state_dim != config.state_dim:
        raise ConfigError(f"demonstrations have state_dim {demos.state_dim}, config "
                          f"{config.state_dim}")
    if tuple(demos.task_names) != tuple(config.task_names):
        raise ConfigError(f"demonstrations name tasks {list(demos.task_names)}, config "
                          f"{list(config.task_names)} (same names in the same order needed)")


FORWARD_PROCESS = ("horizon", "state_dim", "task_names", "start_conditioned",
                   "num_train_timesteps", "beta_schedule", "beta_start", "beta_end")
"""The settings a student must share with its teacher: the same paths, conditioning and
noising, so a noisy input means the same to both."""


def check_teacher(teacher: DiffusionPolicy, config: DiffusionConfig) -> None:
    """Raise ConfigError unless ``teacher`` noises and conditions as ``config`` does."""
    for name in FORWARD_PROCESS:
        mine, theirs = getattr(config, name), getattr(teacher.config, name)
        if mine != theirs:
            raise ConfigError(f"the teacher has {name} {_show(theirs)}, the student "
                              f"{_show(mine)}; a student distils a teacher of the same "
                              "paths and forward process")


def _show(v: object) -> str:
    return str(list(v)) if isinstance(v, tuple) else str(v)


def fit_normalizer(demos: Demonstrations, config: DiffusionConfig) -> MinMaxNormalizer:
    """Min-max bounds over every demonstrated point (and start pose when conditioned on)."""
    pts = demos.trajectories.reshape(-1, demos.state_dim)
    if config.start_conditioned:
        pts = np.concatenate([pts, demos.start_poses()], axis=0)
    return MinMaxNormalizer.fit(pts)


def total_steps(n_demos: int, config: DiffusionConfig) -> int:
    """Optimiser steps of a run: ``config.steps``, or epochs x batches per epoch."""
    if config.epochs is None:
        return config.steps
    return config.epochs * math.ceil(n_demos / min(config.batch_size, n_demos))


GPU_LOG_EVERY = 50
"""Optimiser steps between two reads of the loss on a GPU (each read waits for the device)."""

GRAPH_WARMUP = 3
"""Eager optimiser steps (real ones, on a side stream) before a CUDA graph is captured: they
create the optimiser's state and let the allocator and cuDNN settle, as capture requires."""


def train_policy(demos: Demonstrations, config: DiffusionConfig,
                 progress: ProgressFn | None = None,
                 device: str | torch.device | None = None,
                 mixed_precision: bool = False,
                 teacher: DiffusionPolicy | None = None,
                 cuda_graph: bool | None = None,
                 ) -> tuple[DiffusionPolicy, TrainHistory]:
    """Train a policy from scratch on ``demos``.

    config: must match the demonstrations' horizon, state_dim and task names.
    progress: called as progress(step, loss) after every optimiser step on the CPU, every
    :data:`GPU_LOG_EVERY` steps (and the last) on a GPU, whose loss is read only then.
    device: overrides ``config.device`` ("auto", "cpu", "cuda").
    mixed_precision: the network's forward pass in bfloat16 autocast (weights, optimiser and
    loss stay float32; checkpoints the same float32 format). Off by default: on an H200 it
    made this U-Net's step slower (its casts are more kernels, and the kernels are tiny), 15
    against 9.6 ms captured and 27 against 20 ms op by op (docs/benchmarks.md).
    teacher: distil it: the network learns the teacher's noise predictions on the
    demonstrations (:meth:`DiffusionPolicy.compute_loss`) in the teacher's normalised units
    (its normaliser is kept); moved to the device. Its forward process must be ``config``'s.
    cuda_graph: on a GPU, capture one whole optimiser step (forward, backward, AdamW) as a
    CUDA graph after :data:`GRAPH_WARMUP` eager steps and replay it: a small network's step is
    hundreds of kernels, each launched by the host, so launching is what a step costs there
    (20 ms op by op, 9.6 captured on an H200: docs/benchmarks.md). The same steps, learning
    rates and random streams; batches of another size (an epoch's last) run eagerly. None: on
    a GPU. Ignored on the CPU.
    Returns the policy (EMA weights when ``config.use_ema``, in eval mode) and the history.
    On CPU the same seed gives bit-identical weights. The demonstrations, every batch's
    indices and the random numbers live on the device: a step never waits for the host.
    """
    check_compatible(demos, config)
    if teacher is not None:
        check_teacher(teacher, config)
    dev = resolve_device(device, default=config.device)
    amp = bool(mixed_precision)
    graph = dev.type == "cuda" and (cuda_graph is None or cuda_graph)
    with cpu_threads(config.cpu_threads if dev.type == "cpu" else 0):
        return _train(demos, config, progress, dev, amp, teacher, graph)


def _batches(config: DiffusionConfig, n: int, steps: int, dev: torch.device
             ) -> tuple[torch.Tensor, list[int]]:
    """Every step's demonstration indices, drawn up front (a fresh permutation per epoch, its
    last batch maybe smaller: the numbers a step-by-step draw gives) and copied to ``dev``
    once: (all indices, offsets), step k's batch being ``indices[offsets[k]:offsets[k + 1]]``."""
    rng = np.random.default_rng(config.seed)
    bs = min(config.batch_size, n)
    parts, offsets = [], [0]
    order = np.empty(0, dtype=np.int64)
    for _ in range(steps):
        if order.size == 0:
            order = rng.permutation(n)
        parts.append(order[:bs])
        offsets.append(offsets[-1] + len(parts[-1]))
        order = order[bs:]
    return torch.as_tensor(np.concatenate(parts), device=dev), offsets


def _train(demos: Demonstrations, config: DiffusionConfig, progress: ProgressFn | None,
           dev: torch.device, amp: bool, teacher: DiffusionPolicy | None, graph: bool = False
           ) -> tuple[DiffusionPolicy, TrainHistory]:
    normalizer = fit_normalizer(demos, config) if teacher is None else teacher.normalizer
    policy = DiffusionPolicy.from_config(config, normalizer, device=dev)
    target = None if teacher is None else teacher.to(dev).denoiser()
    model = policy.model.train()
    ema = _Ema(model, config.ema_decay) if config.use_ema else None

    traj = torch.as_tensor(demos.trajectories, dtype=torch.float32, device=dev)
    task_idx = torch.as_tensor(demos.task_index, dtype=torch.long, device=dev)
    start = torch.as_tensor(demos.start_poses(), dtype=torch.float32, device=dev)
    n = len(demos)
    steps = total_steps(n, config)
    warmup = min(config.lr_warmup_steps, steps - 1)

    def lr_factor(k: int) -> float:
        if k < warmup:
            return (k + 1) / warmup
        return 0.5 * (1.0 + math.cos(math.pi * (k - warmup) / max(steps - warmup, 1)))

    # a replayed step reads its learning rate and step count from the device
    lr: float | torch.Tensor = (torch.tensor(config.lr * lr_factor(0), device=dev) if graph
                                else config.lr)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, betas=(0.95, 0.999),
                            weight_decay=config.weight_decay,
                            **({"fused": True, "capturable": graph} if dev.type == "cuda"
                               else {}))
    # graph: the rate is set by hand before each step (LambdaLR's values), since a scheduler
    # may replace a tensor rate by a float the captured step would never read
    sched = None if graph else torch.optim.lr_scheduler.LambdaLR(opt, lr_factor)
    gen = torch.Generator(dev).manual_seed(config.seed)  # noise drawn where it is used
    history = TrainHistory(device=str(dev))
    log_every = 1 if dev.type == "cpu" else GPU_LOG_EVERY

    def optimiser_step(pick: torch.Tensor) -> torch.Tensor:
        batch = {"trajectory": traj[pick], "task_index": task_idx[pick], "start": start[pick]}
        # no autocast cache: a captured step must recast the weights AdamW changed
        with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=amp, cache_enabled=False):
            loss = policy.compute_loss(batch, generator=gen, teacher=target)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        # detached: a loss kept alive would keep its autograd graph, whose gradient
        # accumulators on the warm-up's stream then mismatch the captured step's
        return loss.detach()

    t0 = time.perf_counter()
    index, offsets = _batches(config, n, steps, dev)
    losses = torch.empty(steps, device=dev)
    replay = _StepGraph(optimiser_step, min(config.batch_size, n), gen, dev) if graph else None
    for step in range(1, steps + 1):
        pick = index[offsets[step - 1]:offsets[step]]
        if sched is None:
            opt.param_groups[0]["lr"].fill_(config.lr * lr_factor(step - 1))
        loss = optimiser_step(pick) if replay is None else replay(pick)
        if sched is not None:
            sched.step()
        if ema is not None:
            ema.update(model)
        losses[step - 1] = loss
        if progress is not None and (step % log_every == 0 or step == steps):
            progress(step, float(losses[step - 1]))
    history.loss = losses.tolist()  # one read at the end
    history.steps = steps
    history.seconds = time.perf_counter() - t0
    if replay is not None:
        history.cuda_graph, history.graph_note = replay.captured, replay.note

    if ema is not None:
        model.load_state_dict(ema.shadow.state_dict())
    model.eval()
    return policy, history


class _StepGraph:
    """One optimiser step captured as a CUDA graph and replayed (the PyTorch guide's "whole
    network capture"): the first :data:`GRAPH_WARMUP` steps run eagerly on a side stream, as
    capture's warm-up must; then the step's batch indices are copied into a static buffer,
    the graph replays forward, backward and AdamW, and its loss lands in a static tensor.
    Capture happens at the first full-size batch after the warm-up; when it fails (an
    operation that cannot be captured), every step runs eagerly and ``note`` says why."""

    def __init__(self, step: Callable[[torch.Tensor], torch.Tensor], batch_size: int,
                 gen: torch.Generator, dev: torch.device):
        self.step, self.batch_size, self.gen, self.dev = step, batch_size, gen, dev
        self.graph: torch.cuda.CUDAGraph | None = None
        self.pick = torch.zeros(batch_size, dtype=torch.long, device=dev)
        self.loss: torch.Tensor | None = None
        self.captured, self.note = False, ""
        self.side = torch.cuda.Stream(dev)
        self.warmed = 0

    def _warm(self, pick: torch.Tensor) -> torch.Tensor:
        self.side.wait_stream(torch.cuda.current_stream(self.dev))
        with torch.cuda.stream(self.side):
            loss = self.step(pick)
        torch.cuda.current_stream(self.dev).wait_stream(self.side)
        self.warmed += 1
        return loss

    def __call__(self, pick: torch.Tensor) -> torch.Tensor:
        if self.warmed < GRAPH_WARMUP:
            return self._warm(pick)
        if len(pick) != self.batch_size or self.note:
            return self.step(pick)
        if self.graph is None:
            self._capture()
            if self.graph is None:
                return self.step(pick)
        self.pick.copy_(pick)
        self.graph.replay()
        assert self.loss is not None
        return self.loss

    def _capture(self) -> None:
        graph = torch.cuda.CUDAGraph()
        try:
            graph.register_generator_state(self.gen)
            torch.cuda.synchronize(self.dev)
            with torch.cuda.graph(graph):
                self.loss = self.step(self.pick)
        except (RuntimeError, AttributeError) as exc:
            self.note = f"CUDA graph capture failed, steps run eagerly: {exc}".splitlines()[0]
            torch.cuda.synchronize(self.dev)
            return
        self.graph, self.captured = graph, True
