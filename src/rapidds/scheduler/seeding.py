"""The GA's first populations: randomised earliest-deadline-first list scheduling (the paper's
"EDF"; always feasible), the caller's schedules and, on mid-size jobs with fixed robot
durations, CP-SAT's schedule on the expected durations."""

from __future__ import annotations

import math
import random
from collections.abc import Sequence

import numpy as np

from rapidds.errors import RapiddsError
from rapidds.motion.interface import FixedDurationMotion, MotionModel
from rapidds.problem import AGENTS, Agent
from rapidds.schedule import Item, Schedule, repair, validate
from rapidds.scheduler.active import longest_tails
from rapidds.scheduler.config import GAConfig
from rapidds.scheduler.operators import Operators


def seeds(ops: Operators, motion: MotionModel, config: GAConfig, initial: Sequence[Schedule],
          mean: np.ndarray, d_init: np.ndarray) -> list[Schedule]:
    """The caller's ``initial`` schedules (validated, repaired, distinct) and, with
    ``exact_seed_work``, fixed robot durations and a job of ``exact_seed_min_tasks`` to
    ``exact_seed_tasks`` tasks, CP-SAT's schedule on the expected durations; at most a
    population's worth."""
    problem = ops.problem
    out: dict[Schedule, None] = {}
    for s in initial:
        validate(problem, s)
        out[repair(s)] = None
    cfg = config
    if (cfg.exact_seed_work > 0
            and cfg.exact_seed_min_tasks <= len(problem.tasks) <= cfg.exact_seed_tasks
            and isinstance(motion, FixedDurationMotion)):
        from rapidds.scheduler.exact import solve_exact  # OR-Tools: 0.5 s to import

        human = np.where([t.can("human") for t in problem.tasks], mean, np.nan)
        try:  # a deterministic budget, so the seed does not depend on the machine's load;
            # the wall-time limit only guards against a stalled solver
            exact = solve_exact(problem, time_limit_s=60.0 + 20 * cfg.exact_seed_work,
                                human_mean=human, robot_durations=d_init, load_bound=True,
                                deterministic_time=cfg.exact_seed_work)
        except (RapiddsError, ValueError):  # nothing found in time, or unusable durations
            pass
        else:
            out[exact.schedule] = None
    return list(out)[: cfg.population]


def initial_population(ops: Operators, size: int, rng: random.Random, mean: np.ndarray,
                       d_init: np.ndarray, given: Sequence[Schedule] = ()) -> list[Schedule]:
    """``given`` and then distinct list schedules, ``size`` in all (fewer only if the problem
    has fewer distinct ones)."""
    out: dict[Schedule, None] = dict.fromkeys(given)
    misses = 0
    while len(out) < size and misses < size:
        schedule = list_schedule(ops, rng, mean, d_init)
        misses = misses + 1 if schedule in out else 0
        out[schedule] = None
    pool = list(out)
    misses = 0
    while len(out) < size and misses < size:  # tiny problems: top up with mutants
        child = ops.mutate(rng.choice(pool), rng)
        misses = misses + 1 if child is None or child in out else 0
        if child is not None:
            out[child] = None
    return list(out)


def list_schedule(ops: Operators, rng: random.Random, mean: np.ndarray, d_init: np.ndarray
                  ) -> Schedule:
    """Randomised earliest-deadline-first list scheduling: always feasible.

    Repeatedly takes a ready task (all predecessors placed) and appends it to an agent. The
    task is the one with the earliest deadline, i.e. the longest remaining critical path
    (shortest-agent expected durations), after perturbing each key by uniform noise; the
    agent is the one that would finish the task first, or with some probability a random
    allowed one. The noise level and the greediness are drawn per schedule, so a population
    spans pure EDF/earliest-finish schedules and nearly random ones.
    """
    problem, index, allowed = ops.problem, ops.index, ops.allowed
    durations = {
        t: {
            "human": float(mean[index[t]]) if "human" in allowed[t] else math.inf,
            "robot": float(d_init[index[t]]) if "robot" in allowed[t] else math.inf,
        }
        for t in problem.ids
    }
    # longest path from each task's start to the end of the job (its deadline slack counted
    # backwards), with each task at its faster agent's duration
    tail = longest_tails(problem.ids, problem.following,
                         {t: min(d.values()) for t, d in durations.items()})
    spread = max(tail.values())
    noise = rng.random() * spread
    greedy = rng.random()
    pending = {t: len(problem.preceding[t]) for t in problem.ids}
    ready = [t for t in problem.ids if pending[t] == 0]
    free = {"human": 0.0, "robot": 0.0}
    finish: dict[str, float] = {}
    seqs: dict[Agent, list[Item]] = {"human": [], "robot": []}
    while ready:
        keys = [tail[t] + noise * rng.random() for t in ready]
        task = ready.pop(keys.index(max(keys)))
        agents = [a for a in AGENTS if a in allowed[task]]
        gate = max((finish[p] for p in problem.preceding[task]), default=0.0)
        ends = {a: max(free[a], gate) + durations[task][a] for a in agents}
        if len(agents) == 2 and rng.random() < greedy:
            low = min(ends.values())
            agent = rng.choice([a for a in agents if ends[a] == low])
        else:
            agent = rng.choice(agents)
        finish[task] = free[agent] = ends[agent]
        seqs[agent].append(task)
        for nxt in problem.following[task]:
            pending[nxt] -= 1
            if pending[nxt] == 0:
                ready.append(nxt)
    return Schedule(tuple(seqs["human"]), tuple(seqs["robot"]))
