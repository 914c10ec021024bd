"""What the paper's closed-form replay saves over stepping the executor's clock (issue 32).

An undisturbed cycle under an execution entry that neither monitors nor re-plans (``planned``)
is the schedule replayed on the durations taken (``loop.deploy.deploy``); the clock-driven
executor gives the same times and costs. This times both on the same planned cycles (CPU
seconds of this process, and wall), and checks they agree.

    PYTHONPATH=src python benchmarks/bench_replay.py [--worlds fetch,painting] [--repeats 20]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

SMALL = dict(population=8, generations=3, samples=8, patience=2, particles=2, candidates=4)


def main() -> None:
    from rapidds.execution import PlannedRobot, SimulatedHuman
    from rapidds.loop import AdaptiveRun, RunConfig
    from rapidds.loop.deploy import deploy
    from rapidds.loop.execute import CycleSetup, cycle_executor
    from rapidds.loop.run import load_policy
    from rapidds.worlds.registry import make_world

    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", default="fetch,painting")
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    for name in args.worlds.split(","):
        world = make_world(name)
        run = AdaptiveRun(RunConfig(world=name, cycles=1, seed=0, **SMALL), load_policy(world))
        plan = run.plan()
        human = run.teammate.execute(0, plan.best.schedule.tasks("human"), plan.rng)
        beliefs = (run.model.temporal.mean(), run.model.temporal.std())
        beta = run.model.spatial.config.beta
        sched, motions = plan.best.schedule, plan.best.motions
        out = {}
        for way in ("executor", "replay"):
            cpu, wall = time.process_time(), time.perf_counter()
            for _ in range(args.repeats):
                if way == "replay":
                    dep = deploy(run.world, run.problem, sched, motions, human, beta=beta)
                else:
                    person = SimulatedHuman(run.world, human, None)
                    ex = cycle_executor(CycleSetup(run.world, run.problem, run.config, 0,
                                                   plan.gamma, sched, motions, beliefs,
                                                   run.model.spatial, beta), person)
                    assert isinstance(ex.robot, PlannedRobot)
                    dep = ex.run()
            out[way] = {"cpu_ms": 1e3 * (time.process_time() - cpu) / args.repeats,
                        "wall_ms": 1e3 * (time.perf_counter() - wall) / args.repeats,
                        "cost": dep.cost, "finish": dep.timeline.finish}
        same = (out["executor"]["cost"] == out["replay"]["cost"]
                and np.array_equal(out["executor"]["finish"], out["replay"]["finish"]))
        print(json.dumps({"world": name, "same": bool(same), "load": os.getloadavg()[0],
                          **{w: {k: round(v, 2) for k, v in o.items() if k.endswith("_ms")}
                             for w, o in out.items()}}), flush=True)


if __name__ == "__main__":
    main()
