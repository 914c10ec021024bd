"""Active schedules of one allocation: one by priority, or the shortest by branch and bound.

For a fixed allocation (who does which task) and fixed durations, some makespan-optimal order is
*active*: no task could start earlier without delaying another. Giffler-Thompson builds an
active schedule by repeatedly taking the agent whose next task would finish first and choosing,
among that agent's tasks that could start before that finish, which goes next. A priority picks
one choice (:meth:`AllocationOrders.active`); branching on every choice enumerates all active
schedules, which :meth:`AllocationOrders.search` does depth first with a lower bound, so on small
jobs it proves the shortest order of the allocation within its node budget.

Wait tokens stay attached in front of the task that followed them and gate it like a
predecessor, so the waits a schedule chose survive a reorder.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from operator import add

from rapidds.problem import AGENTS, Agent, Problem
from rapidds.schedule import Item, Schedule, Wait, repair

# (task, agent) -> the duration to plan with
Duration = Callable[[str, Agent], float]


def longest_tails(ids: Sequence[str], succ: Mapping[str, Sequence[str]],
                  duration: Mapping[str, float]) -> dict[str, float]:
    """Longest path from the start of each task to the end of the job through its successors."""
    tail: dict[str, float] = {}

    def visit(t: str) -> float:
        if t not in tail:
            tail[t] = duration[t] + max((visit(s) for s in succ[t]), default=0.0)
        return tail[t]

    for t in ids:
        visit(t)
    return tail


class AllocationOrders:
    """The allocation of ``s``, its waits and its order, ready to be rebuilt as active schedules.

    Tasks are numbered in problem order and the search state is kept in lists: the search
    runs for every new allocation the GA meets, so it has to cost about as much as evaluating
    a few schedules.

    Args:
        s: the schedule whose allocation and waits are kept; its order breaks ties.
        problem: the job; its task order is the order tasks become ready in (determinism).
        duration: the duration of a task on an agent (e.g. expected human and nominal robot).
    """

    def __init__(self, s: Schedule, problem: Problem, duration: Duration):
        preds = problem.preceding
        agent_of: dict[str, int] = {}
        position: dict[str, int] = {}
        attached: dict[str, tuple[Wait, ...]] = {}
        for a, agent in enumerate(AGENTS):
            waits: list[Wait] = []
            for k, x in enumerate(s.sequence(agent)):
                if isinstance(x, Wait):
                    waits.append(x)
                else:
                    agent_of[x], position[x], attached[x] = a, k, tuple(waits)
                    waits = []
        self.ids = [t for t in problem.ids if t in agent_of]
        number = {t: i for i, t in enumerate(self.ids)}
        self.agent = [agent_of[t] for t in self.ids]
        self.position = [position[t] for t in self.ids]  # index in its agent's sequence
        self.attached = [attached[t] for t in self.ids]
        self.dur = [float(duration(t, AGENTS[agent_of[t]])) for t in self.ids]
        self.gated: list[list[int]] = [[] for _ in self.ids]  # gate -> tasks it gates
        self.pending: list[int] = []
        for i, t in enumerate(self.ids):
            gates = dict.fromkeys((*preds[t], *(w.task for w in attached[t])))
            self.pending.append(len(gates))
            for g in gates:
                self.gated[number[g]].append(i)
        tails = longest_tails(self.ids, problem.following,
                              dict(zip(self.ids, self.dur, strict=True)))
        self.tail = [tails[t] for t in self.ids]

    def _start(self) -> _State:
        left = [0.0, 0.0]
        for a, d in zip(self.agent, self.dur, strict=True):
            left[a] += d
        ready = [i for i, p in enumerate(self.pending) if p == 0]
        return _State([0.0, 0.0], [0.0] * len(self.ids), list(self.pending), ready, None,
                      left, 0.0, 0)

    def _conflict(self, state: _State) -> tuple[list[float], int, list[tuple[int, float]]]:
        """Earliest starts of the ready tasks, the agent to place on next, and that agent's
        tasks that could start before the earliest finish with their starts (the
        Giffler-Thompson conflict set)."""
        free, gate, agent, dur, ready = state.free, state.gate, self.agent, self.dur, state.ready
        est: list[float] = []
        ends: list[float] = []
        for t in ready:  # one plain loop: half the time of zipped comprehensions (hot path)
            f, g = free[agent[t]], gate[t]
            e = f if f > g else g
            est.append(e)
            ends.append(e + dur[t])
        cutoff = min(ends)
        a = agent[ready[ends.index(cutoff)]]
        return est, a, [(t, e) for t, e in zip(ready, est, strict=True)
                        if e < cutoff and agent[t] == a]

    def _place(self, state: _State, task: int, agent: int, est: float) -> _State:
        """A new state with ``task`` next on ``agent``, starting at ``est``."""
        done = est + self.dur[task]
        gate, pending = list(state.gate), list(state.pending)
        ready = [t for t in state.ready if t != task]
        for t in self.gated[task]:
            if done > gate[t]:
                gate[t] = done
            pending[t] -= 1
            if pending[t] == 0:
                ready.append(t)
        free, left = list(state.free), list(state.left)
        free[agent] = done
        left[agent] -= self.dur[task]
        return _State(free, gate, pending, ready, (state.placed_order, task), left,
                      max(state.makespan, done), state.placed + 1)

    def _result(self, state: _State) -> Schedule | None:
        if state.placed < len(self.ids):
            return None  # waits and precedence form a cycle
        order: list[int] = []
        link = state.placed_order
        while link is not None:
            link, task = link
            order.append(task)
        seqs: tuple[list[Item], list[Item]] = ([], [])
        for t in reversed(order):
            seqs[self.agent[t]].extend((*self.attached[t], self.ids[t]))
        return repair(Schedule(tuple(seqs[0]), tuple(seqs[1])))

    def active(self, critical_path: bool = False) -> Schedule | None:
        """The active schedule that, among tasks competing for an agent, takes the one
        earlier in the schedule's order or, with ``critical_path``, the one with the longest
        path to the end of the job (ties: earlier). None if the waits make every order cyclic.
        """
        tail, position = self.tail, self.position
        key = (lambda c: (-tail[c[0]], position[c[0]])) if critical_path else (
            lambda c: position[c[0]])
        state = self._start()
        while state.ready:
            _, agent, conflict = self._conflict(state)
            task, start = min(conflict, key=key)
            state = self._place(state, task, agent, start)
        return self._result(state)

    def search(self, max_nodes: int, keep: int = 4) -> tuple[list[Schedule], bool]:
        """Depth-first branch and bound over the active schedules, longest remaining path
        first, pruned where a lower bound (each agent's remaining work, each ready task's
        remaining path) cannot beat the shortest makespan found.

        Returns the last ``keep`` improving schedules, shortest first, and whether the search
        finished within ``max_nodes`` placements; then the first is a shortest order of this
        allocation on these durations. The first complete order is always reached, whatever
        the budget. Empty if the waits make every order cyclic.
        """
        found: list[tuple[float, _State]] = []
        best = float("inf")
        nodes = 0
        dived = False  # a complete (or dead-ended) order has been reached
        # A child is placed when it is popped, not when pushed: on large jobs the budget ends
        # the search after the first dive, and most pushed siblings are never visited.
        stack: list[tuple[_State, int, int, float]] = []
        root: _State | None = self._start()
        position, tail, n = self.position, self.tail, len(self.ids)
        while (root is not None or stack) and (nodes < max_nodes or not dived):
            if root is not None:
                state, root = root, None
            else:
                state = self._place(*stack.pop())
            if not state.ready:
                dived = True
                if state.placed == n and state.makespan < best:
                    best = state.makespan
                    found.append((best, state))
                continue
            est, agent, conflict = self._conflict(state)
            paths = map(add, est, [tail[t] for t in state.ready])
            bound = max(state.makespan, state.free[0] + state.left[0],
                        state.free[1] + state.left[1], *paths)
            if bound >= best - 1e-9 * max(1.0, abs(best)):
                continue
            conflict.sort(key=lambda c: (tail[c[0]], -position[c[0]]))
            for t, start in conflict:  # the stack pops the longest path first
                nodes += 1
                stack.append((state, t, agent, start))
        schedules = [self._result(st) for _, st in reversed(found[-keep:])]
        return [x for x in schedules if x is not None], not stack


class _State:
    """A partial active schedule: when each agent is free, when each task's gates are done,
    which tasks are ready, and the placements so far as a linked list (shared, not copied)."""

    __slots__ = ("free", "gate", "left", "makespan", "pending", "placed", "placed_order",
                 "ready")

    def __init__(self, free: list[float], gate: list[float], pending: list[int],
                 ready: list[int], placed_order: tuple[object, int] | None, left: list[float],
                 makespan: float, placed: int):
        self.free, self.gate, self.pending, self.ready = free, gate, pending, ready
        self.placed_order, self.left, self.makespan, self.placed = (
            placed_order, left, makespan, placed)
