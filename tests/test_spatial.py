"""Spatial cost model (paper Eqs. 7-12) on a 2-D toy layout: a 10 x 10 workspace where people
walk from (5, 1) to (5, 9) either left round x = 2 (route A) or right round x = 8 (route B)."""

from __future__ import annotations

import hashlib
import itertools
import json
import math

import numpy as np
import pytest
import torch
from scipy.interpolate import RegularGridInterpolator

from rapidds.errors import StateError
from rapidds.human.spatial import (
    SpatialConfig,
    SpatialCostModel,
    SpatialModel,
    point_cost,
)
from rapidds.human.spatial.grid import grid_trajectory_costs

BOUNDS = ((0.0, 10.0), (0.0, 10.0))
ROUTE_A = [(5, 1), (2, 3), (2, 7), (5, 9)]
ROUTE_B = [(5, 1), (8, 3), (8, 7), (5, 9)]


def polyline(corners, spacing: float = 0.1) -> np.ndarray:
    """(T, 2) points every ``spacing`` along the corners."""
    c = np.asarray(corners, dtype=float)
    out = []
    for a, b in itertools.pairwise(c):
        n = max(2, math.ceil(np.linalg.norm(b - a) / spacing))
        out.append(a + (b - a) * np.linspace(0, 1, n, endpoint=False)[:, None])
    return np.concatenate([*out, c[-1:]])


def walk(route, rng, jitter: float = 0.3) -> np.ndarray:
    """One person's path: the route with its inner corners moved by N(0, jitter^2)."""
    c = np.asarray(route, dtype=float).copy()
    c[1:-1] += rng.normal(0.0, jitter, c[1:-1].shape)
    return polyline(c)


def population(rng, m: int = 10) -> list[np.ndarray]:
    """Half the people take route A, half route B."""
    return [walk(ROUTE_A if k % 2 else ROUTE_B, rng) for k in range(m)]


def seg_dist(x, a, b) -> float:
    """Distance from point x to segment [a, b], the textbook way."""
    ab, ax = b - a, x - a
    t = 0.0 if not ab.any() else min(1.0, max(0.0, float(ax @ ab) / float(ab @ ab)))
    return math.dist(x, a + t * ab)


@pytest.fixture(scope="module")
def pop() -> list[np.ndarray]:
    return population(np.random.default_rng(0))


# ----------------------------------------------------------------------------- Eq. 7
def test_point_cost_hand_example():
    pts = np.array([[0.0, 0.0], [3.0, 4.0], [6.0, 8.0]])
    traj = np.array([[0.0, 1.0], [6.0, 8.0]])
    # samples only (Eq. 7 as printed): nearest samples (0,1) at 1; (0,1) at sqrt(18), closer
    # than (6,8) at 5; (6,8) itself.
    want = [math.exp(-0.5), math.exp(-0.5 * math.sqrt(18.0)), 1.0]
    np.testing.assert_allclose(point_cost(pts, traj, beta=0.5, polyline=False), want, rtol=1e-14)
    # polyline (default): distance to the segments of an L-shaped path
    path = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 0.0], [4.0, 4.0]])  # a repeated sample: dwell
    pts = np.array([[2.0, 1.0], [5.0, 2.0], [6.0, -1.0], [-3.0, 0.0], [4.0, 3.0]])
    dist = np.array([1.0, 1.0, math.sqrt(5.0), 3.0, 0.0])  # segment, segment, corner, end, on it
    np.testing.assert_allclose(point_cost(pts, path, beta=2.0), np.exp(-2.0 * dist), rtol=1e-14)
    # 1-D, 3-D and single-sample paths work the same way
    assert point_cost([[2.0]], [[0.0], [5.0]], 1.0, polyline=False)[0] == pytest.approx(
        math.exp(-2.0))
    assert point_cost([[2.0]], [[0.0], [5.0]], 1.0)[0] == pytest.approx(1.0)
    got = point_cost([[1.0, 2.0, 2.0]], [[0.0, 0.0, 0.0]], beta=2.0)[0]
    assert got == pytest.approx(math.exp(-6.0))


def test_point_cost_chunks_agree_with_brute_force():
    rng = np.random.default_rng(1)
    pts, traj = rng.random((5000, 2)) * 10, rng.random((300, 2)) * 10  # several chunks
    d = np.sqrt(((pts[:, None] - traj[None]) ** 2).sum(-1)).min(1)
    np.testing.assert_allclose(point_cost(pts, traj, 0.7, polyline=False), np.exp(-0.7 * d),
                               rtol=1e-12)
    # polyline == samples-only on a path resampled every 1e-3 (to within beta * 5e-4)
    path = traj[:6]
    dense = np.concatenate([np.linspace(a, b, 20_000) for a, b in itertools.pairwise(path)])
    np.testing.assert_allclose(point_cost(pts[:400], path, 0.7),
                               point_cost(pts[:400], dense, 0.7, polyline=False), atol=4e-4)
    # a point's cost does not depend on which points share its chunk (3-D body-point paths)
    pts3, body = rng.random((3000, 3)), rng.random((50, 4, 3))
    whole = point_cost(pts3, body, 2.0)
    assert np.array_equal(whole, np.concatenate([point_cost(pts3[:7], body, 2.0),
                                                 point_cost(pts3[7:], body, 2.0)]))
    seg_d = min(seg_dist(pts3[11], a, b) for k in range(4)
                for a, b in itertools.pairwise(body[:, k]))
    assert whole[11] == pytest.approx(math.exp(-2.0 * seg_d), rel=1e-12)


def test_point_cost_on_a_device_is_the_hosts_bit_for_bit(monkeypatch, pop):
    """A run on a GPU updates its belief there (``device``); its distances are the same
    operations in the same order, each exactly rounded, so the costs are the host's bits.
    Checked here with tensors on the CPU, in chunks of every size, and through an update."""
    from rapidds.human.spatial import path_cost

    rng = np.random.default_rng(4)
    cases = [(rng.random((3000, 3)), rng.random((50, 4, 3)), 2.0, True),   # body points, 3-D
             (rng.random((900, 2)) * 10, pop[0], 0.7, True),
             (rng.random((900, 2)) * 10, pop[0], 0.7, False),               # samples only
             (rng.random((400, 3)), rng.random((1, 3)), 5.0, True),          # one sample
             (rng.random((400, 4)), rng.random((20, 2, 4)), 1.0, True)]      # d = 4
    for pairs in (path_cost._DEVICE_PAIRS, 997):
        monkeypatch.setattr(path_cost, "_DEVICE_PAIRS", pairs)
        for pts, traj, beta, line in cases:
            assert np.array_equal(point_cost(pts, traj, beta, polyline=line, device="cpu"),
                                  point_cost(pts, traj, beta, polyline=line))
    cfg = SpatialConfig(bounds=BOUNDS, beta=0.7, grid_points=15)
    host, dev = (SpatialCostModel.from_population(cfg, pop[:4]) for _ in range(2))
    host.observe(pop[5])
    dev.observe(pop[5], device="cpu")
    assert np.array_equal(host.mean, dev.mean) and np.array_equal(host.var, dev.var)


def test_point_cost_rejects_bad_input():
    with pytest.raises(ValueError, match="NaN"):
        point_cost([[0.0, 0.0]], [[np.nan, 1.0]], 1.0)
    with pytest.raises(ValueError, match="NaN"):
        point_cost([[np.inf, 0.0]], [[0.0, 1.0]], 1.0)
    with pytest.raises(ValueError, match="beta"):
        point_cost([[0.0, 0.0]], [[0.0, 1.0]], 0.0)
    with pytest.raises(ValueError, match="coordinates per point"):
        point_cost([[0.0, 0.0]], [[0.0, 1.0, 2.0]], 1.0)
    with pytest.raises(ValueError, match="non-empty"):
        point_cost([[0.0, 0.0]], np.zeros((0, 2)), 1.0)


# ---------------------------------------------------------------------------- Eqs. 9-11
def test_prior_is_population_average_at_grid_points(pop):
    cfg = SpatialConfig(bounds=BOUNDS, grid_points=(9, 7), beta=0.8)
    model = SpatialCostModel.from_population(cfg, pop)
    grid = model.grid_points
    assert grid.shape == (63, 2)
    # brute force: every grid point, every person, every segment of their path
    brute = np.array([
        np.mean([max(math.exp(-0.8 * seg_dist(x, a, b)) for a, b in itertools.pairwise(p))
                 for p in pop])
        for x in grid
    ])
    np.testing.assert_allclose(model.mean, brute, rtol=1e-12)
    np.testing.assert_allclose(model.prior_mean, brute, rtol=1e-12)
    per_person = np.stack([point_cost(grid, p, 0.8) for p in pop])
    np.testing.assert_allclose(model.var, np.maximum(per_person.var(0), cfg.min_prior_var))
    fixed = SpatialCostModel.from_population(
        SpatialConfig(bounds=BOUNDS, grid_points=(9, 7), prior_var=0.2), pop)
    assert np.all(fixed.var == 0.2)


def test_posterior_converges_to_the_persons_cost_and_variance_follows_closed_form(pop):
    cfg = SpatialConfig(bounds=BOUNDS, grid_points=24)
    model = SpatialCostModel.from_population(cfg, pop)
    grid = model.grid_points
    rng = np.random.default_rng(7)
    # the person's true expected cost s*(x): Monte Carlo over their own route-A walks
    truth = np.mean([point_cost(grid, walk(ROUTE_A, rng), cfg.beta) for _ in range(300)], axis=0)
    errors = [np.abs(model.mean - truth).mean()]
    var = model.var
    for _ in range(30):
        model.observe(walk(ROUTE_A, rng))
        np.testing.assert_allclose(1.0 / model.var, 1.0 / var + 1.0 / cfg.rho, rtol=1e-12)
        assert np.all(model.var < var)
        var = model.var
        errors.append(np.abs(model.mean - truth).mean())
    assert model.n_obs == 30
    assert errors[0] > 0.1  # half the population walks route B: the prior is far off
    assert errors[1] < 0.5 * errors[0]
    assert errors[30] < errors[5] < errors[1]
    assert errors[30] < 0.02


def test_route_a_walker_raises_cost_on_a_and_lowers_it_on_b(pop):
    model = SpatialCostModel.from_population(SpatialConfig(bounds=BOUNDS), pop)
    on_a, on_b = np.array([[2.0, 5.0]]), np.array([[8.0, 5.0]])
    robot_a = polyline([(3, 2), (2, 5), (3, 8)])[None]  # a robot path along route A
    robot_b = polyline([(7, 2), (8, 5), (7, 8)])[None]
    before = [float(model.point_cost(p)[0]) for p in (on_a, on_b)]
    traj_before = [float(model.trajectory_cost(r)[0]) for r in (robot_a, robot_b)]
    assert 0.35 < before[0] < 0.75 and 0.35 < before[1] < 0.75  # people split between routes
    rng = np.random.default_rng(3)
    for _ in range(5):
        model.observe(walk(ROUTE_A, rng))
    after = [float(model.point_cost(p)[0]) for p in (on_a, on_b)]
    traj_after = [float(model.trajectory_cost(r)[0]) for r in (robot_a, robot_b)]
    assert after[0] > before[0] + 0.25 and after[0] > 0.65  # the walk jitters ~0.3 around A
    assert after[1] < before[1] - 0.25 and after[1] < 0.15
    assert traj_after[0] > traj_before[0] + 0.2
    assert traj_after[1] < traj_before[1] - 0.2


# --------------------------------------------------------------------------- evaluation
def test_grid_interpolation_matches_scipy_and_trajectory_cost_is_max_of_points(pop):
    cfg = SpatialConfig(bounds=((0.0, 10.0), (-1.0, 11.0)), grid_points=(17, 12))
    model = SpatialCostModel.from_population(cfg, pop)
    axes = [np.linspace(lo, hi, n) for (lo, hi), n in zip(cfg.bounds, cfg.shape, strict=True)]
    ref = RegularGridInterpolator(axes, model.mean.reshape(cfg.shape), method="linear")
    rng = np.random.default_rng(4)
    xi = rng.uniform(-2.0, 12.0, size=(7, 5, 2))  # some points outside: clamped
    lo, hi = np.array(cfg.bounds).T
    np.testing.assert_allclose(model.point_cost(xi), ref(np.clip(xi, lo, hi)), atol=1e-12)
    brute = np.array([max(float(model.point_cost(xi[n, h])) for h in range(5)) for n in range(7)])
    got = model.trajectory_cost(xi)
    assert got.shape == (7,) and got.dtype == np.float64
    np.testing.assert_allclose(got, brute, rtol=0, atol=0)
    # tensors in, tensor of the same dtype out
    t = model.trajectory_cost(torch.as_tensor(xi, dtype=torch.float32))
    assert isinstance(t, torch.Tensor) and t.dtype == torch.float32
    np.testing.assert_allclose(t.numpy(), brute, atol=1e-5)
    # exact at grid points
    np.testing.assert_allclose(model.point_cost(model.grid_points), model.mean, atol=1e-12)


def test_grid_interpolation_in_3d_matches_scipy():
    rng = np.random.default_rng(5)
    cfg = SpatialConfig(bounds=((0, 1), (0, 2), (0, 1)), beta=5.0, grid_points=(6, 9, 5))
    people = [rng.random((40, 3)) * [1, 2, 1] for _ in range(3)]
    model = SpatialCostModel.from_population(cfg, people)
    axes = [np.linspace(lo, hi, n) for (lo, hi), n in zip(cfg.bounds, cfg.shape, strict=True)]
    ref = RegularGridInterpolator(axes, model.mean.reshape(cfg.shape))
    x = rng.random((200, 3)) * [1, 2, 1]
    np.testing.assert_allclose(model.point_cost(x), ref(x), atol=1e-12)


def _corner_by_corner(model: SpatialCostModel, x: torch.Tensor) -> torch.Tensor:
    """Multilinear interpolation written out one corner at a time (index, weight, sum)."""
    shape = model.config.shape
    lo, hi = (torch.as_tensor(np.array(b, dtype=float), dtype=x.dtype)
              for b in zip(*model.config.bounds, strict=True))
    top = torch.as_tensor([n - 1 for n in shape], dtype=x.dtype)
    vals = torch.as_tensor(model.mean, dtype=x.dtype)
    u = ((x - lo) / (hi - lo) * top).clamp(min=torch.zeros_like(top), max=top)
    i0 = torch.minimum(u.floor(), top - 1)
    frac, i0 = u - i0, i0.long()
    strides = [math.prod(shape[k + 1:]) for k in range(len(shape))]
    out = torch.zeros(x.shape[0], dtype=x.dtype)
    for corner in itertools.product((0, 1), repeat=len(shape)):
        idx = torch.zeros(x.shape[0], dtype=torch.long)
        w = torch.ones_like(out)
        for k, c in enumerate(corner):
            idx += (i0[:, k] + c) * strides[k]
            w *= frac[:, k] if c else 1.0 - frac[:, k]
        out += w * vals[idx]
    return out


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_grid_interpolation_is_bit_identical_to_corner_by_corner(dtype):
    rng = np.random.default_rng(8)
    cfg = SpatialConfig(bounds=((0, 1), (0, 2), (0, 1)), beta=5.0, grid_points=(6, 9, 5))
    people = [rng.random((40, 3)) * [1, 2, 1] for _ in range(3)]
    model = SpatialCostModel.from_population(cfg, people)
    x = torch.as_tensor(rng.uniform(-0.3, 2.3, size=(500, 3)), dtype=dtype)  # some clamped
    assert torch.equal(model._eval_grid(x), _corner_by_corner(model, x))
    # the corner table follows the belief: after an observation or a reset it interpolates
    # the new mean
    before = model._eval_grid(x)
    model.observe(rng.random((30, 3)) * [1, 2, 1])
    after = model._eval_grid(x)
    assert not torch.equal(after, before)
    assert torch.equal(after, _corner_by_corner(model, x))
    model.reset()
    assert torch.equal(model._eval_grid(x), before)


def test_trajectory_costs_are_the_max_of_every_points_interpolation(pop):
    """Several tasks' trajectory costs from one set of interpolation weights, interpolating
    only the points that can hold a trajectory's maximum, in chunks or not: the bits of the
    max over every point's interpolated value."""
    sm, small = _two_task_model(pop), _two_task_model(pop, chunk=20)  # chunks of 2 paths
    rng = np.random.default_rng(9)
    xi = rng.uniform(-1.0, 11.0, size=(13, 7, 2))
    for dtype in (np.float64, np.float32):
        x = xi.astype(dtype)
        every = [sm[t].point_cost(x).max(axis=1) for t in ("t2", "t3")]
        for shared in (grid_trajectory_costs([sm["t2"], sm["t3"]], x),
                       grid_trajectory_costs([small["t2"], small["t3"]], x),
                       [sm["t2"].trajectory_cost(x), sm["t3"].trajectory_cost(x)]):
            for got, ref in zip(shared, every, strict=True):
                np.testing.assert_array_equal(got, ref)
    tensor = grid_trajectory_costs([sm["t2"], sm["t3"]], torch.as_tensor(xi))
    assert all(isinstance(t, torch.Tensor) for t in tensor)
    assert grid_trajectory_costs([sm["t2"]], np.zeros((0, 3, 2)))[0].shape == (0,)
    with pytest.raises(ValueError, match="NaN"):
        grid_trajectory_costs([sm["t2"], sm["t3"]], np.full((1, 2, 2), np.nan))


def test_the_grid_as_a_device_evaluates_it_equals_the_hosts(pop, monkeypatch):
    """What a GPU runs (no value read back: every point interpolated, no finiteness check,
    the corners summed in one reduction), taken here on the CPU: the host's costs to
    rounding, and a non-finite point's cost is NaN instead of an error."""
    from rapidds.human.spatial import grid

    sm = _two_task_model(pop)
    rng = np.random.default_rng(10)
    xi = torch.as_tensor(rng.uniform(-1.0, 11.0, size=(13, 7, 2)))
    host = grid_trajectory_costs([sm["t2"], sm["t3"]], xi)
    host_points = sm["t2"].point_cost(xi)
    monkeypatch.setattr(grid, "reads_back", lambda t: False)
    device = grid_trajectory_costs([sm["t2"], sm["t3"]], xi)
    for got, ref in zip(device, host, strict=True):
        torch.testing.assert_close(got, ref, rtol=0, atol=1e-12)
    torch.testing.assert_close(sm["t2"].point_cost(xi), host_points, rtol=0, atol=1e-12)
    bad = xi.clone()
    bad[0, 3, 1] = torch.nan
    got = grid_trajectory_costs([sm["t2"]], bad)[0]
    assert torch.isnan(got[0]) and torch.equal(got[1:], device[0][1:])


def test_trajectory_cost_of_a_flat_belief_keeps_every_tie():
    """Where every cell has the same corners, no point can be ruled out; the max is still
    every point's value (ties and rounding included)."""
    cfg = SpatialConfig(bounds=BOUNDS, grid_points=9)
    model = SpatialCostModel(cfg, np.full(cfg.n_points, 0.3), np.ones(cfg.n_points))
    xi = np.random.default_rng(3).uniform(0.0, 10.0, size=(5, 40, 2))
    np.testing.assert_array_equal(model.trajectory_cost(xi), model.point_cost(xi).max(axis=1))


@pytest.fixture(scope="module")
def fitted(pop) -> SpatialCostModel:
    model = SpatialCostModel.from_population(
        SpatialConfig(bounds=BOUNDS, use_surrogate=True), pop)
    model.fit_surrogate()
    return model


def test_surrogate_is_within_stated_error_of_grid_interpolation(fitted):
    # Stated bound: max |MLP - grid| < 0.05 at the grid points (the fit stops at tol = 0.02, so
    # this holds unless the step budget ran out) and mean < 0.01. Between grid points the two
    # interpolate a ridge differently (grid interpolation cuts the peak of exp(-beta r) at the
    # route by up to ~0.13 against the exact posterior), so there the bound is the mean, < 0.01,
    # and the max, < 0.15.
    err = fitted.surrogate_error()
    assert err.grid_max < 0.05 and err.grid_mean < 0.01
    assert err.random_mean < 0.01 and err.random_max < 0.15
    assert not fitted.surrogate_stale
    # point_cost goes through the MLP now
    np.testing.assert_allclose(fitted.point_cost(fitted.grid_points), fitted.mean, atol=0.05)


def test_surrogate_warm_start_is_cheaper_and_deterministic(pop):
    cfg = SpatialConfig(bounds=BOUNDS, grid_points=20, use_surrogate=True)
    rng = np.random.default_rng(11)
    path1, path2 = walk(ROUTE_A, rng), walk(ROUTE_A, rng)
    runs = []
    for _ in range(2):
        model = SpatialCostModel.from_population(cfg, pop)
        cold = model.fit_surrogate()
        model.observe(path1)
        assert model.surrogate_stale
        model.observe(path2)
        warm = model.fit_surrogate()
        runs.append((cold, warm, model))
    (cold, warm, a), (_, _, b) = runs
    # the same posterior fitted from scratch: what the warm start saves (comparing with the
    # first cold fit, of another target, depended on the CPU: 250 steps for both on a Xeon)
    fresh = SpatialCostModel.from_population(cfg, pop)
    fresh.observe(path1)
    fresh.observe(path2)
    cold_same = fresh.fit_surrogate()
    assert cold.max_abs_error <= cfg.tol and warm.max_abs_error <= cfg.tol
    assert cold_same.max_abs_error <= cfg.tol
    assert warm.steps < cold_same.steps
    assert a.fit_surrogate().steps == 0  # nothing new: the warm fit is still within tol
    probe = np.random.default_rng(0).random((64, 4, 2)) * 10
    np.testing.assert_array_equal(a.trajectory_cost(probe), b.trajectory_cost(probe))


def test_stale_surrogate_is_refitted_before_use(pop):
    cfg = SpatialConfig(bounds=BOUNDS, grid_points=12, use_surrogate=True)
    model = SpatialCostModel.from_population(cfg, pop)
    assert model.surrogate_stale
    model.point_cost(np.zeros((1, 2)))
    assert not model.surrogate_stale and model.n_fits == 1


# ------------------------------------------------------------------------ SpatialModel
def _two_task_model(pop, **cfg) -> SpatialModel:
    config = SpatialConfig(bounds=BOUNDS, grid_points=16, **cfg)
    rng = np.random.default_rng(2)
    return SpatialModel.from_population(
        config, {"t2": pop, "t3": [walk(ROUTE_B, rng) for _ in range(4)]})


def test_spatial_model_cost_is_max_over_tasks(pop):
    sm = _two_task_model(pop)
    xi = np.random.default_rng(6).random((9, 6, 2)) * 10
    s2, s3 = sm["t2"].trajectory_cost(xi), sm["t3"].trajectory_cost(xi)
    np.testing.assert_array_equal(sm.cost(["t2", "t3"], xi), np.maximum(s2, s3))
    np.testing.assert_array_equal(sm.cost({"t3"}, xi), s3)
    np.testing.assert_array_equal(sm.cost([], xi), np.zeros(9))
    zeros = sm.cost((), torch.zeros(4, 3, 2))
    assert isinstance(zeros, torch.Tensor) and zeros.shape == (4,) and not zeros.any()
    with pytest.raises(KeyError, match="t9"):
        sm.cost(["t9"], xi)
    with pytest.raises(ValueError, match="shape"):
        sm.cost([], np.zeros((4, 2)))
    sm.observe("t3", walk(ROUTE_A, np.random.default_rng(0)))
    assert sm["t3"].n_obs == 1 and sm["t2"].n_obs == 0
    assert sm.refit() == {}  # use_surrogate=False: nothing to fit


def test_save_load_round_trip_gives_identical_costs(pop, tmp_path):
    sm = _two_task_model(pop, use_surrogate=True)
    rng = np.random.default_rng(8)
    sm.observe("t2", walk(ROUTE_A, rng))
    reports = sm.refit()
    assert set(reports) == {"t2", "t3"}
    sm.observe("t3", walk(ROUTE_A, rng))  # t3's MLP is stale when saved
    path = sm.save(tmp_path / "person.json")
    assert not list(tmp_path.glob(".*.tmp"))  # atomic write left no temp file behind
    back = SpatialModel.load(path, config=sm.config)
    assert back.tasks == sm.tasks and back["t2"].n_obs == 1 and back["t3"].n_obs == 1
    assert not back["t2"].surrogate_stale and back["t3"].surrogate_stale
    xi = rng.random((32, 8, 2)) * 10
    np.testing.assert_array_equal(back.cost(["t2"], xi), sm.cost(["t2"], xi))
    # t3 refits on first use, from the same weights and history: same result
    np.testing.assert_array_equal(back.cost(["t2", "t3"], xi), sm.cost(["t2", "t3"], xi))
    for tid in sm.tasks:
        np.testing.assert_array_equal(back[tid].mean, sm[tid].mean)
        np.testing.assert_array_equal(back[tid].var, sm[tid].var)
    # exact grid mode too
    grid_sm = _two_task_model(pop)
    grid_back = SpatialModel.from_dict(json.loads(json.dumps(grid_sm.to_dict())))
    np.testing.assert_array_equal(grid_back.cost(["t2", "t3"], xi), grid_sm.cost(["t2", "t3"], xi))


def test_corrupt_or_mismatched_files_raise_state_error(pop, tmp_path):
    sm = _two_task_model(pop)
    path = sm.save(tmp_path / "m.json")
    text = path.read_text()

    def write(name: str, content: str):
        p = tmp_path / name
        p.write_text(content)
        return p

    with pytest.raises(StateError, match="no spatial model"):
        SpatialModel.load(tmp_path / "missing.json")
    with pytest.raises(StateError, match="corrupt"):
        SpatialModel.load(write("trunc.json", text[: len(text) // 2]))
    i = text.index('"data":"') + 12
    flipped = text[:i] + ("A" if text[i] != "A" else "B") + text[i + 1:]
    with pytest.raises(StateError, match="checksum"):
        SpatialModel.load(write("flip.json", flipped))
    with pytest.raises(StateError, match="different SpatialConfig"):
        SpatialModel.load(path, config=SpatialConfig(bounds=BOUNDS, grid_points=17))

    def resigned(body) -> str:  # a well-formed file whose content is wrong
        t = json.dumps(body, sort_keys=True, separators=(",", ":"))
        return f'{{"sha256":"{hashlib.sha256(t.encode()).hexdigest()}","body":{t}}}'

    body = json.loads(text)["body"]
    body["tasks"]["t2"]["mean"] = json.loads(text)["body"]["tasks"]["t2"]["var"] | {
        "shape": [3]}
    with pytest.raises(StateError):
        SpatialModel.load(write("shape.json", resigned(body)))
    body = json.loads(text)["body"]
    body["version"] = 99
    with pytest.raises(StateError, match="version"):
        SpatialModel.load(write("ver.json", resigned(body)))
    body = json.loads(text)["body"]
    body["config"]["beta"] = -1.0
    with pytest.raises(StateError, match="config"):
        SpatialModel.load(write("cfg.json", resigned(body)))
    body = json.loads(text)["body"]
    body["tasks"]["t3"]["config"]["rho"] = 0.5
    with pytest.raises(StateError, match="another config"):
        SpatialModel.load(write("mix.json", resigned(body)))


# ------------------------------------------------------------------------- validation
@pytest.mark.parametrize("bad", [
    {"bounds": ()},
    {"bounds": ((1.0, 0.0),)},
    {"bounds": ((0.0, math.inf),)},
    {"bounds": ((0.0, 1.0, 2.0),)},
    {"beta": 0.0},
    {"beta": math.nan},
    {"rho": -0.1},
    {"prior_var": 0.0},
    {"min_prior_var": 0.0},
    {"grid_points": 1},
    {"grid_points": (32,)},
    {"grid_points": 3.5},
    {"hidden": 0},
    {"layers": 0},
    {"steps": 0},
    {"batch": 0},
    {"lr": 0.0},
    {"tol": -0.01},
    {"fourier": -1},
    {"seed": -1},
    {"chunk": 0},
    {"use_surrogate": "yes"},
    {"polyline": 1},
])
def test_bad_config_values_are_rejected(bad):
    kwargs = {"bounds": BOUNDS, **bad}
    with pytest.raises(ValueError, match="SpatialConfig"):
        SpatialConfig(**kwargs)


def test_config_normalises_and_round_trips():
    cfg = SpatialConfig(bounds=[[0, 10], [0, 5]], grid_points=[8, 4])
    assert cfg.bounds == ((0.0, 10.0), (0.0, 5.0)) and cfg.shape == (8, 4) and cfg.n_points == 32
    assert SpatialConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    assert SpatialConfig(bounds=BOUNDS).octaves == 4
    assert SpatialConfig(bounds=BOUNDS, grid_points=16).octaves == 3


def test_nan_trajectories_are_rejected(pop):
    cfg = SpatialConfig(bounds=BOUNDS, grid_points=8)
    model = SpatialCostModel.from_population(cfg, pop)
    mean, var = model.mean, model.var
    bad = walk(ROUTE_A, np.random.default_rng(0))
    bad[10, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        model.observe(bad)
    assert model.n_obs == 0
    np.testing.assert_array_equal(model.mean, mean)
    np.testing.assert_array_equal(model.var, var)
    with pytest.raises(ValueError, match="NaN"):
        SpatialCostModel.from_population(cfg, [*pop, bad])
    with pytest.raises(ValueError, match="NaN"):
        model.trajectory_cost(bad[None])
    with pytest.raises(ValueError, match="coordinates per point"):
        model.observe(np.zeros((5, 3)))
    with pytest.raises(ValueError, match="shape"):
        model.trajectory_cost(np.zeros((5, 2)))
    with pytest.raises(ValueError, match="at least one"):
        SpatialCostModel.from_population(cfg, [])


# ------------------------------------------------- several body points per path: (T, K, d)
def body_paths(rng, t: int = 12, k: int = 3, d: int = 3) -> np.ndarray:
    """(T, K, d): K body points, each wandering on its own, far apart from one another."""
    offsets = np.arange(k)[:, None] * np.array([2.0] + [0.0] * (d - 1))
    return offsets[None] + np.cumsum(rng.normal(0.0, 0.2, (t, k, d)), axis=0)


@pytest.mark.parametrize("polyline", [True, False])
def test_body_point_cost_is_the_max_over_the_body_points(polyline):
    rng = np.random.default_rng(3)
    path = body_paths(rng)
    pts = rng.uniform(-1.0, 5.0, (200, 3))
    each = np.stack([point_cost(pts, path[:, k], 1.5, polyline=polyline)
                     for k in range(path.shape[1])])
    np.testing.assert_allclose(point_cost(pts, path, 1.5, polyline=polyline), each.max(axis=0),
                               rtol=1e-14)
    # one body point as (T, 1, d) is bit for bit the (T, d) path
    np.testing.assert_array_equal(point_cost(pts, path[:, :1], 1.5, polyline=polyline),
                                  point_cost(pts, path[:, 0], 1.5, polyline=polyline))


def test_body_point_paths_are_not_joined_to_each_other():
    # Two hands standing still 4 units apart: the point between them is 2 units from both; a
    # segment from the end of one hand's path to the start of the other's would pass through it.
    path = np.array([[[0.0, 0.0], [4.0, 0.0]]] * 5)          # (T=5, K=2, d=2)
    cost = point_cost([[2.0, 0.0], [0.0, 1.0]], path, 1.0)
    np.testing.assert_allclose(cost, [math.exp(-2.0), math.exp(-1.0)], rtol=1e-14)


def test_models_learn_from_body_point_paths():
    rng = np.random.default_rng(5)
    cfg = SpatialConfig(bounds=((-1.0, 6.0), (-2.0, 2.0), (-2.0, 2.0)), grid_points=6, beta=1.2)
    people = [body_paths(rng, t=8 + m) for m in range(4)]
    model = SpatialCostModel.from_population(cfg, people)
    grid = model.grid_points
    want = np.mean([point_cost(grid, p, 1.2) for p in people], axis=0)
    np.testing.assert_allclose(model.mean, want, rtol=1e-14)
    # one observation: the conjugate update with the body-point cost
    seen = body_paths(rng)
    var0, mean0 = model.var, model.mean
    model.observe(seen)
    new_var = 1.0 / (1.0 / var0 + 1.0 / cfg.rho)
    np.testing.assert_allclose(model.var, new_var, rtol=1e-14)
    np.testing.assert_allclose(model.mean, new_var * (mean0 / var0 + point_cost(grid, seen, 1.2)
                                                      / cfg.rho), rtol=1e-14)
    # the per-task wrapper takes them too
    both = SpatialModel.from_population(cfg, {"a": people, "b": people[:2]})
    both.observe("a", seen)
    assert both["a"].n_obs == 1 and both["b"].n_obs == 0
    np.testing.assert_allclose(both["a"].mean, model.mean, rtol=1e-14)


def test_bad_body_point_paths_are_rejected():
    cfg = SpatialConfig(bounds=((0.0, 1.0), (0.0, 1.0)), grid_points=4)
    with pytest.raises(ValueError, match="coordinates per point"):
        point_cost([[0.0, 0.0]], np.zeros((5, 2, 3)), 1.0)
    with pytest.raises(ValueError, match="non-empty"):
        point_cost([[0.0, 0.0]], np.zeros((5, 0, 2)), 1.0)
    with pytest.raises(ValueError, match="non-empty"):
        SpatialCostModel.from_population(cfg, [np.zeros((5, 3, 2, 2))])
    bad = np.zeros((5, 2, 2))
    bad[2, 1, 0] = np.inf
    with pytest.raises(ValueError, match="NaN or infinite"):
        SpatialCostModel.from_population(cfg, [bad])
