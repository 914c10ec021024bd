"""The grid belief of one person's expected point cost for one task (paper Eqs. 7-11):
:func:`point_cost` (Eq. 7) and :class:`SpatialCostModel` (the conjugate Normal belief at the
grid points, evaluated by multilinear interpolation or the MLP surrogate)."""

from __future__ import annotations

import inspect
import itertools
import math
import time
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

import numpy as np
import torch
from numpy.typing import ArrayLike

from rapidds.cache import cached_arrays, code_version, content_key
from rapidds.codec import decode_array, encode_array
from rapidds.errors import StateError
from rapidds.human.spatial.config import SpatialConfig, _is_int
from rapidds.human.spatial.path_cost import check_path, point_cost
from rapidds.human.spatial.surrogate import FitReport, Surrogate, SurrogateError

__all__ = ["Points", "SpatialCostModel", "grid_trajectory_costs"]

Points = TypeVar("Points", np.ndarray, torch.Tensor)


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
        self._net: Surrogate | None = None
        self._stale = True
        self._grid_cache: dict[tuple[Any, ...], tuple[torch.Tensor, ...]] = {}
        self._net_cache: dict[torch.device, Surrogate] = {}

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
        paths = [check_path(t, f"population trajectory {m}", config.dim)
                 for m, t in enumerate(trajectories)]

        def build() -> dict[str, np.ndarray]:
            costs = np.stack([point_cost(grid, p, config.beta, polyline=config.polyline)
                              for p in paths])
            return {"mean": costs.mean(axis=0), "var": costs.var(axis=0)}

        # seconds of point costs, the same in every run with these paths (the population
        # prior, a simulated person's truth): built once, then read back bit for bit
        key = content_key(code_version(__file__, inspect.getfile(point_cost)), grid,
                          float(config.beta), config.polyline, *paths)
        stats = cached_arrays("population-costs", key, ("mean", "var"), build)
        mean = stats["mean"]
        if config.prior_var is None:
            var = np.maximum(stats["var"], config.min_prior_var)
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

    def observe(self, traj: ArrayLike, device: str | torch.device | None = None) -> None:
        """Conjugate update with one observed path (T, d) or (T, K, d) of this person
        (Eqs. 10-11).

        At every grid point s_obs = point_cost(x, traj);
        1/var' = 1/var + 1/rho and mean' = var' (mean/var + s_obs/rho). Marks the MLP stale.
        ``device``: where point_cost finds its distances (numpy's operations in numpy's order;
        None: the host).
        """
        obs = point_cost(self._grid, check_path(traj, "trajectory", self.config.dim),
                         self.config.beta, polyline=self.config.polyline, device=device)
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
    def _new_net(self) -> Surrogate:
        c = self.config
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(c.seed)
            net = Surrogate(c.dim, c.hidden, c.layers, c.octaves)
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
    def _corner_table(self, device: torch.device, dtype: torch.dtype
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(2^d, V) posterior mean at the corners of the cell whose lowest corner is grid point
        v, corners in :meth:`_weights`' order, and the (V,) least and greatest of each cell's
        corners; rows of points on a top face hold the padding 0 (no interpolation reads
        them). Built once per belief, so an evaluation gathers each point's corners in one
        indexing instead of one per corner."""
        key = (device, dtype)
        if key not in self._grid_cache:
            table = self.field_table(self._mean, device, dtype)
            self._grid_cache[key] = (table, table.amin(dim=0), table.amax(dim=0))
        return self._grid_cache[key]  # type: ignore[return-value]

    def field_table(self, values: np.ndarray, device: torch.device, dtype: torch.dtype
                    ) -> torch.Tensor:
        """(2^d, V) corner table of a field ``values`` (V,) on this model's grid (the posterior
        mean's is :meth:`_corner_table`'s), for :meth:`field_at`. Build it once per field and
        device: building copies the field to the device."""
        d = len(self.config.shape)
        offsets = [sum(c * s for c, s in zip(corner, self._strides, strict=True))
                   for corner in itertools.product((0, 1), repeat=d)]
        values = np.asarray(values, dtype=float)
        if values.shape != self._mean.shape:
            raise ValueError(f"a field on this grid has shape {self._mean.shape}, got "
                             f"{values.shape}")
        padded = np.concatenate([values, np.zeros(max(offsets))])
        v = len(values)
        return torch.as_tensor(np.stack([padded[o:o + v] for o in offsets]), dtype=dtype,
                               device=device)

    def field_at(self, table: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Multilinear interpolation of the field of a :meth:`field_table` at points x (..., d),
        clamped onto the grid, as the posterior mean is evaluated: (...). Tensor operations on
        x's device (the slowdown model's approach speeds where steering runs)."""
        base, frac = self._stencil(x.reshape(-1, x.shape[-1]))
        return self._sum_corners(table, base, self._weights(frac)).reshape(x.shape[:-1])

    def _grid_constants(self, device: torch.device, dtype: torch.dtype
                        ) -> tuple[torch.Tensor, ...]:
        """Lower bound, extent, top grid index, top cell index and strides per axis, and a
        zero per axis, on ``device``, copied there once (a copy per evaluation would make a
        GPU wait for the host, and each derived constant would be one more kernel there)."""
        key = ("constants", device, dtype)
        if key not in self._grid_cache:
            lo, hi, top = (torch.as_tensor(a, dtype=dtype, device=device) for a in
                           (self._lo, self._hi, [n - 1 for n in self.config.shape]))
            strides = torch.as_tensor(self._strides, dtype=torch.long, device=device)
            # derived on the device in its dtype, as each evaluation derived them before
            self._grid_cache[key] = (lo, hi - lo, top, top - 1, strides, torch.zeros_like(top))
        return self._grid_cache[key]  # type: ignore[return-value]

    def _stencil(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Where points x (n, d) fall in the grid, clamped to bounds: the flat grid index (n,)
        of each point's lowest cell corner and the point's position within its cell (n, d),
        from which :meth:`_weights` gives the corners' weights. Depends on the grid alone, so
        every task of a model shares it."""
        lo, extent, top, top_cell, strides, zero = self._grid_constants(x.device, x.dtype)
        u = ((x - lo) / extent * top).clamp(min=zero, max=top)
        # a NaN coordinate (unchecked on a device) gets cell 0 and a NaN position, so a NaN
        # value: as an integer it would index out of the table, a device-side assertion
        i0 = torch.minimum(u.nan_to_num(0.0).floor(), top_cell)
        frac = u - i0
        base = (i0.long() * strides).sum(dim=1)
        return base, frac

    @staticmethod
    def _weights(frac: torch.Tensor) -> torch.Tensor:
        """Multilinear interpolation weights (2^d, n) of the cell corners (corner c =
        (c_1..c_d) in itertools.product order) for positions within cells (n, d). Per axis the
        weight of the lower (c = 0) and upper (c = 1) corner; a corner's weight is their
        product taken axis by axis, the same products as one corner at a time, one operation
        per axis for all corners. Row by row, so the weights of some points are those of all
        points, taken at those."""
        n, d = frac.shape
        pair = torch.stack([1.0 - frac, frac])                              # (2, n, d)
        weights = pair[:, :, 0]
        for k in range(1, d):
            weights = (weights[:, None] * pair[None, :, :, k]).reshape(-1, n)
        return weights

    def _interpolate(self, base: torch.Tensor, frac: torch.Tensor,
                     weights: torch.Tensor | None = None) -> torch.Tensor:
        """The posterior mean at the points of a :meth:`_stencil`, (n,) (``weights``: their
        :meth:`_weights`, when already computed). The corners are summed one after another in
        a fixed order, so the result does not depend on how many points are evaluated
        together."""
        weights = self._weights(frac) if weights is None else weights
        return self._sum_corners(self._corner_table(weights.device, weights.dtype)[0], base,
                                 weights)

    @staticmethod
    def _sum_corners(table: torch.Tensor, base: torch.Tensor, weights: torch.Tensor
                     ) -> torch.Tensor:
        """The corners of ``table`` at the cells ``base`` weighted by ``weights``, summed one
        corner after another in a fixed order, (n,); on a device in one reduction instead of
        2^d kernel launches (equal to rounding)."""
        corners = torch.index_select(table, 1, base)                        # (2^d, n)
        terms = corners.mul_(weights)
        if not reads_back(base):
            return terms.sum(dim=0)
        out = terms[0].clone()
        for term in terms[1:]:
            out += term
        return out

    def _eval_grid(self, x: torch.Tensor) -> torch.Tensor:
        """Multilinear interpolation of the posterior mean, (n, d) -> (n,), clamped to bounds."""
        return self._interpolate(*self._stencil(x))

    def _row_max(self, base: torch.Tensor, frac: torch.Tensor, rows: int,
                 weights: torch.Tensor | None = None) -> torch.Tensor:
        """max over each row of the interpolated mean at the points of a :meth:`_stencil` of
        ``rows`` equal rows of points, (rows,): the same value as interpolating every point,
        but only points that can hold their row's maximum are interpolated (and only theirs
        get corner weights). An interpolated value lies within its cell's corner range (up to
        rounding, which ``slack`` covers), so a point whose cell's greatest corner is below
        the greatest least corner of its row cannot be that row's maximum. ``weights``: all
        points', off the CPU, where all are interpolated."""
        if not reads_back(base):  # nonzero would wait for the device: interpolate all
            return self._interpolate(base, frac, weights).view(rows, -1).amax(dim=1)
        _, least, greatest = self._corner_table(frac.device, frac.dtype)
        floor = torch.index_select(least, 0, base).view(rows, -1).amax(dim=1)
        slack = 256 * torch.finfo(frac.dtype).eps * (1.0 + floor.abs())
        cand = torch.index_select(greatest, 0, base).view(rows, -1) >= (floor - slack)[:, None]
        idx = cand.view(-1).nonzero().squeeze(1)
        values = torch.full((base.shape[0],), -torch.inf, dtype=frac.dtype, device=frac.device)
        values[idx] = self._interpolate(base[idx], frac[idx])
        return values.view(rows, -1).amax(dim=1)

    def _mlp_on(self, device: torch.device) -> Surrogate:
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
        if reads_back(x) and not bool(torch.isfinite(x).all()):
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
                "state": {k: encode_array(v.detach().cpu().numpy())
                          for k, v in self._net.state_dict().items()},
            }
        return {
            "config": self.config.to_dict(),
            "n_obs": self.n_obs,
            "mean": encode_array(self._mean),
            "var": encode_array(self._var),
            "prior_mean": encode_array(self._prior_mean),
            "prior_var": encode_array(self._prior_var),
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
        mean = decode_array(data.get("mean"), "spatial model: mean", v)
        var = decode_array(data.get("var"), "spatial model: var", v)
        prior = decode_array(data.get("prior_mean"), "spatial model: prior_mean", v)
        # files written before forgetting existed hold no prior variance; only a model that
        # forgets or resets reads it, and such a model always stored it
        prior_var = (decode_array(data["prior_var"], "spatial model: prior_var", v)
                     if "prior_var" in data else None)
        try:
            model = cls(config, mean, var, prior_mean=prior, prior_var=prior_var,
                        n_obs=data.get("n_obs", -1))
        except ValueError as e:
            raise StateError(f"spatial model: {e}") from None
        sur = data.get("surrogate")
        if sur is not None:
            net = model._new_net()
            try:
                state = {k: torch.from_numpy(decode_array(a, f"spatial model: MLP weight {k}"))
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


def reads_back(t: torch.Tensor) -> bool:
    """Whether an evaluation may read ``t``'s values back to choose what to do (a finiteness
    check, the points worth interpolating): free on the CPU; on a device each such read waits
    for it, so there every point is interpolated and nothing is checked."""
    return t.device.type == "cpu"


def _as_points(model: SpatialCostModel, x: Any, ndim: int | None) -> torch.Tensor:
    """The input checks of point_cost / trajectory_cost: x as a floating tensor (a NumPy
    array as float64, shared memory), of shape (..., d), or (N, H, d) when ``ndim`` is 3."""
    d = model.config.dim
    t = x if isinstance(x, torch.Tensor) else torch.from_numpy(np.asarray(x, dtype=np.float64))
    if not t.is_floating_point():
        t = t.to(torch.float32)
    if t.ndim < 1 or t.shape[-1] != d:
        raise ValueError(f"points must have shape (..., {d}), got {tuple(t.shape)}")
    if ndim is not None and (t.ndim != ndim or t.shape[1] == 0):
        raise ValueError(f"trajectories must have shape (N, H, {d}) with H >= 1, "
                         f"got {tuple(t.shape)}")
    return t


def _evaluate(model: SpatialCostModel, x: Any, ndim: int | None) -> Any:
    """Shared input handling of point_cost / trajectory_cost: type, shape, dtype round trip."""
    if ndim == 3 and not model.config.use_surrogate:
        return grid_trajectory_costs([model], x)[0]
    t = _as_points(model, x, ndim)
    out = model._eval_flat(t.reshape(-1, model.config.dim)).reshape(t.shape[:-1])
    if ndim is not None:
        out = out.amax(dim=-1)
    return out if isinstance(x, torch.Tensor) else out.numpy()


def grid_trajectory_costs(models: Sequence[SpatialCostModel], xi: Points) -> list[Points]:
    """[S_i(xi) for each model], xi (N, H, d) -> (N,) each, for models of one config evaluated
    by grid interpolation: the same values as the max over each trajectory of the
    interpolated means, with the interpolation weights of the points computed once for all
    models and only the points that can hold a trajectory's maximum interpolated
    (:meth:`SpatialCostModel._row_max`). Steering scores every candidate against all tasks
    concurrent with the robot's. Chunks hold whole trajectories of at most ``config.chunk``
    points (at least one trajectory)."""
    first = models[0]
    if first.config.use_surrogate or any(m.config != first.config for m in models):
        raise ValueError("grid_trajectory_costs needs models of one config without surrogate")
    t = _as_points(first, xi, ndim=3)
    # a device's points are not checked: that would wait for the device (a non-finite point
    # gives a NaN cost, which steering counts as +inf)
    if reads_back(t) and not bool(torch.isfinite(t).all()):
        raise ValueError("points contain NaN or infinite coordinates")
    n, h, d = t.shape
    step = max(1, first.config.chunk // h)
    parts: list[list[torch.Tensor]] = [[] for _ in models]
    with torch.no_grad():
        for s in range(0, n, step):
            rows = t[s:s + step]
            base, frac = first._stencil(rows.reshape(-1, d))
            # off the CPU every point is interpolated: its weights once for all the models
            weights = None if reads_back(t) else first._weights(frac)
            for part, m in zip(parts, models, strict=True):
                part.append(m._row_max(base, frac, rows=rows.shape[0], weights=weights))
    outs = [torch.cat(p) if p else t.new_zeros(0) for p in parts]
    return outs if isinstance(xi, torch.Tensor) else [o.numpy() for o in outs]
