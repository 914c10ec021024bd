"""Spatial model benchmark: surrogate fit time per cycle and trajectory-cost throughput.

    .venv/bin/python benchmarks/bench_spatial.py [--update-docs]

Four human tasks on a 10 x 10 map with the default SpatialConfig (32 x 32 grid), ten population
paths each. Measures (one torch thread, as every sweep worker runs):
- the cold MLP fit of the four tasks, then per cycle the warm refit of all four after one
  observation each (what the run loop pays between cycles);
- S_i throughput for N = 1024 trajectories of H = 32 points (d = 2), and the latency of one
  steering-sized call (N = 512 particles x 64 candidates), by MLP and by grid interpolation;
- the MLP's error against grid interpolation, and both against the exact posterior mean at
  random points (computed from the raw paths).
With --update-docs the "## Spatial model" section of docs/benchmarks.md is replaced (or added).
"""

from __future__ import annotations

import argparse
import itertools
import os
import statistics
import time

import numpy as np
import torch
from _common import cpu_model, load_average, update_docs_section

from rapidds.human.spatial import SpatialConfig, SpatialCostModel, SpatialModel, point_cost

ROUTES = {  # (start, corners..., end) of each human task, fetch-like
    "t0": [(5, 1), (3, 5), (2, 9)],
    "t1": [(5, 1), (7, 5), (8, 9)],
    "t2": [(5, 1), (2, 2), (2, 4)],
    "t3": [(5, 1), (8, 2), (8, 4)],
}
ALT = {"t2": [(5, 1), (4, 3), (2, 4)], "t3": [(5, 1), (6, 3), (8, 4)]}  # "middle" routes


def walk(corners, rng: np.random.Generator, jitter: float = 0.3, spacing: float = 0.1):
    c = np.asarray(corners, dtype=float).copy()
    c[1:-1] += rng.normal(0.0, jitter, c[1:-1].shape)
    seg = [a + (b - a) * np.linspace(0, 1, max(2, int(np.linalg.norm(b - a) / spacing)),
                                     endpoint=False)[:, None] for a, b in itertools.pairwise(c)]
    return np.concatenate([*seg, c[-1:]])


def timed(fn, min_time: float = 1.0) -> float:
    """Fastest seconds per call over repeats filling about ``min_time`` (the minimum is the
    estimate least disturbed by other jobs on shared cores, as timeit advises)."""
    fn()
    times: list[float] = []
    while sum(times) < min_time or len(times) < 3:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)



def exact_posterior(cfg: SpatialConfig, pop, obs, x: np.ndarray) -> np.ndarray:
    """Eqs. 9-11 evaluated directly at arbitrary points (what the grid approximates)."""
    costs = np.stack([point_cost(x, p, cfg.beta) for p in pop])
    mean, var = costs.mean(0), np.maximum(costs.var(0), cfg.min_prior_var)
    for o in obs:
        s = point_cost(x, o, cfg.beta)
        new = 1.0 / (1.0 / var + 1.0 / cfg.rho)
        mean, var = new * (mean / var + s / cfg.rho), new
    return mean



def run(cycles: int) -> tuple[str, dict[str, float]]:
    torch.set_num_threads(1)
    load_start = load_average()
    rng = np.random.default_rng(0)
    pops = {t: [walk(ALT.get(t, r) if k % 2 else r, rng) for k in range(10)]
            for t, r in ROUTES.items()}
    cfg = SpatialConfig(bounds=((0.0, 10.0), (0.0, 10.0)), use_surrogate=True)
    model = SpatialModel.from_population(cfg, pops)
    t0 = time.perf_counter()
    cold = model.refit()
    cold_s = time.perf_counter() - t0
    cycle_s: list[float] = []
    cycle_steps: list[int] = []
    obs: dict[str, list[np.ndarray]] = {t: [] for t in ROUTES}
    for _ in range(cycles):
        for t, r in ROUTES.items():
            obs[t].append(walk(ALT.get(t, r), rng))
            model.observe(t, obs[t][-1])
        t0 = time.perf_counter()
        reps = model.refit()
        cycle_s.append(time.perf_counter() - t0)
        cycle_steps.append(sum(r.steps for r in reps.values()))

    m: SpatialCostModel = model["t2"]
    err = m.surrogate_error()
    xr = np.random.default_rng(1).random((4096, 2)) * 10
    exact = exact_posterior(cfg, pops["t2"], obs["t2"], xr)
    with torch.no_grad():
        xt = torch.as_tensor(xr)
        grid_vs_exact = np.abs(m._eval_grid(xt).numpy() - exact)
        mlp_vs_exact = np.abs(m._eval_mlp(xt).numpy() - exact)

    grid_cfg = SpatialConfig(bounds=cfg.bounds, use_surrogate=False)
    grid_m = SpatialCostModel.from_dict({**m.to_dict(), "config": grid_cfg.to_dict()})
    xi = torch.rand(1024, 32, 2, generator=torch.Generator().manual_seed(0)) * 10
    xi_np = xi.double().numpy()
    big = torch.rand(512 * 64, 32, 2, generator=torch.Generator().manual_seed(1)) * 10
    res = {}
    for name, mod in (("MLP", m), ("grid", grid_m)):
        res[f"{name}_torch"] = 1024 / timed(lambda mod=mod: mod.trajectory_cost(xi))
        res[f"{name}_numpy"] = 1024 / timed(lambda mod=mod: mod.trajectory_cost(xi_np))
        res[f"{name}_big_ms"] = 1e3 * timed(lambda mod=mod: mod.trajectory_cost(big), 2.0)

    nums = {
        "cold_s": cold_s, "cold_steps": sum(r.steps for r in cold.values()),
        "cycle_med_s": statistics.median(cycle_s), "cycle_max_s": max(cycle_s),
        "cycle_steps": statistics.median(cycle_steps), **res,
        "err_grid_max": err.grid_max, "err_grid_mean": err.grid_mean,
        "err_rand_max": err.random_max, "err_rand_mean": err.random_mean,
        "grid_exact_max": float(grid_vs_exact.max()),
        "grid_exact_mean": float(grid_vs_exact.mean()),
        "mlp_exact_max": float(mlp_vs_exact.max()),
        "mlp_exact_mean": float(mlp_vs_exact.mean()),
    }
    n = nums
    table = f"""\
Machine: {cpu_model()}, {os.cpu_count()} cores (shared), 1 torch thread, torch {torch.__version__};
1-min load average {load_start} at start, {load_average()} at end (other jobs share the cores,
so seconds are upper bounds; Adam step counts do not depend on load).
Default `SpatialConfig` on a 10 x 10 map: 32 x 32 grid (V = 1024), MLP 3 x 64 SiLU with a
4-octave positional encoding, Adam lr 1e-2, fit stops at max grid error 0.02.

| measure | value |
|---|---|
| cold MLP fit, 4 tasks | {n['cold_s']:.2f} s ({n['cold_steps']} Adam steps) |
| warm refit per cycle, 4 tasks, one observation each (median / max of {cycles}) | \
{n['cycle_med_s']:.2f} s / {n['cycle_max_s']:.2f} s ({n['cycle_steps']:.0f} steps) |
| S_i throughput, N = 1024, H = 32, d = 2, MLP (torch f32 / numpy f64 input) | \
{n['MLP_torch']:,.0f} / {n['MLP_numpy']:,.0f} traj/s |
| S_i throughput, same, grid interpolation (torch f32 / numpy f64 input) | \
{n['grid_torch']:,.0f} / {n['grid_numpy']:,.0f} traj/s |
| one steering call, N = 512 x 64, H = 32: MLP / grid | \
{n['MLP_big_ms']:.0f} ms / {n['grid_big_ms']:.0f} ms |
| MLP vs grid at the grid points, max / mean abs | \
{n['err_grid_max']:.3f} / {n['err_grid_mean']:.4f} |
| MLP vs grid at 4096 random points, max / mean abs | \
{n['err_rand_max']:.3f} / {n['err_rand_mean']:.4f} |
| grid interpolation vs exact posterior, random points, max / mean | \
{n['grid_exact_max']:.3f} / {n['grid_exact_mean']:.4f} |
| MLP vs exact posterior, random points, max / mean | \
{n['mlp_exact_max']:.3f} / {n['mlp_exact_mean']:.4f} |
"""
    return table, nums



def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=8)
    ap.add_argument("--update-docs", action="store_true")
    args = ap.parse_args()
    table, _ = run(args.cycles)
    print(table)
    if args.update_docs:
        update_docs_section("## Spatial model", "`benchmarks/bench_spatial.py`\n\n" + table)


if __name__ == "__main__":
    main()
