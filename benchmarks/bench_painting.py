"""Painting world benchmark: what the loop pays for the arm and the person, and the shipped
policy's samples.

    .venv/bin/python benchmarks/bench_painting.py [--update-docs] [--policy-samples N]

Measures (one torch thread, as every sweep worker runs): compiling the MuJoCo scene; forward
kinematics of 32 x 64 and 320 x 64 joint vectors to the arm's 12 points, against one
``mj_kinematics`` call per configuration; completion times of a steering batch; one IK solve;
the demonstrations; building the spatial prior from the population (hands and elbows) and one
observed cycle; S of a steering batch from the arm's points. Then samples the bundled policy
(``--policy-samples`` per task, unsteered) and reports how many complete their task, the motion
modes and how many cannot be executed; ``--policy DIR`` does only that, for another checkpoint
(a distilled one, say). With --update-docs the "## Painting world" section of
docs/benchmarks.md is replaced (or added).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch
from _common import cpu_model, load_average, update_docs_section

from rapidds.worlds.painting import PaintingWorld
from rapidds.worlds.painting.calibration import prior_model
from rapidds.worlds.painting.kinematics import arm_kinematics, solve_ik
from rapidds.worlds.painting.scene import build_model, load_model


def timed(fn, min_time: float = 1.0) -> float:
    """Fastest seconds per call over repeats filling about ``min_time`` (the minimum is the
    estimate least disturbed by other jobs on shared cores, as timeit advises)."""
    fn()
    best, spent, n = float("inf"), 0.0, 0
    while spent < min_time or n < 3:
        t0 = time.perf_counter()
        fn()
        dt = time.perf_counter() - t0
        best, spent, n = min(best, dt), spent + dt, n + 1
    return best


def world_timings(world: PaintingWorld) -> list[tuple[str, str]]:
    import mujoco

    rows = []
    t0 = time.perf_counter()
    build_model()
    rows.append(("compile the scene (Panda meshes, cell, mocap person)",
                 f"{time.perf_counter() - t0:.2f} s"))
    kin = arm_kinematics()
    rng = np.random.default_rng(0)
    for n in (32, 320):
        q = rng.uniform(kin.lower, kin.upper, size=(n, world.horizon, 7))
        s = timed(lambda q=q: kin.points(q))
        rows.append((f"forward kinematics, {n} x {world.horizon} configurations -> 12 points",
                     f"{s * 1e3:.2f} ms"))
    model = load_model()
    data = mujoco.MjData(model)
    q = rng.uniform(kin.lower, kin.upper, size=(32 * world.horizon, 7))

    def one_by_one() -> None:
        for row in q:
            data.qpos[:7] = row
            mujoco.mj_kinematics(model, data)

    s = timed(one_by_one)
    rows.append((f"mj_kinematics, one call per configuration, 32 x {world.horizon}",
                 f"{s * 1e3:.1f} ms"))
    demos = world.robot_demonstrations(8, np.random.default_rng(1))
    batch = demos.trajectories[demos.task_index == 0][:8].repeat(4, axis=0)
    s = timed(lambda: world.completion_time("mix_l", batch))
    rows.append((f"completion time (FK, collisions, goals), 32 x {world.horizon}",
                 f"{s * 1e3:.2f} ms"))
    rest = world.robot_rest()
    s = timed(lambda: solve_ik((-0.3, 0.05, 0.05), rest), min_time=0.5)
    rows.append(("one IK solve with mink (180 steps)", f"{s * 1e3:.1f} ms"))
    t0 = time.perf_counter()
    world.robot_demonstrations(64, np.random.default_rng(0))
    rows.append(("demonstrations, 64 per mode x 6 modes", f"{time.perf_counter() - t0:.2f} s"))
    t0 = time.perf_counter()
    prior = prior_model(world)
    n_paths = len(world.prior().paths["secure_piece"])
    rows.append((f"spatial prior of Prep Vise and Secure Piece, {n_paths} paths each, "
                 f"{world.spatial_grid}^3 grid", f"{time.perf_counter() - t0:.1f} s"))
    person = world.teammate("left-fast")
    path = person.perform("secure_piece", np.random.default_rng(2))[1]
    s = timed(lambda: prior["secure_piece"].observe(path), min_time=0.5)
    rows.append((f"one observed Secure Piece path ({len(path)} x 4 body points)",
                 f"{s * 1e3:.0f} ms"))
    pts = world.robot_points(demos.trajectories[:32].repeat(8, axis=0)).reshape(256, -1, 3)
    s = timed(lambda: prior.cost(["secure_piece"], pts))
    rows.append((f"S of 256 trajectories x {world.horizon} rows x 12 points (grid)",
                 f"{s * 1e3:.1f} ms"))
    return rows


def policy_samples(world: PaintingWorld, n: int, path: Path | None = None
                   ) -> list[tuple[str, ...]]:
    """Per task: completed, direct / avoidant, median completion time per mode, not
    executable; of ``n`` unsteered samples of the checkpoint at ``path`` (the bundled one)."""
    from rapidds.motion.policy import DiffusionPolicy

    path = path or world.bundled_policy()
    if path is None:
        return []
    policy = DiffusionPolicy.load(path)
    out = []
    for k, task in enumerate(("mix_l", "mix_r", "brush")):
        traj = policy.sample(task, n, generator=100 + k)
        t = world.completion_time(task, traj)
        done = t < world.penalty
        ok = world.executable(traj)
        modes = [world.motion_label(task, tr) for tr, d in zip(traj, done, strict=True) if d]
        direct = sum(m == "direct" for m in modes)
        med = {m: np.median([x for x, mm in zip(t[done], modes, strict=True) if mm == m])
               for m in ("direct", "avoidant") if m in modes}
        out.append((task, f"{done.mean():.1%}", f"{direct} / {len(modes) - direct}",
                    " / ".join(f"{med.get(m, float('nan')):.2f}" for m in ("direct", "avoidant")),
                    f"{1 - ok.mean():.1%}"))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--update-docs", action="store_true")
    ap.add_argument("--policy-samples", type=int, default=200)
    ap.add_argument("--policy", type=Path,
                    help="only sample this checkpoint (a distilled one, say) and print its rows")
    args = ap.parse_args()
    if args.policy is not None:
        torch.set_num_threads(1)
        for row in policy_samples(PaintingWorld(), args.policy_samples, args.policy):
            print("| " + " | ".join(row) + " |")
        return
    torch.set_num_threads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    load0 = load_average()
    world = PaintingWorld()
    rows = world_timings(world)
    samples = policy_samples(world, args.policy_samples)
    load1 = load_average()
    lines = [
        "`benchmarks/bench_painting.py`: the painting world's costs inside the loop, one torch "
        f"thread on {cpu_model()} (2 cores, shared; 1-min load average {load0} at start, "
        f"{load1} at end, so seconds are upper bounds). Times are the fastest of repeats.",
        "",
        "| step | time |",
        "|---|---|",
        *[f"| {a} | {b} |" for a, b in rows],
    ]
    if samples:
        lines += [
            "",
            f"Bundled policy, {args.policy_samples} unsteered samples per task: share that "
            "completes the task, their modes (direct / avoidant), median completion time of each "
            "mode (s), share not executable (joint range, speed, collision):",
            "",
            "| task | completes | direct / avoidant | median s direct / avoidant | "
            "not executable |",
            "|---|---|---|---|---|",
            *[f"| {' | '.join(r)} |" for r in samples],
        ]
    body = "\n".join(lines)
    print(body)
    if args.update_docs:
        update_docs_section("## Painting world", body)


if __name__ == "__main__":
    main()
