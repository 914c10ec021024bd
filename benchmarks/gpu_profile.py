"""Where a step's device time goes: the kernels of a painting-policy training step and of one
painting steering batch, by device time (``torch.profiler``), beside the wall time.

    .venv/bin/python benchmarks/gpu_profile.py [--device cuda] [--steps 20] [--top 15] [--json OUT]

Part of ``gpu_check.sh``. On the H200 a captured training step took 9.6-16.2 ms for a few
hundred kernels (docs/benchmarks.md, "The GPU measured"), far above what its arithmetic needs,
and a steering batch was bound by the host launching its kernels. This says which: the device's
busy time per step against the wall time, and the kernels (or, on the CPU, the operators)
that take it, so the next change aims at the right one. Training is profiled op by op (a
captured graph hides its kernels from some profilers), after 20 warm-up steps; the steering
batch is the 6-request batch of ``bench_steer_device.py`` with the value on the device, with
and without CUDA graphs (``DiffusionPolicy.cuda_graphs``). Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch
from torch.autograd import DeviceType
from torch.profiler import ProfilerActivity, profile

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import sync  # noqa: E402


def _table(prof: profile, device: str, top: int) -> tuple[float, int, list[dict[str, object]]]:
    """(total device ms, kernels launched, the ``top`` kernels or operators by self device
    time). On a GPU only the device's own events count (kernels, copies): an operator's row
    carries its kernels' time as well, and summing both counted the time twice (the H200's
    profile of 2026-11-28 read 12.6 ms of device time per training step so)."""
    on_gpu = device == "cuda"
    rows = []
    for e in prof.key_averages():
        if on_gpu and e.device_type != DeviceType.CUDA:
            continue
        self_us = e.self_device_time_total if on_gpu else e.self_cpu_time_total
        if self_us > 0:
            rows.append({"name": e.key[:90], "calls": e.count, "self_ms": self_us / 1000})
    rows.sort(key=lambda r: -float(r["self_ms"]))  # type: ignore[arg-type]
    # on the CPU the operators' self times add up to the host's busy time
    return (sum(float(r["self_ms"]) for r in rows), sum(int(r["calls"]) for r in rows),  # type: ignore[call-overload]
            rows[:top])


def training(device: str, steps: int, top: int) -> dict[str, object]:
    from rapidds.cli.motion import _world_demos
    from rapidds.motion.config import DiffusionConfig
    from rapidds.motion.train import train_policy

    demos, fields = _world_demos("painting", 16, 0)
    fields.update(horizon=demos.horizon, state_dim=demos.state_dim,
                  task_names=list(demos.task_names), steps=20, device=device)
    cfg = DiffusionConfig.from_dict(fields)
    train_policy(demos, cfg, cuda_graph=False)  # allocator, kernels
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device == "cuda" else [])
    with profile(activities=activities) as prof:
        w0 = time.perf_counter()
        _, history = train_policy(demos, cfg.replace(steps=steps), cuda_graph=False)
        sync(device)
        wall = time.perf_counter() - w0
    busy, launched, kernels = _table(prof, device, top)
    return {"steps": steps, "wall_ms_per_step": 1000 * wall / steps,
            "device_busy_ms_per_step": busy / steps, "launched_per_step": launched / steps,
            "top": kernels,
            "final_loss": history.mean_loss(last=5)}


def steering(device: str, graphs: bool, top: int) -> dict[str, object]:
    from bench_steer_device import REQUESTS, painting_cell, steering_motion

    world, spatial, policy = painting_cell(device)
    policy.cuda_graphs = graphs

    def batch(seed: int) -> None:
        steering_motion(world, spatial, policy, seed).plan(REQUESTS)

    batch(98)  # kernels, caches, the network's graphs
    batch(99)
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device == "cuda" else [])
    with profile(activities=activities) as prof:
        w0 = time.perf_counter()
        batch(0)
        sync(device)
        wall = time.perf_counter() - w0
    busy, launched, kernels = _table(prof, device, top)
    return {"graphs": graphs, "wall_ms": 1000 * wall, "device_busy_ms": busy,
            "launched": launched,
            "graph_notes": dict(policy.graph_notes), "top": kernels}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--top", type=int, default=15)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    out: dict[str, object] = {"device": args.device}
    out["training"] = training(args.device, args.steps, args.top)
    print(json.dumps({"training": out["training"]}), flush=True)
    for graphs in (False, True) if args.device == "cuda" else (False,):
        key = "steering, graphs" if graphs else "steering"
        out[key] = steering(args.device, graphs, args.top)
        print(json.dumps({key: out[key]}), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
