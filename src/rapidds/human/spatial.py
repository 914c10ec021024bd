"""Individual spatial cost model: where this person is while doing each task (paper, "Spatial
Adaptation", Eqs. 7-11).

For a robot point x and one human path xi_h the point cost is
s(x, xi_h) = max_{x_h in xi_h} exp(-beta ||x_h - x||) (Eq. 7; by default the max runs over the
piecewise-linear path through the samples, see ``SpatialConfig.polyline``). For every human task
the model keeps, at the V points of a regular grid over the workspace, a Gaussian belief about
this person's expected point cost s*(x) (Eq. 8): its prior is the population average (Eq. 9),
and every observed path of the person updates it by the conjugate Normal rule with observation
variance rho (Eqs. 10-11). Between grid points the cost is either a small MLP fitted to the
posterior mean (the paper's choice) or exact multilinear interpolation of the grid (the
reference the MLP is held against, and the default). The cost of a robot trajectory is the
maximum over its points, the paper's S_i(xi), and a set of concurrent human tasks costs the
maximum over the tasks.

Storage: :meth:`SpatialModel.to_dict` is JSON-safe (arrays as little-endian base64 with dtype
and shape, so float64 beliefs and float32 MLP weights round-trip bit for bit);
:meth:`SpatialModel.save` writes that dict as JSON with a SHA-256 of its body, atomically.
"""

from __future__ import annotations

import base64
import hashlib
import itertools
import json
import math
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar, TypeVar

import numpy as np
import torch
from numpy.typing import ArrayLike
from pydantic import Field, ValidationInfo, field_validator
from torch import nn

from rapidds.errors import StateError
from rapidds.fileio import atomic_write_text
from rapidds.settings import Flag, Int, Real, Settings

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "FitReport",
    "SpatialConfig",
    "SpatialCostModel",
    "SpatialModel",
    "SurrogateError",
    "point_cost",
]

FORMAT = "rapidds.spatial-model"
FORMAT_VERSION = 1

# Elements of the largest temporary (chunk x T x d) array point_cost builds: 8 MiB of float64.
_POINT_COST_ELEMS = 1 << 20

Points = TypeVar("Points", np.ndarray, torch.Tensor)


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


def _check_points(a: ArrayLike, what: str, d: int | None = None) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{what} must be a non-empty (n, d) array, got shape {arr.shape}")
    if d is not None and arr.shape[1] != d:
        raise ValueError(f"{what} has {arr.shape[1]} coordinates per point, the model has {d}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{what} contains NaN or infinite coordinates")
    return arr


def _check_path(a: ArrayLike, what: str, d: int) -> np.ndarray:
    """A validated human path, (T, d) (one body point) or (T, K, d) (K body points, each a
    polyline over the same T samples), as float64 in the same layout."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 3:
        if 0 in arr.shape:
            raise ValueError(f"{what} must be a non-empty (T, K, d) array, got shape {arr.shape}")
        if arr.shape[2] != d:
            raise ValueError(f"{what} has {arr.shape[2]} coordinates per point, the model has {d}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{what} contains NaN or infinite coordinates")
        return arr
    if arr.ndim != 2:
        raise ValueError(f"{what} must be a non-empty (T, d) or (T, K, d) array, got shape "
                         f"{arr.shape}")
    return _check_points(arr, what, d)


def point_cost(
    points: ArrayLike, human_traj: ArrayLike, beta: float, *, polyline: bool = True
) -> np.ndarray:
    """Eq. 7: s(x, xi_h) = max over the human path of exp(-beta ||x_h - x||), for every x.

    Args:
        points: (V, d) robot points x.
        human_traj: (T, d) human path xi_h, T >= 1 samples in time order; or (T, K, d), K body
            points (hands, elbows, ...) each followed over the same T samples: the cost is then
            the max over the K paths, i.e. set by the body point nearest to x.
        beta: distance decay, > 0.
        polyline: True takes each path as the piecewise-linear route through its samples (the
            person is between two samples between time steps); False takes the samples alone,
            as Eq. 7 is printed, which leaves dips between samples spaced wider than ~1/beta.

    Returns:
        (V,) float64 costs in (0, 1]. The exponential is monotone, so this is
        exp(-beta * distance to the nearest path point or segment), computed in chunks of points
        so the (chunk, S, d) temporaries stay near 8 MiB (S segments of all K paths together).
    """
    if not _is_real(beta) or not math.isfinite(beta) or beta <= 0:
        raise ValueError(f"beta must be a finite number > 0, got {beta!r}")
    pts = _check_points(points, "points")
    traj = _check_path(human_traj, "human_traj", pts.shape[1])
    paths = traj[None] if traj.ndim == 2 else traj.transpose(1, 0, 2)   # (K, T, d)
    if polyline and paths.shape[1] > 1:
        # The segments of every body point's path, and only those: no segment joins the end of
        # one body point's path to the start of the next.
        start = paths[:, :-1].reshape(-1, pts.shape[1])
        seg = np.diff(paths, axis=1).reshape(-1, pts.shape[1])  # (S, d)
        seg_len2 = np.einsum("sd,sd->s", seg, seg)
        inv = np.divide(1.0, seg_len2, out=np.zeros_like(seg_len2), where=seg_len2 > 0)
    else:
        start = paths.reshape(-1, pts.shape[1])
        seg, inv = np.zeros_like(start), np.zeros(len(start))
    s, d = start.shape
    step = max(1, _POINT_COST_ELEMS // (s * d))
    nearest = np.empty(len(pts))
    for k in range(0, len(pts), step):
        rel = pts[k:k + step, None, :] - start[None]  # (c, S, d)
        t = np.clip(np.einsum("csd,sd->cs", rel, seg) * inv, 0.0, 1.0)
        rel -= t[..., None] * seg
        nearest[k:k + step] = np.einsum("csd,csd->cs", rel, rel).min(axis=1)
    return np.exp(-float(beta) * np.sqrt(nearest))


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


class _Surrogate(nn.Module):
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


def _encode(a: np.ndarray) -> dict[str, Any]:
    a = np.ascontiguousarray(a)
    le = a.astype(a.dtype.newbyteorder("<"), copy=False)
    return {"dtype": le.dtype.str, "shape": list(a.shape),
            "data": base64.b64encode(le.tobytes()).decode("ascii")}


def _decode(obj: Any, what: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    try:
        dtype = np.dtype(obj["dtype"])
        if dtype.kind != "f":
            raise ValueError(f"dtype {dtype} is not floating point")
        arr = np.frombuffer(base64.b64decode(obj["data"], validate=True), dtype=dtype)
        arr = arr.reshape([int(n) for n in obj["shape"]]).astype(dtype.newbyteorder("="))
    except (KeyError, TypeError, ValueError) as e:
        raise StateError(f"spatial model: {what} is not a valid encoded array ({e})") from None
    if shape is not None and arr.shape != shape:
        raise StateError(f"spatial model: {what} has shape {arr.shape}, expected {shape}")
    if not np.isfinite(arr).all():
        raise StateError(f"spatial model: {what} contains NaN or infinite values")
    return arr


class SpatialCostModel:
    """Belief about one person's expected point cost s_i(x) for one human task.

    Holds (V,) posterior mean and variance at the grid points of ``config`` and, when fitted, an
    MLP approximating the mean. Build it with :meth:`from_population`.
    """

    def __init__(
        self,
        config: SpatialConfig,
        mean: ArrayLike,
        var: ArrayLike,
        *,
        prior_mean: ArrayLike | None = None,
        prior_var: ArrayLike | None = None,
        n_obs: int = 0,
    ):
        self.config = config
        v = config.n_points
        self._mean = np.array(mean, dtype=np.float64).reshape(-1)
        self._var = np.array(var, dtype=np.float64).reshape(-1)
        self._prior_mean = (self._mean.copy() if prior_mean is None
                            else np.array(prior_mean, dtype=np.float64).reshape(-1))
        self._prior_var = (self._var.copy() if prior_var is None
                           else np.array(prior_var, dtype=np.float64).reshape(-1))
        for name, a in (("mean", self._mean), ("var", self._var), ("prior_mean", self._prior_mean),
                        ("prior_var", self._prior_var)):
            if a.shape != (v,):
                raise ValueError(f"{name} must have V = {v} values, got {a.shape}")
            if not np.isfinite(a).all():
                raise ValueError(f"{name} contains NaN or infinite values")
        if (self._var <= 0).any() or (self._prior_var <= 0).any():
            raise ValueError("var and prior_var must be > 0 at every grid point")
        if not _is_int(n_obs) or n_obs < 0:
            raise ValueError(f"n_obs must be an integer >= 0, got {n_obs!r}")
        self.n_obs = int(n_obs)
        self.n_fits = 0
        self._grid = config.grid()
        self._lo = np.array([b[0] for b in config.bounds])
        self._hi = np.array([b[1] for b in config.bounds])
        shape = config.shape
        self._strides = [math.prod(shape[k + 1:]) for k in range(len(shape))]
        self._net: _Surrogate | None = None
        self._stale = True
        self._grid_cache: dict[tuple[torch.device, torch.dtype], torch.Tensor] = {}
        self._net_cache: dict[torch.device, _Surrogate] = {}

    @classmethod
    def from_population(
        cls, config: SpatialConfig, trajectories: Sequence[ArrayLike]
    ) -> SpatialCostModel:
        """Prior from M >= 1 other people's paths of this task (each (T_m, d), or (T_m, K, d)
        for K body points; see :func:`point_cost`).

        Mean: Eq. 9, the average over people of their point costs. Variance: ``config.prior_var``
        or, when None, the per-point population variance floored at ``config.min_prior_var``.
        """
        if len(trajectories) == 0:
            raise ValueError("from_population needs at least one population trajectory")
        grid = config.grid()
        costs = np.stack([
            point_cost(grid, _check_path(t, f"population trajectory {m}", config.dim),
                       config.beta, polyline=config.polyline)
            for m, t in enumerate(trajectories)
        ])
        mean = costs.mean(axis=0)
        if config.prior_var is None:
            var = np.maximum(costs.var(axis=0), config.min_prior_var)
        else:
            var = np.full(config.n_points, config.prior_var)
        return cls(config, mean, var)

    # ----------------------------------------------------------------------------- belief
    @property
    def grid_points(self) -> np.ndarray:
        """(V, d) grid points (a copy)."""
        return self._grid.copy()

    @property
    def mean(self) -> np.ndarray:
        """(V,) posterior mean of s*(x) at the grid points (a copy)."""
        return self._mean.copy()

    @property
    def var(self) -> np.ndarray:
        """(V,) posterior variance at the grid points (a copy)."""
        return self._var.copy()

    @property
    def prior_mean(self) -> np.ndarray:
        """(V,) population prior mean, Eq. 9 (a copy)."""
        return self._prior_mean.copy()

    @property
    def prior_var(self) -> np.ndarray:
        """(V,) population prior variance (a copy): where forgetting and a reset return to."""
        return self._prior_var.copy()

    @property
    def surrogate_stale(self) -> bool:
        """True when the MLP is missing or was fitted to an older posterior."""
        return self._stale

    def observe(self, traj: ArrayLike) -> None:
        """Conjugate update with one observed path (T, d) or (T, K, d) of this person
        (Eqs. 10-11).

        At every grid point s_obs = point_cost(x, traj);
        1/var' = 1/var + 1/rho and mean' = var' (mean/var + s_obs/rho). Marks the MLP stale.
        """
        obs = point_cost(self._grid, _check_path(traj, "trajectory", self.config.dim),
                         self.config.beta, polyline=self.config.polyline)
        rho, f = self.config.rho, self.config.forgetting
        var = self._var / f if f < 1 else self._var  # forgetting: precision times f
        new_var = 1.0 / (1.0 / var + 1.0 / rho)
        self._mean = new_var * (self._mean / var + obs / rho)
        self._var = new_var
        self.n_obs += 1
        self._stale = True
        self._grid_cache.clear()

    def reset(self) -> None:
        """Back to the population prior (a detected change: this person's old paths no longer
        describe them). ``n_obs`` keeps counting what was observed."""
        self._mean = self._prior_mean.copy()
        self._var = self._prior_var.copy()
        self._stale = True
        self._grid_cache.clear()

    # ------------------------------------------------------------------------- surrogate
    def _new_net(self) -> _Surrogate:
        c = self.config
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(c.seed)
            net = _Surrogate(c.dim, c.hidden, c.layers, c.octaves)
        return net

    def _unit(self, x: np.ndarray) -> np.ndarray:
        return 2.0 * (x - self._lo) / (self._hi - self._lo) - 1.0

    def fit_surrogate(self, steps: int | None = None) -> FitReport:
        """Fit the MLP to the posterior mean at the grid points (Adam on the squared error).

        Warm-starts from the previous weights when there are any, so a refit after one cycle
        usually stops after a few hundred steps at ``config.tol`` (0 steps when the old fit is
        still within tol). Deterministic on CPU for a given history of observations and fits.
        ``steps`` overrides ``config.steps``.
        """
        c = self.config
        n_steps = c.steps if steps is None else steps
        if not _is_int(n_steps) or n_steps < 1:
            raise ValueError(f"steps must be an integer >= 1, got {n_steps!r}")
        t0 = time.perf_counter()
        if self._net is None:
            self._net = self._new_net()
        net = self._net
        net.train()
        u = torch.as_tensor(self._unit(self._grid), dtype=torch.float32)
        target = torch.as_tensor(self._mean, dtype=torch.float32)
        opt = torch.optim.Adam(net.parameters(), lr=c.lr)
        gen = torch.Generator().manual_seed(c.seed * 1_000_003 + self.n_fits)
        v = len(target)

        def check() -> tuple[float, float]:
            with torch.no_grad():
                r = net(u).clamp(0.0, 1.0) - target
            return float((r * r).mean()), float(r.abs().max())

        done, (mse, err) = 0, ((math.inf, math.inf) if self.n_fits == 0 else check())
        while done < n_steps and err > c.tol:
            opt.zero_grad(set_to_none=True)
            if v <= c.batch:
                resid = net(u) - target
            else:
                idx = torch.randint(v, (c.batch,), generator=gen)
                resid = net(u[idx]) - target[idx]
            loss = (resid * resid).mean()
            loss.backward()
            opt.step()
            done += 1
            if done % 25 == 0 or done == n_steps:
                mse, err = check()
        net.eval()
        self.n_fits += 1
        self._stale = False
        self._net_cache.clear()
        return FitReport(done, time.perf_counter() - t0, mse, err)

    def surrogate_error(self, n_random: int = 4096) -> SurrogateError:
        """|MLP - grid interpolation| at the grid points and at ``n_random`` uniform random
        points (seeded by ``config.seed``). Fits the MLP first if it is stale."""
        if self._stale:
            self.fit_surrogate()
        rng = np.random.default_rng(self.config.seed)
        rand = self._lo + (self._hi - self._lo) * rng.random((n_random, self.config.dim))
        out = []
        with torch.no_grad():
            for pts in (self._grid, rand):
                x = torch.as_tensor(pts)
                diff = (self._eval_mlp(x) - self._eval_grid(x)).abs()
                out += [float(diff.max()), float(diff.mean())]
        return SurrogateError(*out)

    # ------------------------------------------------------------------------ evaluation
    def _grid_values(self, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
        key = (device, dtype)
        if key not in self._grid_cache:
            self._grid_cache[key] = torch.as_tensor(self._mean, dtype=dtype, device=device)
        return self._grid_cache[key]

    def _eval_grid(self, x: torch.Tensor) -> torch.Tensor:
        """Multilinear interpolation of the posterior mean, (n, d) -> (n,), clamped to bounds."""
        shape = self.config.shape
        vals = self._grid_values(x.device, x.dtype)
        lo = torch.as_tensor(self._lo, dtype=x.dtype, device=x.device)
        hi = torch.as_tensor(self._hi, dtype=x.dtype, device=x.device)
        top = torch.as_tensor([n - 1 for n in shape], dtype=x.dtype, device=x.device)
        u = ((x - lo) / (hi - lo) * top).clamp(min=torch.zeros_like(top), max=top)
        i0 = torch.minimum(u.floor(), top - 1)
        frac = u - i0
        i0 = i0.long()
        out = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
        for corner in itertools.product((0, 1), repeat=len(shape)):
            idx = torch.zeros(x.shape[0], dtype=torch.long, device=x.device)
            w = torch.ones_like(out)
            for k, c in enumerate(corner):
                idx += (i0[:, k] + c) * self._strides[k]
                w *= frac[:, k] if c else 1.0 - frac[:, k]
            out += w * vals[idx]
        return out

    def _mlp_on(self, device: torch.device) -> _Surrogate:
        assert self._net is not None
        if device.type == "cpu":
            return self._net
        if device not in self._net_cache:
            net = self._new_net().to(device)
            net.load_state_dict(self._net.state_dict())
            net.eval()
            self._net_cache[device] = net
        return self._net_cache[device]

    def _eval_mlp(self, x: torch.Tensor) -> torch.Tensor:
        net = self._mlp_on(x.device)
        lo = torch.as_tensor(self._lo, dtype=torch.float32, device=x.device)
        hi = torch.as_tensor(self._hi, dtype=torch.float32, device=x.device)
        u = (2.0 * (x.to(torch.float32) - lo) / (hi - lo) - 1.0).clamp(-1.0, 1.0)
        return net(u).clamp(0.0, 1.0).to(x.dtype)

    def _eval_flat(self, x: torch.Tensor) -> torch.Tensor:
        if not bool(torch.isfinite(x).all()):
            raise ValueError("points contain NaN or infinite coordinates")
        if self.config.use_surrogate and self._stale:
            self.fit_surrogate()
        fn = self._eval_mlp if self.config.use_surrogate else self._eval_grid
        step = self.config.chunk
        with torch.no_grad():
            if x.shape[0] <= step:
                return fn(x)
            return torch.cat([fn(x[s:s + step]) for s in range(0, x.shape[0], step)])

    def point_cost(self, x: Points) -> Points:
        """s_i(x) for points x (..., d) -> (...), by MLP or grid interpolation per
        ``config.use_surrogate``; points outside the bounds are clamped onto them.

        NumPy in gives float64 NumPy out; a tensor gives a tensor of its dtype on its device
        (integer tensors are evaluated as float32). A stale MLP is refitted first.
        """
        return _evaluate(self, x, ndim=None)

    def trajectory_cost(self, xi: Points) -> Points:
        """S_i(xi) = max over the path's points of s_i: xi (N, H, d) -> (N,).

        One batched evaluation of all N*H points (the steering hot loop calls this with
        N = particles x candidates).
        """
        return _evaluate(self, xi, ndim=3)

    # ----------------------------------------------------------------------- persistence
    def to_dict(self) -> dict[str, Any]:
        """JSON-safe: config, belief arrays, observation count, and the MLP (or None): weights,
        number of fits so far and whether it was fitted to the current posterior."""
        surrogate = None
        if self._net is not None:
            surrogate = {
                "stale": self._stale,
                "n_fits": self.n_fits,
                "state": {k: _encode(v.detach().cpu().numpy())
                          for k, v in self._net.state_dict().items()},
            }
        return {
            "config": self.config.to_dict(),
            "n_obs": self.n_obs,
            "mean": _encode(self._mean),
            "var": _encode(self._var),
            "prior_mean": _encode(self._prior_mean),
            "prior_var": _encode(self._prior_var),
            "surrogate": surrogate,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SpatialCostModel:
        """Inverse of :meth:`to_dict`; raises StateError when the dict is malformed or its
        arrays do not fit its config."""
        if not isinstance(data, Mapping):
            raise StateError("spatial model: task entry is not a mapping")
        try:
            config = SpatialConfig.from_dict(data["config"])
        except (KeyError, TypeError, ValueError) as e:
            raise StateError(f"spatial model: bad config ({e})") from None
        v = (config.n_points,)
        mean = _decode(data.get("mean"), "mean", v)
        var = _decode(data.get("var"), "var", v)
        prior = _decode(data.get("prior_mean"), "prior_mean", v)
        # files written before forgetting existed hold no prior variance; only a model that
        # forgets or resets reads it, and such a model always stored it
        prior_var = (_decode(data["prior_var"], "prior_var", v) if "prior_var" in data
                     else None)
        try:
            model = cls(config, mean, var, prior_mean=prior, prior_var=prior_var,
                        n_obs=data.get("n_obs", -1))
        except ValueError as e:
            raise StateError(f"spatial model: {e}") from None
        sur = data.get("surrogate")
        if sur is not None:
            net = model._new_net()
            try:
                state = {k: torch.from_numpy(_decode(a, f"MLP weight {k}"))
                         for k, a in sur["state"].items()}
                net.load_state_dict(state)
                stale, n_fits = sur["stale"], sur["n_fits"]
            except (KeyError, TypeError, AttributeError, RuntimeError) as e:
                raise StateError(
                    f"spatial model: MLP weights do not fit the config ({e})"
                ) from None
            if not isinstance(stale, bool) or not _is_int(n_fits) or n_fits < 1:
                raise StateError("spatial model: bad surrogate.stale or surrogate.n_fits")
            net.eval()
            model._net, model._stale, model.n_fits = net, stale, int(n_fits)
        return model


def _evaluate(model: SpatialCostModel, x: Any, ndim: int | None) -> Any:
    """Shared input handling of point_cost / trajectory_cost: type, shape, dtype round trip."""
    d = model.config.dim
    is_tensor = isinstance(x, torch.Tensor)
    t = x if is_tensor else torch.from_numpy(np.asarray(x, dtype=np.float64))
    if not t.is_floating_point():
        t = t.to(torch.float32)
    if t.ndim < 1 or t.shape[-1] != d:
        raise ValueError(f"points must have shape (..., {d}), got {tuple(t.shape)}")
    if ndim is not None and (t.ndim != ndim or t.shape[1] == 0):
        raise ValueError(f"trajectories must have shape (N, H, {d}) with H >= 1, "
                         f"got {tuple(t.shape)}")
    out = model._eval_flat(t.reshape(-1, d)).reshape(t.shape[:-1])
    if ndim is not None:
        out = out.amax(dim=-1)
    return out if is_tensor else out.numpy()


class SpatialModel:
    """One person's spatial models, one :class:`SpatialCostModel` per human task id."""

    def __init__(self, config: SpatialConfig, models: Mapping[str, SpatialCostModel]):
        for tid, m in models.items():
            if m.config != config:
                raise ValueError(f"task '{tid}' has a different SpatialConfig than the model")
        self.config = config
        self._models = dict(models)

    @classmethod
    def from_population(
        cls, config: SpatialConfig, trajectories: Mapping[str, Sequence[ArrayLike]]
    ) -> SpatialModel:
        """Prior models from population paths: task id -> list of (T, d) or (T, K, d) arrays
        (Eq. 9)."""
        return cls(config, {tid: SpatialCostModel.from_population(config, trajs)
                            for tid, trajs in trajectories.items()})

    @property
    def tasks(self) -> tuple[str, ...]:
        """Task ids with a model, in insertion order."""
        return tuple(self._models)

    def __getitem__(self, task_id: str) -> SpatialCostModel:
        try:
            return self._models[task_id]
        except KeyError:
            raise KeyError(f"no spatial model for task '{task_id}'; known: "
                           f"{list(self._models)}") from None

    def __contains__(self, task_id: object) -> bool:
        return task_id in self._models

    def __iter__(self) -> Iterator[str]:
        return iter(self._models)

    def __len__(self) -> int:
        return len(self._models)

    def observe(self, task_id: str, traj: ArrayLike) -> None:
        """Update task ``task_id`` with one observed path (T, d) or (T, K, d) of this person."""
        self[task_id].observe(traj)

    def refit(self, tasks: Iterable[str] | None = None) -> dict[str, FitReport]:
        """Refit the stale MLPs of ``tasks`` (default: all). Does nothing when
        ``config.use_surrogate`` is False, since then nothing evaluates the MLP."""
        if not self.config.use_surrogate:
            return {}
        ids = self.tasks if tasks is None else tuple(tasks)
        return {tid: self[tid].fit_surrogate() for tid in ids if self[tid].surrogate_stale}

    def cost(self, task_ids: Iterable[str], xi: Points) -> Points:
        """max_{i in task_ids} S_i(xi) for trajectories xi (N, H, d) -> (N,); 0 for no tasks."""
        ids = list(dict.fromkeys(task_ids))
        if not ids:
            arr = xi if isinstance(xi, torch.Tensor) else np.asarray(xi, dtype=np.float64)
            if arr.ndim != 3 or arr.shape[1] == 0 or arr.shape[-1] != self.config.dim:
                raise ValueError(f"trajectories must have shape (N, H, {self.config.dim}) with "
                                 f"H >= 1, got {tuple(arr.shape)}")
            if isinstance(arr, torch.Tensor):
                dtype = arr.dtype if arr.is_floating_point() else torch.float32
                return torch.zeros(arr.shape[0], dtype=dtype, device=arr.device)
            return np.zeros(arr.shape[0])
        costs = [self[tid].trajectory_cost(xi) for tid in ids]
        if isinstance(costs[0], torch.Tensor):
            return torch.stack(costs).amax(dim=0)
        return np.max(np.stack(costs), axis=0)

    # ----------------------------------------------------------------------- persistence
    def to_dict(self) -> dict[str, Any]:
        """JSON-safe: format tag and version, config, and each task's model dict."""
        return {"format": FORMAT, "version": FORMAT_VERSION, "config": self.config.to_dict(),
                "tasks": {tid: m.to_dict() for tid, m in self._models.items()}}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SpatialModel:
        """Inverse of :meth:`to_dict`; StateError on a wrong format, version or content."""
        if not isinstance(data, Mapping) or data.get("format") != FORMAT:
            raise StateError(f"not a {FORMAT} document")
        if data.get("version") != FORMAT_VERSION:
            raise StateError(f"spatial model format version {data.get('version')!r} is not "
                             f"supported (expected {FORMAT_VERSION})")
        try:
            config = SpatialConfig.from_dict(data["config"])
            tasks = dict(data["tasks"])
        except (KeyError, TypeError, ValueError) as e:
            raise StateError(f"spatial model: bad config or task table ({e})") from None
        models = {}
        for tid, entry in tasks.items():
            m = SpatialCostModel.from_dict(entry)
            if m.config != config:
                raise StateError(f"spatial model: task '{tid}' was stored with another config")
            models[str(tid)] = m
        return cls(config, models)

    def save(self, path: str | Path) -> Path:
        """Write JSON {format, version, sha256, body} atomically (temp file + os.replace)."""
        body = self.to_dict()
        text = json.dumps(body, sort_keys=True, separators=(",", ":"))
        digest = hashlib.sha256(text.encode()).hexdigest()
        path = Path(path)
        atomic_write_text(path, f'{{"sha256":"{digest}","body":{text}}}')
        return path

    @classmethod
    def load(cls, path: str | Path, config: SpatialConfig | None = None) -> SpatialModel:
        """Read a file written by :meth:`save`. StateError when it is missing, unreadable,
        corrupt (checksum), of another format, or, given ``config``, saved with another one."""
        path = Path(path)
        try:
            raw = json.loads(path.read_text())
            body = raw["body"]
            digest = raw["sha256"]
        except FileNotFoundError:
            raise StateError(f"no spatial model at {path}") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as e:
            raise StateError(f"spatial model {path} is unreadable or corrupt ({e})") from None
        text = json.dumps(body, sort_keys=True, separators=(",", ":"))
        if hashlib.sha256(text.encode()).hexdigest() != digest:
            raise StateError(f"spatial model {path} is corrupt (checksum mismatch)")
        model = cls.from_dict(body)
        if config is not None and model.config != config:
            raise StateError(f"spatial model {path} was saved with a different SpatialConfig")
        return model
