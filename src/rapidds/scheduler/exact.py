"""Exact baseline: minimum-makespan schedule on mean durations with OR-Tools CP-SAT.

This is what a user of a constraint-programming scheduler would run: deterministic durations
(the human's prior means and the robot's nominal durations), no proximity and no diversity. Time
is integer after scaling by ``scale`` (durations are rounded to 1/scale s); each task gets one
optional interval per allowed agent, exactly one of them present; the intervals of an agent do
not overlap; precedence is end_i <= start_j; the makespan is minimised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ortools.sat.python import cp_model

from rapidds.errors import ProblemError
from rapidds.problem import AGENTS, Agent, Problem
from rapidds.schedule import CompiledSchedule, Schedule


@dataclass(frozen=True)
class ExactResult:
    """A CP-SAT schedule.

    Attributes:
        schedule: per-agent sequences ordered by the solver's start times, no waits.
        makespan: makespan of ``schedule`` on the unrounded mean durations, seconds (tasks start
            as early as the sequences allow, so it is at most the solver's value).
        optimal: True when CP-SAT proved optimality (of the problem rounded to 1/scale s).
        status: CP-SAT status name ("OPTIMAL" or "FEASIBLE").
        bound: the solver's lower bound on the makespan, seconds (rounded problem).
    """

    schedule: Schedule
    makespan: float
    optimal: bool
    status: str
    bound: float


def solve_exact(
    problem: Problem,
    time_limit_s: float = 10.0,
    scale: int = 100,
    *,
    human_mean: np.ndarray | None = None,
    robot_durations: np.ndarray | None = None,
    workers: int = 1,
    load_bound: bool = False,
    deterministic_time: float | None = None,
) -> ExactResult:
    """Minimum-makespan schedule of ``problem`` on deterministic durations.

    Args:
        problem: the job; ``allowed`` and precedence are respected.
        time_limit_s: CP-SAT wall-time limit; the best solution so far is returned when it is
            reached (``optimal=False``).
        scale: time resolution, ticks per second.
        human_mean: (n,) human durations to use instead of the problem's prior means (e.g. the
            posterior means of a cycle); NaN/ignored where the human may not do the task.
        robot_durations: (n,) robot durations instead of the problem's.
        workers: CP-SAT search workers; 1 is deterministic and fastest on small instances.
        load_bound: add the redundant constraint that each agent's total work fits in the
            makespan. It lifts CP-SAT's lower bound from about the longest chain to the
            agents' loads: random 32-task instances are then proven optimal in 1-5 s instead
            of not in 20 s (bound 34 s against an optimum of 72 s). Off by default because
            among equally short schedules CP-SAT may then return another one (on the 4-task
            fetch job, another robot order in 3 of 200 draws of the means), and the loop's
            "exact" condition must keep its plans.
        deterministic_time: also stop after this much of CP-SAT's deterministic time (work
            units of about a second each, independent of the machine's load), so that a run
            cut short returns the same schedule every time; None = wall time only.

    Raises:
        ProblemError: no feasible schedule found within the time limit.
    """
    if scale < 1:
        raise ValueError(f"scale must be >= 1, got {scale}")
    if time_limit_s <= 0:
        raise ValueError(f"time_limit_s must be > 0, got {time_limit_s}")
    n = len(problem.tasks)
    dur: dict[Agent, np.ndarray] = {
        "human": _durations(problem, "human", human_mean),
        "robot": _durations(problem, "robot", robot_durations),
    }
    ticks = {a: {t.id: max(1, round(float(dur[a][k]) * scale))
                 for k, t in enumerate(problem.tasks) if t.can(a)} for a in AGENTS}
    model, start, present = _cp_model(problem, ticks, load_bound)

    solver = cp_model.CpSolver()
    solver.parameters.max_time_in_seconds = float(time_limit_s)
    solver.parameters.num_workers = int(workers)
    if deterministic_time is not None:
        solver.parameters.max_deterministic_time = float(deterministic_time)
    status = solver.solve(model)
    if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
        what = "is infeasible" if status == cp_model.INFEASIBLE else "was not solved"
        raise ProblemError(
            f"CP-SAT: problem '{problem.name}' {what} within {time_limit_s:g} s "
            f"(status {solver.status_name(status)})"
        )

    schedule = _schedule(problem, solver, start, present)
    compiled = CompiledSchedule.build(problem, schedule)
    if compiled is None:  # pragma: no cover - start-time order respects precedence
        raise ProblemError(f"CP-SAT: solution of '{problem.name}' deadlocks as a sequence")
    d = np.where(np.isnan(dur["human"]), dur["robot"], dur["human"]).reshape(1, n)
    real = float(compiled.simulate(compiled.durations(d, dur["robot"])).makespan[0])
    return ExactResult(
        schedule=schedule,
        makespan=real,
        optimal=status == cp_model.OPTIMAL,
        status=solver.status_name(status),
        bound=solver.best_objective_bound / scale,
    )


_Present = dict[Agent, dict[str, cp_model.IntVar]]


def _cp_model(problem: Problem, ticks: dict[Agent, dict[str, int]], load_bound: bool
              ) -> tuple[cp_model.CpModel, dict[str, cp_model.IntVar], _Present]:
    """The minimum-makespan model: each task on one agent that may do it, no overlap per agent,
    precedence; its start variables and each (agent, task)'s presence literal."""
    horizon = sum(max(ticks[a].get(t.id, 0) for a in AGENTS) for t in problem.tasks)

    model = cp_model.CpModel()
    start = {t.id: model.new_int_var(0, horizon, f"s_{t.id}") for t in problem.tasks}
    end = {t.id: model.new_int_var(0, horizon, f"e_{t.id}") for t in problem.tasks}
    present: dict[Agent, dict[str, cp_model.IntVar]] = {a: {} for a in AGENTS}
    intervals: dict[Agent, list[cp_model.IntervalVar]] = {a: [] for a in AGENTS}
    for t in problem.tasks:
        for a in AGENTS:
            if t.can(a):
                # Own start/end per alternative, tied to the task's when present (OR-Tools'
                # flexible job-shop formulation). Sharing the task's start/end between the
                # optional intervals is equivalent on paper, but CP-SAT 9.15 then reports
                # non-optimal makespans as OPTIMAL on a few percent of small instances.
                lit = model.new_bool_var(f"{a}_{t.id}")
                present[a][t.id] = lit
                a_start = model.new_int_var(0, horizon, f"s_{a}_{t.id}")
                a_end = model.new_int_var(0, horizon, f"e_{a}_{t.id}")
                intervals[a].append(model.new_optional_interval_var(
                    a_start, ticks[a][t.id], a_end, lit, f"i_{a}_{t.id}"
                ))
                model.add(start[t.id] == a_start).only_enforce_if(lit)
                model.add(end[t.id] == a_end).only_enforce_if(lit)
        model.add_exactly_one(present[a][t.id] for a in AGENTS if t.can(a))
    for a in AGENTS:
        model.add_no_overlap(intervals[a])
    for i, j in problem.precedence:
        model.add(end[i] <= start[j])
    makespan = model.new_int_var(0, horizon, "makespan")
    model.add_max_equality(makespan, list(end.values()))
    if load_bound:  # redundant: each agent's work fits in the makespan
        for a in AGENTS:
            model.add(sum(ticks[a][t] * lit for t, lit in present[a].items()) <= makespan)
    model.minimize(makespan)
    return model, start, present


def _schedule(problem: Problem, solver: cp_model.CpSolver, start: dict[str, cp_model.IntVar],
              present: _Present) -> Schedule:
    """The solved sequences: each task with the agent it was given to, by start time."""
    seqs: dict[Agent, list[str]] = {a: [] for a in AGENTS}
    for t in problem.tasks:
        agent = next(a for a in AGENTS if t.id in present[a] and solver.value(present[a][t.id]))
        seqs[agent].append(t.id)
    for a in AGENTS:
        seqs[a].sort(key=lambda tid: solver.value(start[tid]))
    return Schedule(tuple(seqs["human"]), tuple(seqs["robot"]))


def _durations(problem: Problem, agent: Agent, given: np.ndarray | None) -> np.ndarray:
    """(n,) durations of ``agent``, NaN where it may not do the task; checks ``given``."""
    n = len(problem.tasks)
    if given is None:
        vals = [
            (t.human_mean if agent == "human" else t.robot_duration) if t.can(agent) else None
            for t in problem.tasks
        ]
        return np.array([np.nan if v is None else float(v) for v in vals])
    arr = np.asarray(given, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"{agent} durations must have shape ({n},), got {arr.shape}")
    for k, t in enumerate(problem.tasks):
        if t.can(agent) and not (np.isfinite(arr[k]) and arr[k] > 0):
            raise ValueError(f"{agent} duration of '{t.id}' must be > 0, got {arr[k]}")
    return np.where([t.can(agent) for t in problem.tasks], arr, np.nan)
