"""Settings of one person's spatial model (:class:`SpatialConfig`): the workspace box, the
grid, the belief's noise and prior, and the surrogate's training. No torch here."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike
from pydantic import Field, ValidationInfo, field_validator

from rapidds.settings import Flag, Int, Real, Settings

__all__ = ["SpatialConfig"]


def _is_int(v: Any) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def _is_real(v: Any) -> bool:
    return isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)


class SpatialConfig(Settings):
    """Settings of one person's spatial model (shared by all their human tasks).

    Attributes:
        bounds: (lo, hi) per workspace dimension, d >= 1 pairs with lo < hi, in world units (the
            fetch map is 2-D, the arm's workspace 3-D). The grid spans the box including its
            faces; evaluation clamps points outside the box onto it, so a robot path that leaves
            the box is charged the cost at the nearest face. Required: it is world geometry.
            A world that gives (lo, hi) arrays instead uses :meth:`SpatialConfig.from_box`.
        beta: distance decay of Eq. 7, 1 / world length unit; exp(-beta r) is the cost at
            distance r from the nearest human point. Default 1.0: a 1-unit gap costs 0.37, a
            3-unit gap 0.05, which suits workspaces about 10 units across; scale it with the
            world (for an arm in metres, beta ~ 10 gives the same shape over ~1 m).
        polyline: measure distance to the piecewise-linear path through the human's samples
            (True, default) or to the samples only (False, Eq. 7 as printed). The fetch world
            samples people every 0.2 s at up to 5 units/s, about 1 unit apart: with beta = 1
            the samples-only cost would dip to ~0.6 between samples on the path itself.
        rho: variance of one observed point cost around the person's true cost (the likelihood
            N(s*, rho) of Eq. 11). Costs lie in [0, 1]; a person repeating a route with a path
            jitter of delta units changes a nearby point's cost by about beta * delta, so
            delta = 0.2, beta = 1 gives rho ~ 0.04. Default 0.05. Smaller rho trusts single
            cycles more.
        prior_var: prior variance of every grid point's belief. None (default) takes the
            population spread: the per-point variance of the M prior people's point costs
            (an empirical-Bayes prior: where people disagreed the model learns fast, where they
            agreed it needs more evidence), floored at ``min_prior_var``. A float sets the same
            prior variance everywhere.
        min_prior_var: floor of the population-spread prior variance, so a point where all
            prior people agreed (or M = 1) can still adapt: with the defaults 0.01 and
            rho = 0.05 a person who always differs there moves the estimate 17 % of the way
            after one cycle and 50 % after five.
        grid_points: points per axis of the regular grid, an int for all axes or one per axis,
            each >= 2; V is their product. Default 32 (V = 1024 in 2-D, 32768 in 3-D): spacing
            ~0.3 units on a 10-unit map, finer than the 1/beta decay length.
        hidden: width of the surrogate MLP's hidden layers.
        layers: number of hidden layers of the MLP (>= 1).
        fourier: octaves of the MLP's positional encoding [u, sin(2^k pi u), cos(2^k pi u)],
            k < fourier, u the point scaled to [-1, 1]. The cost has sharp ridges along the
            routes that a plain coordinate MLP needs thousands of steps to resolve. Frequencies
            above the grid's Nyquist limit let the MLP oscillate between grid points where
            nothing constrains it, so None (default) takes the most octaves whose top frequency
            2^(k-1) pi stays within the coarsest axis's limit (n - 1) pi / 2: 4 for n = 32,
            3 for n = 16. 0 disables the encoding.
        steps: maximum Adam steps of one fit.
        batch: grid points per Adam step; the full grid when V <= batch (the 2-D default, no
            sampling noise), else a seeded random subset, which keeps a step of a 32^3 grid as
            cheap as one of a 64^2 grid.
        lr: Adam learning rate. 1e-2 reached tol in about half the steps of 3e-3 on the fetch-
            like test layouts, without instability.
        tol: a fit stops early once the MLP's maximum absolute error against the posterior mean
            at the grid points is <= tol (checked every 25 steps), which is what makes a
            warm-started refit after one cycle cheap. 0 always runs ``steps``.
        seed: seed of the MLP's initial weights and of surrogate_error's random test points;
            the same seed and observations give the same weights on CPU.
        use_surrogate: evaluate s_i with the MLP (True, the paper) or by exact multilinear grid
            interpolation (False, default). Interpolation is exact at the grid points,
            continuous, needs no training and is faster per point on CPU (docs/benchmarks.md),
            so it is the default; the MLP is kept for fidelity to the paper and is held to
            ``surrogate_error``.
        chunk: most points evaluated at once, bounding the memory of one call (MLP activations
            are chunk x hidden floats).
        forgetting: factor f in (0, 1] applied before every observation: the belief is raised
            to the power f (precision times f, mean kept: exponential forgetting, as the
            temporal model's), so it holds about 1/(1 - f) observations, precision at most
            1/(rho (1 - f)), and follows a person whose paths change. 1 (default): the paper's
            Eqs. 10-11 exactly.
    """

    label: ClassVar[str] = "SpatialConfig"

    bounds: Annotated[tuple[tuple[Real, Real], ...], Field(min_length=1)]
    beta: Annotated[Real, Field(gt=0)] = 1.0
    polyline: Flag = True
    rho: Annotated[Real, Field(gt=0)] = 0.05
    prior_var: Annotated[Real, Field(gt=0)] | None = None
    min_prior_var: Annotated[Real, Field(gt=0)] = 0.01
    grid_points: Annotated[Int | tuple[Int, ...], Field(validate_default=True)] = 32
    hidden: Annotated[Int, Field(ge=1)] = 64
    layers: Annotated[Int, Field(ge=1)] = 3
    fourier: Annotated[Int, Field(ge=0)] | None = None
    steps: Annotated[Int, Field(ge=1)] = 3000
    batch: Annotated[Int, Field(ge=1)] = 4096
    lr: Annotated[Real, Field(gt=0)] = 1e-2
    tol: Annotated[Real, Field(ge=0)] = 0.02
    seed: Annotated[Int, Field(ge=0)] = 0
    use_surrogate: Flag = False
    chunk: Annotated[Int, Field(ge=1)] = 1 << 16
    forgetting: Annotated[Real, Field(gt=0, le=1)] = 1.0

    @field_validator("bounds")
    @classmethod
    def _boxes(cls, v: tuple[tuple[float, float], ...]) -> tuple[tuple[float, float], ...]:
        for k, (lo, hi) in enumerate(v):
            if not lo < hi:
                raise ValueError(f"[{k}] needs lo < hi, got {(lo, hi)}")
        return v

    @field_validator("grid_points")
    @classmethod
    def _per_axis(cls, v: int | tuple[int, ...], info: ValidationInfo) -> tuple[int, ...]:
        """One count per axis (an int is the same on every axis), each >= 2."""
        d = len(info.data.get("bounds", ()))
        grid = (v,) * d if isinstance(v, int) else tuple(v)
        if len(grid) != d or not all(n >= 2 for n in grid):
            raise ValueError(f"must be an int >= 2 or {d} of them (one per axis), got {v!r}")
        return grid

    @classmethod
    def from_box(cls, lo: ArrayLike, hi: ArrayLike, **kwargs: Any) -> SpatialConfig:
        """Config for the box lo <= x <= hi given as two (d,) arrays (a world's ``bounds``)."""
        lo_a = np.asarray(lo, dtype=float).reshape(-1)
        hi_a = np.asarray(hi, dtype=float).reshape(-1)
        if lo_a.shape != hi_a.shape:
            raise ValueError(f"SpatialConfig.from_box: lo {lo_a.shape} and hi {hi_a.shape} differ")
        return cls(bounds=tuple(zip(lo_a.tolist(), hi_a.tolist(), strict=True)), **kwargs)

    @property
    def dim(self) -> int:
        """d, the workspace dimension."""
        return len(self.bounds)

    @property
    def shape(self) -> tuple[int, ...]:
        """Grid shape, one entry per axis."""
        return self.grid_points  # type: ignore[return-value]  # one per axis, _per_axis

    @property
    def octaves(self) -> int:
        """Octaves of the positional encoding actually used (``fourier`` resolved)."""
        if self.fourier is not None:
            return int(self.fourier)
        return math.floor(math.log2((min(self.shape) - 1) / 2)) + 1

    @property
    def n_points(self) -> int:
        """V, the number of grid points."""
        return math.prod(self.shape)

    def grid(self) -> np.ndarray:
        """(V, d) grid points, C order over ``shape`` (the last axis varies fastest)."""
        axes = [np.linspace(lo, hi, n) for (lo, hi), n in zip(self.bounds, self.shape,
                                                               strict=True)]
        mesh = np.meshgrid(*axes, indexing="ij")
        return np.stack([m.reshape(-1) for m in mesh], axis=-1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict; ``SpatialConfig.from_dict`` inverts it."""
        out = dict(self.__dict__)
        out["bounds"] = [list(p) for p in self.bounds]
        out["grid_points"] = list(self.shape)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SpatialConfig:
        """Inverse of :meth:`to_dict`; unknown keys or bad values raise ValueError."""
        return cls(**dict(data))
