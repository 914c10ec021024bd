"""1-D temporal U-Net that predicts the noise in a trajectory, FiLM-conditioned.

The architecture of Diffusion Policy (Chi et al. 2023): convolutions run along time, so nearby
points of a path are denoised together; the diffusion step, the task one-hot and (optionally)
the start pose enter every residual block as a per-channel scale and bias (FiLM), which is how
one network serves all tasks.
"""

from __future__ import annotations

import itertools
import math

import torch
from torch import Tensor, nn

from rapidds.motion.config import DiffusionConfig


def check_inputs(x: Tensor, cond: Tensor, state_dim: int, cond_dim: int) -> None:
    """ValueError unless x is (B, H, state_dim) and cond (B, cond_dim)."""
    if x.ndim != 3 or x.shape[-1] != state_dim:
        raise ValueError(f"expected x of shape (B, H, {state_dim}), got {tuple(x.shape)}")
    if cond.shape != (x.shape[0], cond_dim):
        raise ValueError(f"expected cond of shape ({x.shape[0]}, {cond_dim}), got "
                         f"{tuple(cond.shape)}")


class SinusoidalStepEmbedding(nn.Module):
    """Diffusion step t (B,) -> (B, dim) sin/cos features at geometric frequencies."""

    def __init__(self, dim: int):
        super().__init__()
        half = dim // 2
        freqs = torch.exp(-math.log(10000.0) * torch.arange(half) / max(half - 1, 1))
        self.register_buffer("freqs", freqs, persistent=False)

    def forward(self, t: Tensor) -> Tensor:
        angles = t.float()[:, None] * self.freqs[None, :]
        return torch.cat([angles.sin(), angles.cos()], dim=-1)


class ConvNormAct(nn.Sequential):
    """Conv1d -> GroupNorm -> Mish; (B, C_in, L) -> (B, C_out, L)."""

    def __init__(self, c_in: int, c_out: int, kernel_size: int, n_groups: int):
        super().__init__(
            nn.Conv1d(c_in, c_out, kernel_size, padding=kernel_size // 2),
            nn.GroupNorm(n_groups, c_out),
            nn.Mish(),
        )


class FiLMResidualBlock(nn.Module):
    """Two conv blocks with a FiLM modulation in between and a residual connection.

    x (B, C_in, L), cond (B, cond_dim) -> (B, C_out, L). The conditioning predicts a scale and
    a bias per output channel: out = scale * h + bias.
    """

    def __init__(self, c_in: int, c_out: int, cond_dim: int, kernel_size: int, n_groups: int):
        super().__init__()
        self.conv1 = ConvNormAct(c_in, c_out, kernel_size, n_groups)
        self.conv2 = ConvNormAct(c_out, c_out, kernel_size, n_groups)
        self.film = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, 2 * c_out))
        self.skip = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: Tensor, cond: Tensor) -> Tensor:
        h = self.conv1(x)
        scale, bias = self.film(cond).unsqueeze(-1).chunk(2, dim=1)
        h = self.conv2(scale * h + bias)
        return h + self.skip(x)


class TemporalUnet1d(nn.Module):
    """Noise predictor eps_theta(x_t, t, c).

    forward(x (B, H, d), t (B,) int, cond (B, cond_dim)) -> eps (B, H, d), where cond is the
    task one-hot followed by the normalised start pose when ``config.start_conditioned``.
    The time axis is halved len(down_dims) - 1 times and restored; after each up-sampling the
    features of the same resolution on the way down are concatenated (skip connections).
    """

    def __init__(self, config: DiffusionConfig):
        super().__init__()
        self.state_dim = config.state_dim
        self.cond_dim = config.cond_dim
        k, g, e = config.kernel_size, config.n_groups, config.step_embed_dim
        self.step_encoder = nn.Sequential(
            SinusoidalStepEmbedding(e), nn.Linear(e, 4 * e), nn.Mish(), nn.Linear(4 * e, e)
        )
        film_dim = e + config.cond_dim
        dims = (config.state_dim, *config.down_dims)
        n_levels = len(config.down_dims)

        self.down = nn.ModuleList()
        for i, (c_in, c_out) in enumerate(itertools.pairwise(dims)):
            last = i == n_levels - 1
            self.down.append(nn.ModuleList([
                FiLMResidualBlock(c_in, c_out, film_dim, k, g),
                FiLMResidualBlock(c_out, c_out, film_dim, k, g),
                nn.Identity() if last else nn.Conv1d(c_out, c_out, 3, stride=2, padding=1),
            ]))
        mid = config.down_dims[-1]
        self.mid = nn.ModuleList([
            FiLMResidualBlock(mid, mid, film_dim, k, g),
            FiLMResidualBlock(mid, mid, film_dim, k, g),
        ])
        self.up = nn.ModuleList()
        widths = config.down_dims
        for i in range(n_levels - 1, 0, -1):
            c_deep, c_skip = widths[i], widths[i - 1]
            self.up.append(nn.ModuleList([
                nn.ConvTranspose1d(c_deep, c_deep, 4, stride=2, padding=1),
                FiLMResidualBlock(c_deep + c_skip, c_skip, film_dim, k, g),
                FiLMResidualBlock(c_skip, c_skip, film_dim, k, g),
            ]))
        self.head = nn.Sequential(
            ConvNormAct(widths[0], widths[0], k, g), nn.Conv1d(widths[0], config.state_dim, 1)
        )

    def forward(self, x: Tensor, t: Tensor, cond: Tensor) -> Tensor:
        check_inputs(x, cond, self.state_dim, self.cond_dim)
        if t.ndim == 0:
            t = t.expand(x.shape[0])
        film = torch.cat([self.step_encoder(t), cond.to(x.dtype)], dim=-1)

        h = x.transpose(1, 2)  # (B, d, H): convolve along time
        skips = []
        for block1, block2, downsample in self.down:
            h = block2(block1(h, film), film)
            skips.append(h)
            h = downsample(h)
        skips.pop()  # the deepest level is not down-sampled; mid continues from it directly
        for block in self.mid:
            h = block(h, film)
        for upsample, block1, block2 in self.up:
            h = torch.cat([upsample(h), skips.pop()], dim=1)
            h = block2(block1(h, film), film)
        return self.head(h).transpose(1, 2)
