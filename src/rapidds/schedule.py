"""Schedules: one sequence per agent of task ids and wait tokens, and their timelines.

Semantics under given durations (docs/design-notes.md item 16): an agent starts its next item
when it is free, every precedence predecessor of that task has finished, and, for a wait token
``w_i``, task ``i`` has finished. A wait takes no time. Precedence is ``finish_i <= start_j``
(the paper's strict inequality read as <= on a timeline). A cycle among agent order, precedence
and wait edges is a deadlock: the schedule is infeasible.

Timelines are vectorised over K duration samples: one topological pass over the items with arrays
of shape (K,), so all samples of a candidate cost one Python loop. :class:`ScheduleBatch` also
vectorises over schedules: B schedules cost one pass of at most n steps.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from rapidds.problem import AGENTS, Agent, Problem


@dataclass(frozen=True, order=True)
class Wait:
    """Wait token: do not go on until ``task`` has finished."""

    task: str

    def __str__(self) -> str:
        return f"wait:{self.task}"


Item = str | Wait


def parse_item(text: str) -> Item:
    """Inverse of ``str(item)``: ``"t0"`` -> task, ``"wait:t0"`` -> Wait."""
    return Wait(text[5:]) if text.startswith("wait:") else text


def task_items(items: Iterable[str]) -> list[str]:
    """The tasks of a sequence written as text (a stored record's), its waits left out."""
    return [t for t in items if not isinstance(parse_item(t), Wait)]


def item_json(item: Item | str) -> dict[str, str]:
    """An item as structured data for a reader outside Python (the browser): ``{"task": t}`` or
    ``{"wait": t}``, so no one else needs to know how a wait is written as text."""
    item = parse_item(item) if isinstance(item, str) else item
    return {"wait": item.task} if isinstance(item, Wait) else {"task": item}


@dataclass(frozen=True)
class Schedule:
    """Per-agent sequences. Hashable, so it can key caches and deduplicate a population."""

    human: tuple[Item, ...]
    robot: tuple[Item, ...]

    def sequence(self, agent: Agent) -> tuple[Item, ...]:
        return self.human if agent == "human" else self.robot

    def tasks(self, agent: Agent) -> tuple[str, ...]:
        # a list comprehension: a third faster than a generator here, and the GA's polish
        # asks for hundreds of thousands of these
        return tuple([x for x in self.sequence(agent) if isinstance(x, str)])

    @cached_property
    def assignment(self) -> dict[str, Agent]:
        return {t: a for a in AGENTS for t in self.tasks(a)}

    def agent_of(self, task: str) -> Agent:
        return self.assignment[task]

    def replace(self, agent: Agent, seq: Iterable[Item]) -> Schedule:
        seq = tuple(seq)
        return Schedule(seq, self.robot) if agent == "human" else Schedule(self.human, seq)

    def to_json(self) -> dict[str, list[str]]:
        return {a: [str(x) for x in self.sequence(a)] for a in AGENTS}

    @classmethod
    def from_json(cls, d: dict[str, Sequence[str]]) -> Schedule:
        return cls(
            tuple(parse_item(x) for x in d.get("human", ())),
            tuple(parse_item(x) for x in d.get("robot", ())),
        )

    def __str__(self) -> str:
        return " | ".join(f"{a}: [{', '.join(map(str, self.sequence(a)))}]" for a in AGENTS)


def validate(problem: Problem, s: Schedule) -> None:
    """Raise ValueError unless every task appears exactly once on an agent allowed to do it."""
    seen: list[str] = []
    for agent in AGENTS:
        for item in s.sequence(agent):
            tid = item.task if isinstance(item, Wait) else item
            if tid not in problem.index:
                raise ValueError(f"schedule names unknown task '{tid}'")
            if isinstance(item, str):
                if not problem.task(item).can(agent):
                    raise ValueError(f"task '{item}' is not allowed to the {agent}")
                seen.append(item)
    missing = set(problem.ids) - set(seen)
    if missing or len(seen) != len(set(seen)):
        dup = sorted({t for t in seen if seen.count(t) > 1})
        raise ValueError(
            f"schedule must hold each task once (missing {sorted(missing)}, repeated {dup})"
        )


def _without_waits(s: Schedule) -> bool:
    for seq in (s.human, s.robot):
        for x in seq:
            if x.__class__ is not str:
                return False
    return True


def repair(s: Schedule) -> Schedule:
    """Drop waits that cannot matter: on a task of the same agent, repeated, or at the end."""
    if _without_waits(s):  # most of the GA's polish neighbours: nothing to drop, 7x faster
        return s
    out = []
    for agent in AGENTS:
        own = set(s.tasks(agent))
        seq: list[Item] = []
        waited: set[str] = set()
        for item in s.sequence(agent):
            if isinstance(item, Wait):
                if item.task in own or item.task in waited:
                    continue
                waited.add(item.task)
            seq.append(item)
        while seq and isinstance(seq[-1], Wait):
            seq.pop()
        out.append(tuple(seq))
    return Schedule(out[0], out[1])


@dataclass(frozen=True)
class _Step:
    agent: int  # 0 human, 1 robot
    col: int  # task column; for a wait, the waited task's column
    is_wait: bool
    deps: tuple[int, ...]  # task columns whose finish gates this step


class CompiledSchedule:
    """A schedule resolved into a topological order of steps, or ``None`` if it deadlocks.

    Compile once per schedule, then :meth:`simulate` any number of duration arrays.
    """

    def __init__(self, problem: Problem, schedule: Schedule, steps: list[_Step]):
        self.problem = problem
        self.schedule = schedule
        self.steps = steps
        self.n = len(problem.tasks)
        idx = problem.index
        self.robot_cols = np.array([idx[t] for t in schedule.tasks("robot")], dtype=int)
        self.human_cols = np.array([idx[t] for t in schedule.tasks("human")], dtype=int)

    @classmethod
    def build(cls, problem: Problem, schedule: Schedule) -> CompiledSchedule | None:
        idx = problem.index
        seqs = [schedule.sequence(a) for a in AGENTS]
        placed = {t for seq in seqs for t in seq if isinstance(t, str)}
        preds = problem.preceding
        pos = [0, 0]
        done: set[str] = set()
        steps: list[_Step] = []
        total = len(seqs[0]) + len(seqs[1])
        while len(steps) < total:
            progressed = False
            for a in (0, 1):
                while pos[a] < len(seqs[a]):
                    item = seqs[a][pos[a]]
                    gate = [item.task] if isinstance(item, Wait) else preds[item]
                    if any(g not in done for g in gate):
                        break
                    if isinstance(item, Wait):
                        if item.task not in placed:
                            return None
                        steps.append(_Step(a, idx[item.task], True, (idx[item.task],)))
                    else:
                        steps.append(_Step(a, idx[item], False, tuple(idx[g] for g in gate)))
                        done.add(item)
                    pos[a] += 1
                    progressed = True
            if not progressed:
                return None  # every agent blocked: a cycle of order, precedence and waits
        return cls(problem, schedule, steps)

    def durations(self, human: np.ndarray, robot: np.ndarray) -> np.ndarray:
        """Per-task durations (K, n): human samples (K, n) where the human does the task,
        the robot's durations (n,) where the robot does."""
        d = np.array(human, dtype=float, copy=True)
        if self.robot_cols.size:
            d[:, self.robot_cols] = np.asarray(robot, dtype=float)[self.robot_cols]
        return d

    def simulate(self, durations: np.ndarray) -> Timeline:
        """Start and finish of every task for each of K samples. durations: (K, n) -> (K, n)."""
        durations = np.atleast_2d(durations)
        k = durations.shape[0]
        start = np.zeros((k, self.n))
        finish = np.zeros((k, self.n))
        free = [np.zeros(k), np.zeros(k)]
        for st in self.steps:
            ready = free[st.agent]
            for c in st.deps:
                ready = np.maximum(ready, finish[:, c])
            if st.is_wait:
                free[st.agent] = ready
            else:
                start[:, st.col] = ready
                finish[:, st.col] = ready + durations[:, st.col]
                free[st.agent] = finish[:, st.col]
        return Timeline(self.problem, self.schedule, start, finish)


@dataclass(frozen=True)
class Timeline:
    """Start/finish times, shape (K, n) with tasks in problem order."""

    problem: Problem
    schedule: Schedule
    start: np.ndarray
    finish: np.ndarray

    @property
    def makespan(self) -> np.ndarray:
        """(K,) time at which the last task finishes."""
        return self.finish.max(axis=1)

    def overlaps(self, sample: int = 0) -> dict[str, frozenset[str]]:
        """C_j: for each robot task j, the human tasks whose interval overlaps j's with positive
        length in timeline ``sample`` (use the expected timeline, K = 1)."""
        idx = self.problem.index
        s, f = self.start[sample], self.finish[sample]
        human = self.schedule.tasks("human")
        out = {}
        for j in self.schedule.tasks("robot"):
            cj = idx[j]
            out[j] = frozenset(
                i for i in human if max(s[idx[i]], s[cj]) < min(f[idx[i]], f[cj]) - 1e-9
            )
        return out


class ScheduleBatch:
    """B schedules of one problem as integer arrays, so their timelines run together.

    Task ``i`` of schedule ``b`` starts when its agent is free and its gates ``deps[b, i]`` are
    done: its predecessors and the tasks of the waits in front of it (a wait takes no time, and
    a wait with no task after it delays nothing). Column ``n`` is a sentinel gate, always done
    at time 0. Max and one addition per task are exact, so the times equal
    :meth:`CompiledSchedule.simulate`'s bit for bit.
    """

    def __init__(self, problem: Problem, schedules: Sequence[Schedule]):
        self.problem = problem
        self.schedules = list(schedules)
        n = self.n = len(problem.tasks)
        b_count = len(self.schedules)
        idx = problem.index
        preds = [[idx[p] for p in problem.preceding[t]] for t in problem.ids]
        own: list[list[int]] = []  # per schedule and agent (row 2b + agent): task columns
        waits: list[tuple[int, int, int]] = []  # (schedule, task, waited task)
        for b, s in enumerate(self.schedules):
            for seq in (s.human, s.robot):
                cols = [idx[x] for x in seq if x.__class__ is str]
                if len(cols) < len(seq):
                    pending: list[int] = []
                    for x in seq:
                        if isinstance(x, Wait):
                            pending.append(idx[x.task])
                        elif pending:
                            waits += [(b, idx[x], w) for w in pending]
                            pending = []
                own.append(cols)
        slots = [0] * (b_count * n)
        for b, t, _ in waits:
            slots[b * n + t] += 1
        p_max = max((len(x) for x in preds), default=0)
        deps = np.full((b_count, n + 1, max(1, p_max + max(slots, default=0))), n,
                       dtype=np.intp)
        for i, row in enumerate(preds):
            deps[:, i, : len(row)] = row
        used = [0] * (b_count * n)
        for b, t, w in waits:
            deps[b, t, p_max + used[b * n + t]] = w
            used[b * n + t] += 1
        self.deps = deps.reshape(b_count * (n + 1), -1)  # row b (n + 1) + i
        longest = max((len(c) for c in own), default=0)
        seqs = np.full((2 * b_count, longest + 1), n, dtype=np.intp)
        for r, cols in enumerate(own):
            seqs[r, : len(cols)] = cols
        self.seqs = seqs  # row 2b: the human's columns of schedule b in order, 2b+1 the robot's
        self.lengths = np.array([len(c) for c in own], dtype=np.intp)
        self.human = np.zeros((b_count, n), dtype=bool)  # the human does task i in schedule b
        for b in range(b_count):
            self.human[b, own[2 * b]] = True

    def __len__(self) -> int:
        return len(self.schedules)

    def durations(self, human: np.ndarray, robot: np.ndarray) -> np.ndarray:
        """(B, n, R) durations: human rows (R, n) where the human does the task, else each
        schedule's robot durations ``robot`` (B, n) or (n,)."""
        robot = np.broadcast_to(np.asarray(robot, dtype=float), (len(self), self.n))
        return np.where(self.human[:, :, None], np.asarray(human, dtype=float).T[None],
                        robot[:, :, None])

    def simulate(self, durations: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Start and finish (B, n, R) of every task for R duration rows, and which schedules
        are feasible (B,); a deadlocked schedule's times are meaningless.

        Each step places the next task of every agent of every schedule whose gates are done,
        so a pass takes at most n steps whatever B and R are.
        """
        b_count, n = len(self), self.n
        r_count = durations.shape[2]
        stride = n + 1
        dur = np.zeros((b_count, stride, r_count))
        dur[:, :n] = durations
        dur = dur.reshape(b_count * stride, r_count)
        start = np.zeros(dur.shape)  # zeros, not zeros_like: fresh zero pages, no fill pass
        finish = np.zeros(dur.shape)
        done = np.zeros(b_count * stride, dtype=bool)
        done[n::stride] = True
        free = np.zeros((2 * b_count, r_count))
        base = np.arange(2 * b_count) // 2 * stride
        seqs, deps = self.seqs, self.deps
        width = seqs.shape[1]
        flat_seqs = seqs.ravel()
        cursor = np.arange(2 * b_count) * width  # flat position of each agent's next task
        while True:
            row = flat_seqs[cursor] + base  # flat (schedule, task) of every agent's next task
            live = np.flatnonzero(row - base < n)
            if not live.size:
                break
            row = row[live]
            gate = deps[row] + base[live, None]
            go = done[gate].all(axis=1)
            if not go.all():
                if not go.any():
                    break  # every remaining agent waits on a cycle: those schedules deadlock
                live, row, gate = live[go], row[go], gate[go]
            ready = np.maximum(free[live], finish[gate].max(axis=1))
            start[row] = ready
            finish[row] = free[live] = ready + dur[row]
            done[row] = True
            cursor[live] += 1
        placed = cursor - np.arange(2 * b_count) * width
        feasible = (placed == self.lengths).reshape(b_count, 2).all(axis=1)
        shape = (b_count, stride, r_count)
        return start.reshape(shape)[:, :n], finish.reshape(shape)[:, :n], feasible


def compile_schedule(problem: Problem, schedule: Schedule) -> CompiledSchedule | None:
    """Shorthand for :meth:`CompiledSchedule.build`; ``None`` means the schedule deadlocks."""
    return CompiledSchedule.build(problem, schedule)
