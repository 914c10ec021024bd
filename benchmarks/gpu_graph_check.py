"""Whether replaying CUDA graphs (``DiffusionPolicy.cuda_graphs``) gives the eager results,
bit for bit, and what a replay saves: ``gpu_check.sh``'s ``graph_check`` part, so that a
card's few minutes say at once where capture breaks, if it does.

    python benchmarks/gpu_graph_check.py [--device cuda] [--json OUT]

Checks, each against the same calls run eagerly: the painting network's passes through
:class:`~rapidds.motion.cuda_graphs.Replayed` for two batch shapes and several inputs and
steps, inside and outside inference mode; ``sample`` with and without the switch; and a
steering batch of three requests with the value on the device (the value's graph), with and
without the switch: trajectories and values equal, no capture note. Then the milliseconds of a
192-row pass, eager and replayed. On the CPU nothing is captured and every check holds
trivially (a dry run). Prints one JSON object; exit 1 when a check fails.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import sync  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)

    from bench_steer_device import REQUESTS, painting_cell, steering_motion

    from rapidds.motion.cuda_graphs import Replayed

    world, spatial, policy = painting_cell(args.device)
    dev = policy.device
    net = policy.denoiser()
    out: dict[str, object] = {"device": str(dev)}
    gen = torch.Generator(dev).manual_seed(0)

    # the network: two shapes, fresh inputs and steps every call, in and out of inference mode
    replayed = Replayed(net)
    same = True
    for rows in (24, 192):
        cond = policy.condition(["mix_l", "brush"] * (rows // 2), rows)
        for k in range(5):
            x = torch.randn(rows, policy.config.horizon, policy.config.state_dim,
                            generator=gen, device=dev)
            t = torch.full((), 90 - 10 * k, dtype=torch.long, device=dev)
            # the first shape is captured outside inference mode, the second inside it
            with torch.inference_mode((k + (rows == 192)) % 2 == 0):
                got, want = replayed(x, t, cond), net(x, t, cond)
            same &= bool(torch.equal(got, want))
    out["network_equal"] = same
    out["network_graphs"] = len(replayed.graphs)
    out["network_note"] = replayed.note

    def sample(graphs: bool) -> np.ndarray:
        policy.cuda_graphs = graphs
        return policy.sample(["mix_l", "mix_r", "brush"] * 4, 12, generator=3)

    out["sample_equal"] = bool(np.array_equal(sample(False), sample(True)))

    def steer(graphs: bool) -> list[np.ndarray]:
        policy.cuda_graphs = graphs
        plans = steering_motion(world, spatial, policy, 5).plan(REQUESTS[:3])
        return [np.append(p.trajectory.ravel(), p.duration) for p in plans]

    plain, graphed = steer(False), steer(True)
    out["steer_equal"] = all(np.array_equal(a, b) for a, b in zip(plain, graphed, strict=True))
    out["graph_notes"] = dict(policy.graph_notes)

    # what a replay saves: a 192-row pass, eager and replayed (captured above)
    cond = policy.condition(["mix_l"] * 192, 192)
    x = torch.randn(192, policy.config.horizon, policy.config.state_dim, device=dev)
    t = torch.full((), 50, dtype=torch.long, device=dev)
    for name, fn in (("eager", net), ("replayed", replayed)):
        times = []
        with torch.inference_mode():
            for _ in range(20):
                sync(dev)
                t0 = time.perf_counter()
                fn(x, t, cond)
                sync(dev)
                times.append(time.perf_counter() - t0)
        out[f"pass_ms_{name}"] = 1000 * statistics.median(times[5:])
    ok = all(out[k] for k in ("network_equal", "sample_equal", "steer_equal"))
    out["ok"] = ok and not out["network_note"] and not out["graph_notes"]
    print(json.dumps(out), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=2) + "\n")
    sys.exit(0 if out["ok"] else 1)


if __name__ == "__main__":
    main()
