"""Plan quality under uncertainty: the GA's plans against the true expected-makespan optimum.

    .venv/bin/python benchmarks/bench_plan_quality.py [--base /tmp/old-checkout] [--docs]

Ten small stochastic jobs (5-7 tasks, ``bench_scheduler.random_instance`` with human std 30 %
of the mean), each planned as ``rapidds plan JOB --sampling plugin --seed S`` plans it (default
GA, K = 64 samples from the plug-in belief N(E[mu], E[sigma^2]), fixed robot durations), then
scored on 20,000 fresh samples of that same belief. The optimum is found by enumerating every
allocation and every order of both agents' tasks (orders that put a task before its own
predecessor on one agent are skipped: they deadlock) with the library's batched timeline
(:class:`rapidds.schedule.ScheduleBatch`), every schedule on all 20,000 samples (common random
numbers; the GA's schedule is also scored by its own evaluation, which must agree).
Gap = (GA's expected makespan - optimum) / optimum, both on the 20,000 samples: a speed-up
that trades quality away shows here. With ``--base`` the GA of an older checkout plans the
same jobs (a subprocess with its ``src`` on the path), interleaved job by job.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from _common import cpu_model, load_average, update_docs_section
from bench_scheduler import random_instance

from rapidds.problem import Problem
from rapidds.schedule import Schedule, ScheduleBatch

ROOT = Path(__file__).resolve().parents[1]
SIZES = (5, 5, 5, 6, 6, 6, 6, 7, 7, 7)
STD = 0.3
TRUTH_SAMPLES = 20_000
SECTION = "## Plan quality under uncertainty"
NOTE = ("A gap of 0 on its 64 samples means the search found the best plan for the samples it "
        "was given; what remains of the gap on 20,000 samples is the price of planning on "
        "K = 64 samples, which no speed-up of the search changes.")


def instance(i: int) -> Problem:
    return random_instance(np.random.default_rng(1000 + i), SIZES[i], std_frac=STD)


def plan_worker(i: int) -> None:
    """The GA's plan of job ``i`` with the rapidds on the path, as JSON on stdout."""
    from rapidds.cli.plan import sample_durations
    from rapidds.motion.interface import FixedDurationMotion
    from rapidds.scheduler import GAConfig, GeneticScheduler

    problem = instance(i)
    config = GAConfig(seed=i)
    samples, mean = sample_durations(problem, i, config.samples, "plugin")
    t0 = time.process_time()
    result = GeneticScheduler(problem, FixedDurationMotion(problem), config).solve(samples, mean)
    print(json.dumps({"schedule": result.best.schedule.to_json(),
                      "cpu": time.process_time() - t0, "evaluations": result.evaluations}))


def truth_samples(problem: Problem, i: int) -> np.ndarray:
    """(TRUTH_SAMPLES, n) human durations from the plug-in belief, a stream the plan never saw."""
    from rapidds.human.temporal import TemporalModel

    model = TemporalModel.from_problem(problem, sampling="plugin")
    return model.sample(TRUTH_SAMPLES, np.random.default_rng([i, 4242]))


def expected_makespans(problem: Problem, schedules: list[Schedule], human: np.ndarray,
                       chunk: int = 16) -> np.ndarray:
    """Mean makespan of each schedule over the rows of ``human`` (R, n); inf if it deadlocks."""
    robot = np.array([np.nan if t.robot_duration is None else t.robot_duration
                      for t in problem.tasks])
    robot = np.nan_to_num(robot, nan=0.0)  # only where the robot cannot work: never read
    out = np.empty(len(schedules))
    for s in range(0, len(schedules), chunk):
        batch = ScheduleBatch(problem, schedules[s:s + chunk])
        _, finish, feasible = batch.simulate(batch.durations(human, robot))
        out[s:s + chunk] = np.where(feasible, finish.max(axis=1).mean(axis=1), np.inf)
    return out


def library_makespan(problem: Problem, schedule: Schedule, human: np.ndarray) -> float:
    """Expected makespan of ``schedule`` as the GA's own evaluation computes it (Algorithm 2,
    waits included), checked against :func:`expected_makespans`, the enumeration's."""
    from rapidds.motion.interface import FixedDurationMotion, TrajectoryCache
    from rapidds.scheduler import EvaluationContext, evaluate_population

    motion = FixedDurationMotion(problem)
    mean = human.mean(axis=0)
    got = evaluate_population(EvaluationContext(problem, human, mean, TrajectoryCache(motion),
                                                motion.nominal_durations(problem), 0.0, 0.0),
                              [schedule])[0].makespan_mean
    mine = float(expected_makespans(problem, [schedule], human)[0])
    assert abs(got - mine) <= 1e-9 * max(1.0, mine), (got, mine)
    return float(got)


def every_schedule(problem: Problem) -> list[Schedule]:
    """Every allocation to allowed agents and every order on each agent that keeps each task
    after its own predecessors on that agent."""
    ids = problem.ids
    choices = [sorted(t.allowed) for t in problem.tasks]
    pred = {t: set(problem.preceding[t]) for t in ids}

    def orders(tasks: list[str]) -> list[tuple[str, ...]]:
        return [p for p in itertools.permutations(tasks)
                if not any(pred[p[a]] & set(p[a + 1:]) for a in range(len(p)))]

    out = []
    for agents in itertools.product(*choices):
        human = [t for t, a in zip(ids, agents, strict=True) if a == "human"]
        robot = [t for t, a in zip(ids, agents, strict=True) if a == "robot"]
        for h in orders(human):
            for r in orders(robot):
                out.append(Schedule(h, r))
    return out


def optimum(problem: Problem, human: np.ndarray) -> tuple[float, int]:
    """(expected-makespan optimum on ``human``, schedules enumerated)."""
    schedules = every_schedule(problem)
    return float(expected_makespans(problem, schedules, human).min()), len(schedules)


def search_gap(problem: Problem, i: int, schedule: Schedule) -> float:
    """Gap of ``schedule`` to the optimum on the GA's own 64 samples: what the search left, as
    against what planning on 64 samples instead of the distribution costs."""
    from rapidds.cli.plan import sample_durations

    own, _ = sample_durations(problem, i, 64, "plugin")
    best, _ = optimum(problem, own)
    return (float(expected_makespans(problem, [schedule], own)[0]) - best) / best


def run_plan(src: Path, i: int) -> dict:
    env = {**os.environ, "PYTHONPATH": f"{src}{os.pathsep}{Path(__file__).parent}"}
    got = subprocess.run([sys.executable, __file__, "--worker", str(i)], env=env, check=True,
                         capture_output=True, text=True)
    return json.loads(got.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, help="an older checkout to plan beside this one")
    ap.add_argument("--docs", action="store_true")
    ap.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker is not None:
        plan_worker(args.worker)
        return
    trees = {"this tree": ROOT / "src"}
    if args.base is not None:
        trees = {"base": args.base.resolve() / "src", **trees}
    load0 = load_average()
    gaps: dict[str, list[float]] = {name: [] for name in trees}
    cpu: dict[str, list[float]] = {name: [] for name in trees}
    lines = []
    for i, n in enumerate(SIZES):
        problem = instance(i)
        human = truth_samples(problem, i)
        best, count = optimum(problem, human)
        cells = []
        for name, src in trees.items():
            got = run_plan(src, i)
            schedule = Schedule.from_json(got["schedule"])
            ga = library_makespan(problem, schedule, human)
            gaps[name].append((ga - best) / best)
            cpu[name].append(float(got["cpu"]))
            cells.append(f"{100 * gaps[name][-1]:.3f} % | "
                         f"{100 * search_gap(problem, i, schedule):.3f} % | {got['cpu']:.2f}")
        lines.append(f"| {i} | {n} | {count} | {best:.3f} | " + " | ".join(cells) + " |\n")
        print(lines[-1], end="", flush=True)
    head = "| job | tasks | schedules enumerated | optimum E[makespan] | " + " | ".join(
        f"gap {name} | gap on its 64 samples {name} | GA CPU s {name}" for name in trees) + " |\n"
    head += "|---:|---:|---:|---:|" + "---:|---:|---:|" * len(trees) + "\n"
    summary = "".join(
        f"- {name}: mean gap {100 * statistics.mean(g):.3f} %, worst {100 * max(g):.3f} %, "
        f"{sum(x <= 1e-12 for x in g)} of {len(g)} at the optimum; GA CPU median "
        f"{statistics.median(cpu[name]):.2f} s\n" for name, g in gaps.items())
    text = ("`benchmarks/bench_plan_quality.py"
            + (f" --base {args.base}`" if args.base else "`")
            + f": {len(SIZES)} jobs of 5-7 tasks, human std {STD:.0%} of the mean, plug-in "
            f"sampling, default GA (K = 64), scored on {TRUTH_SAMPLES:,} fresh samples; optimum "
            f"by enumeration on the same samples. "
            f"{cpu_model()}, 2 cores shared with other jobs; 1-min load average {load0} at "
            f"start, {load_average()} at end (gaps do not depend on load).\n\n"
            + head + "".join(lines) + "\n" + summary + "\n" + NOTE)
    print(text)
    if args.docs:
        update_docs_section(SECTION, text)


if __name__ == "__main__":
    main()
