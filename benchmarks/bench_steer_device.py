"""One painting cycle's steering batch (6 requests x 4 particles x 8 candidates, the policy's
10 steps) with the value on the host (numpy, the CPU's path) and on the policy's device
(tensor terms), each without and with the safety monitor's predicted hold (a plan that expects
the monitor), on each device given: seconds per batch, and on CUDA the host synchronisations
inside it (``torch.cuda.set_sync_debug_mode``) and the tensor operations it issues as a GPU
runs it (each one dispatched by the host, each but a view a kernel it launches; counted on any
device). On CUDA also the device value with the network's passes and the value's calls
replayed from CUDA graphs (``DiffusionPolicy.cuda_graphs``), whose plans must equal the plain
device value's, seed by seed (``digest``: the plans' durations and trajectories).

    .venv/bin/python benchmarks/bench_steer_device.py [--devices cpu,cuda] [--repeat 5]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from _common import cpu_model, load_average, sync
from torch.utils._python_dispatch import TorchDispatchMode

from rapidds.execution.slowdowns import HoldModel, approach_speeds
from rapidds.human.spatial import SpatialConfig, SpatialModel, grid
from rapidds.loop.model import device_terms, workspace_cost
from rapidds.loop.run import load_policy
from rapidds.motion.diffusion_motion import DiffusionMotion, SteeringConfig, ValueTerms
from rapidds.motion.policy import DiffusionPolicy
from rapidds.worlds.painting import PaintingWorld
from rapidds.worlds.reactions import cell_reactions

REQUESTS = [("mix_l", frozenset({"secure_piece"})), ("mix_r", frozenset({"secure_piece"})),
            ("brush", frozenset({"prep_vise"})), ("mix_l", frozenset({"prep_vise"})),
            ("mix_r", frozenset({"prep_vise", "secure_piece"})),
            ("brush", frozenset({"secure_piece"}))]


# operations that only make a new view of a tensor: no kernel on a GPU, only the host's
# dispatch
_VIEWS = {"view", "select", "slice", "unsqueeze", "squeeze", "expand", "reshape",
          "_unsafe_view", "transpose", "permute", "split", "split_with_sizes", "unbind",
          "detach", "alias", "t", "as_strided", "_reshape_alias"}


class _OpCount(TorchDispatchMode):
    """Counts the ATen operations run inside it, and those that are not views."""

    count = 0
    kernels = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # type: ignore[override]
        self.count += 1
        self.kernels += func.__name__.split(".")[0] not in _VIEWS
        return func(*args, **(kwargs or {}))


def _count_as_on_a_gpu(policy, plan, on_device: bool) -> _OpCount:
    """The operations ``plan()`` issues as a GPU would run it, on any device: the network
    with PyTorch's Mish, and a value on the device (``on_device``) without the spatial
    grid's host-only pruning and checks."""
    keep = getattr(grid, "reads_back", None)  # None: an older tree, counted as it is
    # (on a GPU the network has PyTorch's Mish already: set again it would rebuild the network
    # copy, and its captured graphs with it)
    cpu = policy.device.type == "cpu"
    if cpu:
        policy.native_mish = True
    if on_device and keep is not None:
        grid.reads_back = lambda t: False
    try:
        with _OpCount() as ops:
            plan()
    finally:
        if cpu:
            policy.native_mish = None
        if keep is not None:
            grid.reads_back = keep
    return ops


def painting_cell(device: str) -> tuple[PaintingWorld, SpatialModel, DiffusionPolicy]:
    """The painting world, its population prior and its shipped policy on ``device``: what a
    measured steering batch plans with."""
    world = PaintingWorld()
    lo, hi = world.workspace_bounds
    spatial = SpatialModel.from_population(
        SpatialConfig.from_box(lo, hi, beta=world.spatial_beta, grid_points=world.spatial_grid),
        world.prior().paths)
    return world, spatial, load_policy(world, device=device)


def steering_motion(world: PaintingWorld, spatial: SpatialModel, policy: DiffusionPolicy,
                    seed: int, on_device: bool = True, holds: HoldModel | None = None
                    ) -> DiffusionMotion:
    """The steering a cycle of the painting cell runs (gamma 12, the default search), its
    value on the device or the host, with ``holds``' predicted hold when given."""
    return DiffusionMotion(policy, world.completion_time, workspace_cost(world, spatial), 12.0,
                           SteeringConfig(seed=seed),
                           terms=ValueTerms(device_terms=device_terms(world, spatial),
                                            hold=None if holds is None else holds.hold,
                                            device_hold=None if holds is None
                                            else holds.tensor_hold, on_device=on_device))


def measure(device: str, repeat: int) -> dict[str, object]:
    torch.set_num_threads(1)
    world, spatial, policy = painting_cell(device)
    limits = cell_reactions(world)[1]
    holds = HoldModel(world, spatial, limits, approach_speeds(world, spatial, limits))
    out: dict[str, object] = {}
    rows = [("host value", False, False, False), ("device value", True, False, False),
            ("host value + hold", False, True, False), ("device value + hold", True, True, False)]
    if device == "cuda" and hasattr(policy, "graph_notes"):  # not an older tree
        rows += [("device value, graphs", True, False, True),
                 ("device value + hold, graphs", True, True, True)]
    for label, on_device, held, graphs in rows:
        policy.cuda_graphs, policy.graph_notes = graphs, {}
        def motion(seed: int, on: bool = on_device, held: bool = held) -> DiffusionMotion:
            return steering_motion(world, spatial, policy, seed, on, holds if held else None)

        motion(99).plan(REQUESTS)  # warm-up: kernels, caches, tensor terms
        wall, cpu, syncs = [], [], 0
        digest = hashlib.sha256()
        for k in range(repeat):
            sync(device)
            w0, c0 = time.perf_counter(), time.process_time()
            if device == "cuda" and on_device:
                torch.cuda.set_sync_debug_mode("warn")
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                plans = motion(k).plan(REQUESTS)
            if device == "cuda":
                torch.cuda.set_sync_debug_mode(0)
            sync(device)
            wall.append(time.perf_counter() - w0)
            cpu.append(time.process_time() - c0)
            syncs += sum("synchroniz" in str(w.message) for w in caught)
            for p in plans:
                digest.update(np.float64(p.duration).tobytes())
                digest.update(np.ascontiguousarray(p.trajectory, dtype=np.float64).tobytes())
        replayed = getattr(policy, "_replayed", None)  # None: an older tree
        # the network's captured shapes, and why a capture failed if one did (timed runs')
        captured = [0 if replayed is None else len(replayed.graphs), dict(policy.graph_notes)]
        # untimed: the tensor operations a batch issues, each one the host dispatches and
        # each but a view a kernel it launches on a GPU (with graphs: the launches the host
        # still makes)
        ops = _count_as_on_a_gpu(policy, lambda: motion(repeat).plan(REQUESTS), on_device)
        out[label] = {"wall_s": statistics.median(wall), "cpu_s": statistics.median(cpu),
                      "syncs_per_batch": syncs / repeat, "tensor_ops_per_batch": ops.count,
                      "kernels_per_batch": ops.kernels,
                      "mean_duration": float(np.mean([p.duration for p in plans])),
                      "digest": digest.hexdigest()[:16]}
        if graphs:
            out[label]["graphs"] = captured
        print(f"{device} {label}: {json.dumps(out[label])}", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--devices", default=None, help="default: cpu, and cuda when available")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    devices = (args.devices.split(",") if args.devices
               else ["cpu"] + (["cuda"] if torch.cuda.is_available() else []))
    load0 = load_average()
    res = {dev: measure(dev, args.repeat) for dev in devices}
    print(f"{cpu_model()}, one torch thread; 1-min load average {load0} at start, "
          f"{load_average()} at end")
    if args.json is not None:
        args.json.write_text(json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
