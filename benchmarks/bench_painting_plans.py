"""The paper's painting behaviours in plans made by the library's planner with the bundled
policy: genetic scheduler + SVDD-steered diffusion motions, as one cycle of the loop plans.

    .venv/bin/python benchmarks/bench_painting_plans.py [--seeds 0,1,2] [--cycles 6]

For each seed and each of the paper's settings (unconstrained gamma 12, 25, 85; constrained
gamma 12) it plans once with the population prior and once with a left-handed person's model
after ``--cycles`` observed cycles, and tests the plan against the behaviour the paper
describes (:func:`rapidds.worlds.painting.calibration.behaviours`). The loop's search settings
(population 24, 40 generations, patience 8, 32 duration samples, 4 particles x 8 candidates).
This plans; it deploys nothing and learns nothing in between.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import statistics
import time

import numpy as np
import torch
from _common import cpu_model, load_average

from rapidds.human.temporal import TemporalModel
from rapidds.motion.diffusion_motion import DiffusionMotion, SteeringConfig
from rapidds.motion.policy import DiffusionPolicy
from rapidds.scheduler import GAConfig, GeneticScheduler
from rapidds.worlds.painting import PaintingWorld
from rapidds.worlds.painting.calibration import behaviours, prior_model, summarize


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--cycles", type=int, default=6)
    args = ap.parse_args()
    torch.set_num_threads(1)
    load0 = load_average()
    world = PaintingWorld()
    path = world.bundled_policy()
    if path is None:
        raise SystemExit("no bundled painting policy")
    policy = DiffusionPolicy.load(path)
    prior = prior_model(world)
    learned = copy.deepcopy(prior)
    rng = np.random.default_rng(11)
    person = world.teammate("left-fast")
    for _ in range(args.cycles):
        for task in ("prep_vise", "secure_piece"):
            learned.observe(task, person.perform(task, rng)[1])
    models = {"prior": prior, "learned": learned}
    results: dict[str, list[bool]] = {}
    seconds = []
    for seed in (int(s) for s in args.seeds.split(",")):
        for spec in behaviours():
            w = dataclasses.replace(world, variant=spec.variant)
            problem = w.problem().with_objective(gamma=spec.gamma, lam=0.0)
            temporal = TemporalModel.from_population(problem, w.prior().durations)
            r = np.random.default_rng(seed)
            samples, mean = temporal.sample(32, r), temporal.mean()
            model = models[spec.belief]

            def cost(ids, xi, model=model, w=w):
                xi = np.asarray(xi)
                return model.cost(list(ids), w.robot_points(xi).reshape(xi.shape[0], -1, 3))

            motion = DiffusionMotion(policy, w.completion_time, cost, spec.gamma,
                                     SteeringConfig(particles=4, candidates=8, seed=seed))
            ga = GeneticScheduler(problem, motion, GAConfig(
                population=24, generations=40, samples=32, patience=8, polish_allocations=1,
                order_search_nodes=0, seed=seed))
            t0 = time.perf_counter()
            best = ga.solve(samples, mean, gamma=spec.gamma, lam=0.0).best
            seconds.append(time.perf_counter() - t0)
            plan = summarize(problem, best,
                             lambda t, p, w=w: w.motion_label(t, p.trajectory))
            ok = spec.test(plan)
            results.setdefault(f"{spec.setting}, {spec.belief}: {spec.name}", []).append(ok)
            print(f"seed {seed} {spec.setting} {spec.belief}: {'yes' if ok else 'NO '} {plan}",
                  flush=True)
    load1 = load_average()
    print(f"\n{cpu_model()}, 1-min load average {load0} at start, {load1} at end; planning "
          f"took median {statistics.median(seconds):.1f} s, max {max(seconds):.1f} s")
    print("\n| setting, belief: behaviour | plans that show it |\n|---|---|")
    for k, v in results.items():
        print(f"| {k} | {sum(v)} of {len(v)} |")


if __name__ == "__main__":
    main()
