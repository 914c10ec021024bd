"""Schedule evaluation with trajectory adaptation (paper Algorithm 2), for a whole population.

For each candidate: infeasible (deadlock) -> objective inf. Otherwise the overlap sets C_j come
from the expected timeline (mean human durations, current robot durations); the robot motion
for every (j, C_j) is looked up in the memory M (a :class:`TrajectoryCache`) or planned; the
new robot durations change the timeline, so C_j are recomputed, until they stop changing.

The loop runs synchronously over all candidates: each round gathers the (j, C_j) of every
candidate still iterating and asks the cache once, so a diffusion policy samples a generation's
new motions in one batch. The loop can oscillate (docs/design-notes.md item 2): it is capped at
``max_overlap_iters`` rounds, stops when an overlap state repeats, and then keeps the best
evaluated variant with ``converged=False``.

Every candidate's makespan is averaged over the same K human samples (common random numbers).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from rapidds.motion.interface import MotionKey, MotionPlan, TrajectoryCache
from rapidds.problem import Problem
from rapidds.schedule import Schedule, ScheduleBatch, Wait, validate
from rapidds.scheduler.diversity import AllocationHistory, diversity_term

OverlapState = tuple[frozenset[str], ...]


@dataclass(frozen=True, eq=False)
class Evaluation:
    """Cost of one candidate schedule and the robot motions chosen for it.

    Attributes:
        schedule: the candidate.
        feasible: False when the schedule deadlocks; then ``objective`` and ``makespan_mean``
            are inf, ``makespan_std`` and ``spatial`` are nan, ``makespan`` is empty and
            ``motions``/``overlaps`` are empty.
        objective: z = z_t + gamma z_s + lam z_d.
        makespan_mean: z_t, mean makespan over the K human samples.
        makespan_std: standard deviation of the makespan over the K samples.
        makespan: (K,) makespan per human sample.
        spatial: z_s, sum over robot tasks of ``MotionPlan.spatial_cost``.
        diversity: z_d, allocation diversity (the same for every schedule without history).
        motions: robot task -> the plan used for it.
        overlaps: robot task -> C_j on the expected timeline under the chosen motions. Equal to
            each motion's ``concurrent`` set when ``converged``.
        converged: False when the overlap loop hit its cap or oscillated; the evaluation is then
            the best variant the loop evaluated.
        overlap_iterations: rounds of the overlap loop (each round plans or looks up motions).
        expected_start, expected_finish: (n,) start and finish of every task, problem order, on
            the expected timeline (mean human durations, chosen robot motions); empty when
            infeasible.
    """

    schedule: Schedule
    feasible: bool
    objective: float
    makespan_mean: float
    makespan_std: float
    makespan: np.ndarray
    spatial: float
    diversity: float
    motions: dict[str, MotionPlan] = field(default_factory=dict)
    overlaps: dict[str, frozenset[str]] = field(default_factory=dict)
    converged: bool = True
    overlap_iterations: int = 0
    expected_start: np.ndarray = field(default_factory=lambda: np.empty(0))
    expected_finish: np.ndarray = field(default_factory=lambda: np.empty(0))


@dataclass(frozen=True)
class _Pass:
    """One timeline pass: (K,) makespans, the expected timeline's (n,) start and finish,
    and its C_j."""

    makespan: np.ndarray
    start: np.ndarray
    finish: np.ndarray
    state: OverlapState


@dataclass
class _Variant:
    objective: float
    spatial: float
    plans: list[MotionPlan]
    timing: _Pass  # its ``state`` is the overlap set under these motions


@dataclass
class _Candidate:
    schedule: Schedule
    robot_tasks: tuple[str, ...]
    robot_cols: np.ndarray  # (r,) problem columns of the robot's tasks, in its order
    human_cols: np.ndarray  # (h,) problem columns of the human's tasks, in its order
    z_d: float
    state: OverlapState = ()
    state_durations: np.ndarray = field(default_factory=lambda: np.empty(0))
    state_pass: _Pass | None = None  # the timeline pass under ``state_durations``
    seen: list[OverlapState] = field(default_factory=list)
    variants: list[_Variant] = field(default_factory=list)


def _check_valid(problem: Problem, schedule: Schedule, allowed: dict[str, frozenset[str]],
                 may: tuple[frozenset[str], frozenset[str]]) -> None:
    """ValueError unless ``schedule`` holds every task once on an allowed agent (``may``: the
    tasks each agent may do) and waits only on known tasks. Set operations, not a loop over
    items: the GA checks every one of its tens of thousands of candidates."""
    h, r = schedule.tasks("human"), schedule.tasks("robot")
    ok = (len(h) + len(r) == len(allowed) and may[0].issuperset(h) and may[1].issuperset(r)
          and len(set(h).union(r)) == len(allowed))
    if ok and len(h) + len(r) < len(schedule.human) + len(schedule.robot):  # it has waits
        ok = all(x.task in allowed for x in (*schedule.human, *schedule.robot)
                 if isinstance(x, Wait))
    if not ok:
        validate(problem, schedule)  # raises with a message naming what is wrong
        raise ValueError(f"invalid schedule {schedule}")  # pragma: no cover - validate raised


# Candidates simulated at once: bounds the (B, n, K+1) arrays of a batch to about 4 MiB each
# (and the (B, n, n) overlap tests); larger batches only page-fault more.
_CHUNK_FLOATS = 2**19


def _passes(
    problem: Problem,
    schedules: Sequence[Schedule],
    rows: np.ndarray,
    robot: np.ndarray,
    ids: tuple[str, ...],
) -> list[_Pass | None]:
    """One timeline pass per schedule over the K samples plus the expected row (last row of
    ``rows``, shape (K+1, n)) with robot durations ``robot`` (B, n); None where it deadlocks.
    C_j follow the rule of :meth:`Timeline.overlaps`, for the whole batch at once."""
    n = len(problem.tasks)
    size = max(1, _CHUNK_FLOATS // (rows.shape[0] * (n + 1)))
    out: list[_Pass | None] = []
    for lo in range(0, len(schedules), size):
        batch = ScheduleBatch(problem, schedules[lo : lo + size])
        start, finish, feasible = batch.simulate(batch.durations(rows, robot[lo : lo + size]))
        makespans = finish.max(axis=1)  # (B, K+1)
        s, f = start[:, :, -1], finish[:, :, -1]  # (B, n) expected timeline
        human = batch.human
        # robot task j and human task i overlap with positive length (Timeline.overlaps)
        hit = (np.maximum(s[:, :, None], s[:, None, :])
               < np.minimum(f[:, :, None], f[:, None, :]) - 1e-9)
        hit &= ~human[:, :, None] & human[:, None, :] & feasible[:, None, None]
        groups: dict[tuple[int, int], list[str]] = {}
        for b, j, i in zip(*(a.tolist() for a in np.nonzero(hit)), strict=True):
            groups.setdefault((b, j), []).append(ids[i])
        for b in range(len(batch)):
            if not feasible[b]:
                out.append(None)
                continue
            robot_cols = batch.seqs[2 * b + 1, : batch.lengths[2 * b + 1]].tolist()
            state = tuple(frozenset(groups[b, j]) if (b, j) in groups else _EMPTY
                          for j in robot_cols)
            out.append(_Pass(makespans[b, :-1].copy(), s[b].copy(), f[b].copy(), state))
    return out


_EMPTY: frozenset[str] = frozenset()


def _infeasible(schedule: Schedule, z_d: float) -> Evaluation:
    return Evaluation(
        schedule=schedule,
        feasible=False,
        objective=math.inf,
        makespan_mean=math.inf,
        makespan_std=math.nan,
        makespan=np.empty(0),
        spatial=math.nan,
        diversity=z_d,
        converged=True,
        overlap_iterations=0,
    )


@dataclass(frozen=True, eq=False)
class EvaluationContext:
    """What every schedule of one evaluation is scored against: the job, the human durations,
    the memory M and the objective's weights (one value, so the GA's evaluator, the CLI and
    the benchmarks pass the same thing).

    Attributes:
        problem: the job.
        human_samples: (K, n) human durations in problem task order, shared by all candidates.
        human_mean: (n,) expected human durations, for the expected timeline that defines C_j.
        cache: memory M; new (j, C_j) are planned in one batch per round.
        d_init: (n,) initial robot durations (d_init of Algorithm 2); may be NaN where the robot
            cannot do the task.
        gamma, lam: weights of z_s and z_d.
        history: past allocations for z_d (None = no history).
        max_overlap_iters: cap on the overlap loop's rounds (>= 1).
    """

    problem: Problem
    human_samples: np.ndarray
    human_mean: np.ndarray
    cache: TrajectoryCache
    d_init: np.ndarray
    gamma: float
    lam: float
    history: AllocationHistory | None = None
    max_overlap_iters: int = 8


def evaluate_population(context: EvaluationContext, schedules: Sequence[Schedule]
                        ) -> list[Evaluation]:
    """Evaluate every schedule (Algorithm 2) against ``context``, one :class:`Evaluation` per
    schedule, in order.

    ``schedules``: candidates; each must hold every task once on an allowed agent (ValueError
    otherwise). Deadlocking candidates are fine: they get inf.
    """
    problem, history, max_overlap_iters = (context.problem, context.history,
                                           context.max_overlap_iters)
    d_init = context.d_init
    rows = _rows(problem, context.human_samples, context.human_mean, d_init, max_overlap_iters)
    d0 = np.asarray(d_init, dtype=float)
    results: list[Evaluation | None] = [None] * len(schedules)
    active = _first_pass(problem, schedules, rows, d0, diversity_term(problem, history), results)
    rounds = 0
    while active:
        rounds += 1
        active = _overlap_round(context, active, rows, d0, results,
                                final=rounds >= max_overlap_iters, rounds=rounds)
    return [r for r in results if r is not None]


def _rows(problem: Problem, human_samples: np.ndarray, human_mean: np.ndarray,
          d_init: np.ndarray, max_overlap_iters: int) -> np.ndarray:
    """The (K+1, n) human durations to simulate: the samples and then the expected row (the
    expected timeline rides along); ValueError on shapes or values that cannot be used."""
    n = len(problem.tasks)
    samples = np.atleast_2d(np.asarray(human_samples, dtype=float))
    mean = np.asarray(human_mean, dtype=float)
    d0 = np.asarray(d_init, dtype=float)
    if samples.ndim != 2 or samples.shape[1] != n:
        raise ValueError(f"human_samples must have shape (K, {n}), got {samples.shape}")
    if mean.shape != (n,) or d0.shape != (n,):
        raise ValueError(
            f"human_mean and d_init must have shape ({n},), got {mean.shape} and {d0.shape}"
        )
    if max_overlap_iters < 1:
        raise ValueError(f"max_overlap_iters must be >= 1, got {max_overlap_iters}")
    human_cols = [k for k, t in enumerate(problem.tasks) if t.can("human")]
    if not (np.isfinite(samples[:, human_cols]).all() and np.isfinite(mean[human_cols]).all()):
        raise ValueError("human_samples and human_mean must be finite where the human may work")
    return np.vstack([samples, mean])


def _first_pass(
    problem: Problem,
    schedules: Sequence[Schedule],
    rows: np.ndarray,
    d0: np.ndarray,
    z_d_of: Callable[[Schedule], float],
    results: list[Evaluation | None],
) -> list[tuple[int, _Candidate]]:
    """Validates every schedule and simulates it with the initial robot durations ``d0``:
    deadlocking ones get their (infeasible) result, the others come back as candidates for the
    overlap loop, with their position in ``results``."""
    n = len(problem.tasks)
    allowed = {t.id: frozenset(t.allowed) for t in problem.tasks}
    ids = problem.ids
    col = problem.index.__getitem__
    may = (frozenset(t.id for t in problem.tasks if t.can("human")),
           frozenset(t.id for t in problem.tasks if t.can("robot")))
    candidates: list[_Candidate] = []
    for schedule in schedules:
        _check_valid(problem, schedule, allowed, may)
        robot_tasks = schedule.tasks("robot")
        human_tasks = schedule.tasks("human")
        rc = np.fromiter(map(col, robot_tasks), dtype=np.intp, count=len(robot_tasks))
        hc = np.fromiter(map(col, human_tasks), dtype=np.intp, count=len(human_tasks))
        candidates.append(_Candidate(schedule, robot_tasks, rc, hc, z_d_of(schedule)))
    first = _passes(problem, schedules, rows, np.broadcast_to(d0, (len(schedules), n)), ids)
    active: list[tuple[int, _Candidate]] = []
    for pos, (cand, timing) in enumerate(zip(candidates, first, strict=True)):
        if timing is None:
            results[pos] = _infeasible(cand.schedule, cand.z_d)
            continue
        rc = cand.robot_cols
        if not np.all(np.isfinite(d0[rc])):
            bad = [ids[c] for c in rc[~np.isfinite(d0[rc])]]
            raise ValueError(f"d_init has no finite robot duration for robot tasks {bad}")
        cand.state, cand.state_durations, cand.state_pass = (
            timing.state, d0[cand.robot_cols], timing)
        active.append((pos, cand))
    return active


def _overlap_round(
    context: EvaluationContext,
    active: list[tuple[int, _Candidate]],
    rows: np.ndarray,
    d0: np.ndarray,
    results: list[Evaluation | None],
    *,
    final: bool,
    rounds: int,
) -> list[tuple[int, _Candidate]]:
    """One round of Algorithm 2's overlap loop for every unconverged candidate: motions for
    its (j, C_j) in one batch, a new timeline where its robot durations changed, and then its
    result (converged, cycling or ``final``) or its next overlap state. Returns those still
    unconverged."""
    problem, cache, gamma, lam = context.problem, context.cache, context.gamma, context.lam
    n = len(problem.tasks)
    keys: list[MotionKey] = [
        (j, cj) for _, c in active for j, cj in zip(c.robot_tasks, c.state, strict=True)
    ]
    plans = cache.get_many(keys)
    owns: list[list[MotionPlan]] = []
    durations: list[np.ndarray] = []
    changed: list[int] = []  # candidates whose robot durations changed: simulate again
    offset = 0
    for k, (_, c) in enumerate(active):
        m = len(c.robot_tasks)
        own = plans[offset : offset + m]
        offset += m
        rdur = np.array([p.duration + p.hold for p in own], dtype=float)  # hold: 0 open loop
        owns.append(own)
        durations.append(rdur)
        if not np.array_equal(rdur, c.state_durations):
            changed.append(k)
    robot = np.empty((len(changed), n))
    for row, k in enumerate(changed):
        robot[row] = d0
        robot[row, active[k][1].robot_cols] = durations[k]
    again = dict(zip(changed, _passes(problem, [active[k][1].schedule for k in changed],
                                      rows, robot, problem.ids), strict=True))
    still: list[tuple[int, _Candidate]] = []
    for k, (pos, c) in enumerate(active):
        own, rdur = owns[k], durations[k]
        # C_j depend only on the schedule and the durations: unchanged ones keep the pass
        timing = again.get(k, c.state_pass)
        assert timing is not None  # the same schedule cannot deadlock under new durations
        next_state = timing.state
        z_s = float(sum(p.spatial_cost for p in own))
        objective = float(timing.makespan.mean()) + gamma * z_s + lam * c.z_d
        c.variants.append(_Variant(objective, z_s, own, timing))
        if next_state == c.state:
            results[pos] = _finish(c, c.variants[-1], converged=True, rounds=rounds)
        elif next_state in c.seen or final:
            best = min(c.variants, key=lambda v: v.objective)
            results[pos] = _finish(c, best, converged=False, rounds=rounds)
        else:
            c.seen.append(c.state)
            c.state, c.state_durations, c.state_pass = next_state, rdur, timing
            still.append((pos, c))
    return still


def _finish(c: _Candidate, v: _Variant, *, converged: bool, rounds: int) -> Evaluation:
    makespan = v.timing.makespan
    mean = float(makespan.mean())
    spread = makespan - mean
    return Evaluation(
        schedule=c.schedule,
        feasible=True,
        objective=v.objective,
        makespan_mean=mean,
        makespan_std=math.sqrt(float(spread @ spread) / len(makespan)),
        makespan=makespan,
        spatial=v.spatial,
        diversity=c.z_d,
        motions={p.task: p for p in v.plans},
        overlaps=dict(zip(c.robot_tasks, v.timing.state, strict=True)),
        converged=converged,
        overlap_iterations=rounds,
        expected_start=v.timing.start,
        expected_finish=v.timing.finish,
    )
