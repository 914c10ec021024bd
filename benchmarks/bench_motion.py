"""Motion benchmark: steered samples per second of the bundled fetch policy on this CPU, the
reference network (``policy.model``) against the inference copy (``FastUnet``) side by side in
one process; mean V against the number of reverse steps; fetch cycle times; optionally training
speed.

V in the speed table is the paper's value for robot task t3 while the human does t2, with the
population prior as the human's spatial cost: V = completion time + 1.75 * S_t2. The steps
table scores every request the scheduler can make in the fetch job (each robot task alone and
beside each human task), best of 4 particles as the loop keeps it.

    .venv/bin/python benchmarks/bench_motion.py [--reps 5] [--seeds 24] [--cycles 8]
        [--cycle-seeds 3] [--train-steps 200] [--update-docs]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from _common import cpu_model, load_average, update_docs_section

from rapidds.loop import AdaptiveRun, RunConfig, load_policy, prior_model
from rapidds.motion.diffusion_motion import DiffusionMotion, SteeringConfig
from rapidds.motion.policy import DiffusionPolicy
from rapidds.motion.steering import SteerRequest, steer
from rapidds.worlds.fetch import POLICY_DEFAULTS, FetchWorld

SECTION = "## Motion (diffusion policy and SVDD-PM steering)"
SHIPPED = ("Recorded when the bundled policy was trained (not re-measured by this script): "
           "`rapidds train-policy --world fetch` took 263 s for 4000 steps (final loss 0.008); "
           "its samples complete every task with both routes of t2/t3 about half and half, "
           "0-1.6% failures and under 1% wall contacts per task.")

# (candidates M, particles): 32 and 256 network rows per pass for each M.
SPEED_CASES = ((1, 32), (1, 256), (8, 4), (8, 32))
FEWER_STEPS = (6, 5, 4)
STUDY_STEPS = (3, 4, 5, 6, 8, 10)


def speed_table(policy: DiffusionPolicy, value, reps: int
                ) -> tuple[list[str], dict[tuple[int, int, int | None], float]]:
    """Samples/s and mean V, reference vs fast network, repetitions interleaved so that load
    changes hit both alike; also the speed-ups by (M, particles, steps or None)."""

    def once(fast: bool, m: int, p: int, steps: int | None, seed: int
             ) -> tuple[float, float, float]:
        policy.fast_inference = fast
        t0, c0 = time.perf_counter(), time.process_time()
        res = steer(policy, SteerRequest("t3", p), value, num_candidates=m, generator=seed,
                    num_steps=steps)
        return time.perf_counter() - t0, time.process_time() - c0, float(np.mean(res.values))

    rows = ["| M | particles | rows per pass | steps | reference samples/s | fast samples/s "
            "| speed-up | mean V reference / fast |", "|---|---|---|---|---|---|---|---|"]
    speedup: dict[tuple[int, int, int | None], float] = {}
    for m, p in SPEED_CASES:
        variants = [(False, None), (True, None)]
        if m > 1:
            variants += [(True, s) for s in FEWER_STEPS]
        for v in variants:
            once(*v[:1], m, p, v[1], 0)  # warm-up
        runs: dict[tuple[bool, int | None], list] = {v: [] for v in variants}
        for rep in range(reps):
            for v in variants:
                runs[v].append(once(v[0], m, p, v[1], rep + 1))
        med = {v: np.median(np.array(r)[:, :2], axis=0) for v, r in runs.items()}
        mean_v = {v: float(np.mean(np.array(r)[:, 2])) for v, r in runs.items()}
        ref = variants[0]
        steps = policy.config.num_inference_steps
        for v in variants[1:]:
            label = f"{steps}" if v[1] is None else f"**{v[1]}** (reference: {steps})"
            (rw, rc), (fw, fc) = med[ref], med[v]
            rows.append(f"| {m} | {p} | {p * m} | {label} | {p / rw:.1f} ({p / rc:.1f}) | "
                        f"{p / fw:.1f} ({p / fc:.1f}) | {rw / fw:.2f}x ({rc / fc:.2f}x) | "
                        f"{mean_v[ref]:.3f} / {mean_v[v]:.3f} |")
            speedup[(m, p, v[1])] = rw / fw
    policy.fast_inference = True
    return rows, speedup


def time_split(policy: DiffusionPolicy, value, reps: int) -> str:
    """Where a fast steering call of 32 particles x 8 candidates spends its time."""
    spent = {"network": 0.0, "value": 0.0, "total": 0.0}
    net = policy.denoiser()

    def timed_net(x, t, cond):
        t0 = time.perf_counter()
        out = net(x, t, cond)
        spent["network"] += time.perf_counter() - t0
        return out

    def timed_value(xi):
        t0 = time.perf_counter()
        out = value(xi)
        spent["value"] += time.perf_counter() - t0
        return out

    policy.denoiser = lambda: timed_net  # an instance attribute shadows the method meanwhile
    try:
        for rep in range(reps):
            t0 = time.perf_counter()
            steer(policy, SteerRequest("t3", 32), timed_value, num_candidates=8, generator=rep)
            spent["total"] += time.perf_counter() - t0
    finally:
        del policy.denoiser
    share = {k: 100 * v / spent["total"] for k, v in spent.items()}
    return (f"A fast steering call of 32 particles x 8 candidates at the policy's steps spends "
            f"{share['network']:.0f} % of its time in the network, {share['value']:.0f} % in "
            f"the value function (world code: completion time with the wall check, spatial "
            f"cost) and {100 - share['network'] - share['value']:.0f} % in the rest (reverse "
            f"kernel, Tweedie estimates, selection; mean of {reps} calls).")


def steps_table(policy: DiffusionPolicy, world: FetchWorld, seeds: int) -> tuple[list[str], int]:
    """Mean V of the kept plan over every (robot task, concurrent human task) request, by
    reverse steps; 4 particles x 8 candidates as in the default RunConfig."""
    cfg = RunConfig().resolved(world)
    problem = world.problem()
    spatial = prior_model(world, cfg).spatial
    ids = [t.id for t in problem.tasks]
    requests = [(j, frozenset(c)) for j in ids for c in [(), *((i,) for i in ids if i != j)]]
    results = {}
    for steps in STUDY_STEPS:
        per_seed, fails, secs = [], 0, 0.0
        for s in range(seeds):
            motion = DiffusionMotion(policy, world.completion_time, spatial.cost, cfg.gamma or 0.0,
                                     SteeringConfig(particles=cfg.particles,
                                                    candidates=cfg.candidates, seed=1000 * s,
                                                    steps=steps))
            t0 = time.perf_counter()
            plans = motion.plan(requests)
            secs += time.perf_counter() - t0
            per_seed.append(np.mean([p.duration + cfg.gamma * p.spatial_cost for p in plans]))
            fails += sum(p.duration >= world.penalty for p in plans)
        results[steps] = (np.array(per_seed), fails, secs / seeds)
    # Seed s draws the same x_T at every step count, so differences are taken seed by seed.
    base = results[policy.config.num_inference_steps][0]
    rows = ["| reverse steps | network rows per request | mean V (s.e.) | "
            f"V - V({policy.config.num_inference_steps} steps), paired (s.e.) | never completed "
            "| seconds per call |", "|---|---|---|---|---|---|"]
    se = np.sqrt(seeds)
    for steps, (v, fails, sec) in results.items():
        n_rows = cfg.particles * (1 + cfg.candidates * (steps - 1))
        d = v - base
        rows.append(f"| {steps} | {n_rows} | {v.mean():.3f} ({v.std(ddof=1) / se:.3f}) | "
                    f"{d.mean():+.3f} ({d.std(ddof=1) / se:.3f}) | {fails} of "
                    f"{seeds * len(requests)} | {sec:.2f} |")
    return rows, len(requests)


def cycle_table(policy: DiffusionPolicy, cycles: int, seeds: int) -> list[str]:
    """Fetch cycle (plan + execute + learn) with the default RunConfig; the fewer-steps rows set
    RunConfig.steps."""
    variants = [("reference network, policy steps", False, None),
                ("fast network, policy steps", True, None)]
    variants += [(f"fast network, {s} steps", True, s) for s in FEWER_STEPS]
    times: dict[str, list[float]] = {v[0]: [] for v in variants}
    costs: dict[str, list[float]] = {v[0]: [] for v in variants}
    plans: dict[str, list[tuple]] = {v[0]: [] for v in variants}
    try:
        for seed in range(seeds):
            for name, fast, steps in variants:
                policy.fast_inference = fast
                recs = AdaptiveRun(RunConfig(cycles=cycles, seed=seed, steps=steps), policy).run()
                times[name] += [(r.seconds or {}).get("total", 0.0) for r in recs]
                costs[name] += [r.realised.cost for r in recs]
                plans[name] += [(r.plan.human, r.plan.robot, r.plan.routes) for r in recs]
    finally:
        policy.fast_inference = True
    rows = ["| variant | median s | p90 s | mean realised cost |", "|---|---|---|---|"]
    for name, _, _ in variants:
        t = np.array(times[name])
        rows.append(f"| {name} | {np.median(t):.3f} | {np.percentile(t, 90):.3f} | "
                    f"{np.mean(costs[name]):.2f} |")
    ref, fast = (plans[v[0]] for v in variants[:2])
    same = sum(a == b for a, b in zip(ref, fast, strict=True))
    rows += ["", f"Reference and fast network chose the same schedule and robot routes in {same} "
                 f"of {len(ref)} cycles."]
    return rows


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
    return (f"Training (fetch demonstrations, 384 trajectories, batch 64, one thread; always "
            f"the reference network): {1000 * per:.0f} ms per step over {steps} steps, i.e. "
            f"{per * int(POLICY_DEFAULTS['steps']) / 60:.1f} min for the shipped policy's "
            f"{POLICY_DEFAULTS['steps']} steps.")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--seeds", type=int, default=24)
    ap.add_argument("--cycles", type=int, default=8)
    ap.add_argument("--cycle-seeds", type=int, default=3)
    ap.add_argument("--train-steps", type=int, default=0)
    ap.add_argument("--update-docs", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    load_start = load_average()
    world = FetchWorld()
    policy = load_policy(world, device="cpu")
    spatial = prior_model(world, RunConfig().resolved(world)).spatial

    def value(xi: np.ndarray) -> np.ndarray:
        return world.completion_time("t3", xi) + 1.75 * spatial.cost(["t2"], xi)

    t0 = time.perf_counter()
    speed, speedup = speed_table(policy, value, args.reps)
    split = time_split(policy, value, args.reps)
    load_speed = load_average()
    steps, n_requests = steps_table(policy, world, args.seeds)
    lines = [
        SECTION,
        "",
        f"`benchmarks/bench_motion.py --reps {args.reps} --seeds {args.seeds} --cycles "
        f"{args.cycles} --cycle-seeds {args.cycle_seeds}`: bundled fetch policy "
        f"({POLICY_DEFAULTS['down_dims']} channels, {policy.config.num_inference_steps} "
        f"reverse steps), one torch thread on {cpu_model()} (2 cores shared with other jobs: "
        f"1-min load average {load_start} at the start, {load_speed} after the speed table; "
        "seconds are upper bounds, ratios within one table are robust). No GPU was lent to this "
        "session, so only CPU is measured.",
        "",
        "Reference = sampling through `policy.model` (`fast_inference = False`, what every "
        "release before this one ran); fast = through `FastUnet`, the inference copy of the "
        "same network (exact Mish rewrite with one vectorised sigmoid, FiLM layers as one "
        "matrix product, the transposed convolution as an ordinary one, GroupNorm/FiLM/"
        "residual in place): equal to float32 rounding (see the mean V columns and the cycle "
        "table for whether the same candidates win). Steered samples per second of wall "
        "time (in brackets: per second of this process's CPU time, less sensitive to the other "
        f"jobs), median of {args.reps} interleaved calls; mean V of the kept samples (lower is "
        "better; V = completion s + 1.75 x spatial cost):",
        "",
        *speed,
        "",
        split,
        "",
        f"Against the target set for the fast network (5x the steered samples/s at M = 8 and "
        f"the policy's steps, same V): the fast network gives "
        f"{speedup[(8, 32, None)]:.2f}x at 256 rows per pass and "
        f"{speedup[(8, 4, None)]:.2f}x at 32; with fewer "
        f"reverse steps on top, {speedup[(8, 32, 6)]:.2f}x with 6 steps and "
        f"{speedup[(8, 32, 4)]:.2f}x with 4 at 256 rows. Whether V stays the same at fewer "
        "steps is what the next table measures (the t3-beside-t2 V above is one request type).",
        "",
        f"Mean V by reverse steps, fast network, over the {n_requests} requests the fetch "
        f"scheduler can make (each robot task alone and beside each human task), best of 4 "
        f"particles x 8 candidates, {args.seeds} seeds:",
        "",
        *steps,
        "",
    ]
    if args.cycles:
        cyc = cycle_table(policy, args.cycles, args.cycle_seeds)
        lines += [
            f"Fetch cycle (plan + execute + learn), default `RunConfig` (4 particles x 8 "
            f"candidates per request; one steering call of 8 requests per cycle), "
            f"{args.cycles} cycles x {args.cycle_seeds} seeds per variant (1-min load "
            f"average {load_average()} at the end):",
            "",
            *cyc,
            "",
        ]
    lines += [SHIPPED, ""]
    if args.train_steps:
        lines += [train_speed(args.train_steps), ""]
    lines += [f"Benchmark wall time {time.perf_counter() - t0:.0f} s.", ""]
    text = "\n".join(lines)
    print(text)
    if args.update_docs:
        update_docs_section(SECTION, text.split("\n", 1)[1])


if __name__ == "__main__":
    main()
