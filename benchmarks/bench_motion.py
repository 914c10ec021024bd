"""Motion benchmark: steered samples per second of the bundled fetch policy on this CPU, for
SVDD candidates M in {1, 8, 16, 32} and reverse steps in {10, 20, 50}; optionally training
speed.

V is the paper's value for robot task t3 while the human does t2, with the population prior as
the human's spatial cost: V = completion time + 1.75 * S_t2.

    .venv/bin/python benchmarks/bench_motion.py [--particles 16] [--train-steps 200]
        [--update-docs]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from _common import cpu_model, load_average, update_docs_section

from rapidds.loop import RunConfig, load_policy, prior_model
from rapidds.motion.steering import steer
from rapidds.worlds.fetch import POLICY_DEFAULTS, FetchWorld

SECTION = "## Motion (diffusion policy and SVDD-PM steering)"



def train_speed(steps: int) -> str:
    from rapidds.motion.config import DiffusionConfig
    from rapidds.motion.demos import Demonstrations
    from rapidds.motion.train import train_policy

    world = FetchWorld()
    d = world.robot_demonstrations(64, np.random.default_rng(0))
    demos = Demonstrations(d.trajectories.astype(np.float32), d.task_index, d.task_names)
    fields = {**POLICY_DEFAULTS, "steps": steps, "horizon": world.horizon, "state_dim": 2,
              "task_names": list(d.task_names), "device": "cpu"}
    _, hist = train_policy(demos, DiffusionConfig.from_dict(fields))
    per = hist.seconds / steps
    return (f"Training (fetch demonstrations, 384 trajectories, batch 64, one thread): "
            f"{1000 * per:.0f} ms per step over {steps} steps, i.e. "
            f"{per * int(POLICY_DEFAULTS['steps']) / 60:.1f} min for the shipped policy's "
            f"{POLICY_DEFAULTS['steps']} steps.")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--particles", type=int, default=16)
    ap.add_argument("--train-steps", type=int, default=0)
    ap.add_argument("--update-docs", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    world = FetchWorld()
    policy = load_policy(world)
    spatial = prior_model(world, RunConfig().resolved(world)).spatial

    def value(xi: np.ndarray) -> np.ndarray:
        return world.completion_time("t3", xi) + 1.75 * spatial.cost(["t2"], xi)

    base = policy.config
    rows = []
    for steps in (10, 20, 50):
        policy.config = base.replace(num_inference_steps=steps)
        cells = []
        for m in (1, 8, 16, 32):
            steer(policy, "t3", 2, value, num_candidates=m, generator=0)  # warm-up
            t0 = time.perf_counter()
            res = steer(policy, "t3", args.particles, value, num_candidates=m, generator=1)
            dt = time.perf_counter() - t0
            cells.append(f"{args.particles / dt:.1f} ({np.mean(res.values):.2f})")
        rows.append(f"| {steps} | " + " | ".join(cells) + " |")
    policy.config = base
    lines = [
        SECTION,
        "",
        f"`benchmarks/bench_motion.py`: bundled fetch policy ({POLICY_DEFAULTS['down_dims']} "
        f"channels), one torch thread on {cpu_model()} (2 cores, 1-min load average "
        f"{load_average()} at the end: other jobs shared the cores, so rates are lower bounds); "
        "no GPU was lent to this session, so only CPU is measured.",
        "",
        f"Steered samples per second, {args.particles} particles per call (mean V of the kept "
        "samples in brackets: lower is better; V = completion s + 1.75 x spatial cost):",
        "",
        "| reverse steps | M = 1 (unsteered) | M = 8 | M = 16 | M = 32 |",
        "|---|---|---|---|---|",
        *rows,
        "",
    ]
    if args.train_steps:
        lines += [train_speed(args.train_steps), ""]
    text = "\n".join(lines)
    print(text)
    if args.update_docs:
        update_docs_section(SECTION, text.split("\n", 1)[1])


if __name__ == "__main__":
    main()
