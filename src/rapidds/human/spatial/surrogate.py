"""The MLP surrogate of a learned spatial cost (the paper's choice between grid points) and
what a fit reports. The only part of the spatial model that needs torch's autograd."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

__all__ = ["FitReport", "Surrogate", "SurrogateError"]


@dataclass(frozen=True)
class FitReport:
    """Outcome of one surrogate fit: Adam steps taken, wall seconds, final mean squared error and
    maximum absolute error against the posterior mean at the grid points."""

    steps: int
    seconds: float
    mse: float
    max_abs_error: float


@dataclass(frozen=True)
class SurrogateError:
    """Absolute difference |MLP - grid interpolation|: at the V grid points, where interpolation
    is the posterior mean itself, and at uniform random points of the box, where it also shows
    how the two interpolate differently between grid points."""

    grid_max: float
    grid_mean: float
    random_max: float
    random_mean: float


class Surrogate(nn.Module):
    """MLP u (n, d) in [-1, 1]^d -> (n,) cost, with an axis-aligned positional encoding."""

    def __init__(self, d: int, hidden: int, layers: int, fourier: int):
        super().__init__()
        self.freqs: torch.Tensor
        self.register_buffer("freqs", math.pi * 2.0 ** torch.arange(fourier, dtype=torch.float32))
        width = d * (1 + 2 * fourier)
        mods: list[nn.Module] = []
        for _ in range(layers):
            mods += [nn.Linear(width, hidden), nn.SiLU()]
            width = hidden
        mods.append(nn.Linear(width, 1))
        self.net = nn.Sequential(*mods)

    def forward(self, u: torch.Tensor) -> torch.Tensor:
        if self.freqs.numel():
            z = (u[:, :, None] * self.freqs).flatten(1)
            u = torch.cat([u, torch.sin(z), torch.cos(z)], dim=1)
        return self.net(u).squeeze(-1)
