"""The GA's polish: best-improvement local search over a schedule's whole single-step
neighbourhood, for the best schedule of each stalled population, the final best, and the best
schedule of each of the next-best allocations (``GAConfig.polish``, ``polish_allocations``)."""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Callable, Iterator

import numpy as np

from rapidds.problem import AGENTS, Agent
from rapidds.schedule import Item, Schedule, Wait, repair
from rapidds.scheduler.config import GAConfig
from rapidds.scheduler.evaluate import Evaluation
from rapidds.scheduler.evaluator import Evaluator, allocation, rank
from rapidds.scheduler.operators import Operators, other


def _anchors(ops: Operators, s: Schedule, start: np.ndarray) -> dict[Item, dict[Agent, int]]:
    """Where each task's expected start falls in each sequence of ``s``."""
    at: dict[Item, dict[Agent, int]] = {}
    index = ops.index
    for agent in AGENTS:
        seq = s.sequence(agent)
        slots = [k for k, x in enumerate(seq) if isinstance(x, str)]
        starts = [start[index[seq[k]]] for k in slots]  # nondecreasing along seq
        slots.append(len(seq))
        for item in ops.problem.ids:
            at.setdefault(item, {})[agent] = slots[bisect_left(starts, start[index[item]])]
    return at


def neighbours(ops: Operators, s: Schedule, start: np.ndarray | None = None,
               window: int = 0) -> list[Schedule]:
    """Every single move, reorder, swap within an agent, pair of adjacent swaps (one in each
    agent), exchange of two tasks between agents, and wait removal of ``s`` (repaired,
    distinct, without ``s``): the polish neighbourhood, O(n^2) schedules.

    With ``window`` and the expected start times ``start`` (n,), only changes within
    ``window`` positions: an item moves at most that far in its sequence, a task goes to
    the other agent at most that far from where its start falls there, and the adjacent
    swaps and exchanges pair items at most that far apart in time order. O(n window)
    schedules; on sequences of at most ``window`` items, the whole neighbourhood.
    """
    near = window > 0 and start is not None and start.size > 0
    reach = window if near else 1 << 30
    at = _anchors(ops, s, start) if near and start is not None else {}

    def anchor(agent: Agent, k: int) -> int:
        """Where the item at ``k`` in the other sequence falls in ``agent``'s."""
        seq = s.sequence(other(agent))
        task = next((x for x in seq[k:] if isinstance(x, str)), None)
        return at[task][agent] if near and task is not None else len(s.sequence(agent))

    out: dict[Schedule, None] = {}
    for task in ops.shared:
        src = s.agent_of(task)
        dst = other(src)
        rest = tuple(x for x in s.sequence(src) if x != task)
        seq = s.sequence(dst)
        lo, hi = ops.window(seq, task)
        if near:
            mid = at[task][dst]
            lo, hi = max(lo, mid - reach), min(hi, mid + reach)
        for p in range(lo, hi + 1):
            out[repair(s.replace(src, rest).replace(dst, (*seq[:p], task, *seq[p:])))] = None
    for agent in AGENTS:
        seq = s.sequence(agent)
        for k, item in enumerate(seq):
            rest = seq[:k] + seq[k + 1 :]
            if isinstance(item, Wait):
                out[repair(s.replace(agent, rest))] = None
            lo, hi = (0, len(rest)) if isinstance(item, Wait) else ops.window(rest, item)
            for p in range(max(lo, k - reach), min(hi, k + reach) + 1):
                if p != k:
                    out[repair(s.replace(agent, (*rest[:p], item, *rest[p:])))] = None
            for j in range(k + 1, min(len(seq), k + reach + 1)):
                swapped = (*seq[:k], seq[j], *seq[k + 1 : j], item, *seq[j + 1 :])
                out[repair(s.replace(agent, swapped))] = None
    h, r = s.human, s.robot
    for i in range(len(h) - 1):  # adjacent swaps in both sequences at once: one agent's
        mid = anchor("robot", i)  # new order often pays only with the other's
        for j in range(len(r) - 1):
            if abs(j - mid) <= reach:
                out[repair(Schedule((*h[:i], h[i + 1], h[i], *h[i + 2 :]),
                                    (*r[:j], r[j + 1], r[j], *r[j + 2 :])))] = None
    for i, a in enumerate(h):
        if isinstance(a, Wait) or "robot" not in ops.allowed[a]:
            continue
        mid = anchor("robot", i)
        for j, b in enumerate(r):
            if isinstance(b, Wait) or "human" not in ops.allowed[b] or abs(j - mid) > reach:
                continue
            out[repair(Schedule((*h[:i], b, *h[i + 1 :]), (*r[:j], a, *r[j + 1 :])))] = None
    out.pop(s, None)
    return list(out)


def polish(ops: Operators, config: GAConfig, start: Evaluation, evaluator: Evaluator,
           stop: Callable[[], bool] | None = None) -> Evaluation:
    """Local search over :func:`neighbours`; ``stop`` is asked before every pass.

    A pass takes the best neighbour (best improvement, one batch), or on jobs of at least
    ``polish_screen_min_tasks`` tasks with a :attr:`Evaluator.bounded` objective the best of
    the first chunk of :func:`screened` neighbours that holds an improvement. Either way a
    polish stops only where no neighbour improves."""
    screen = (config.polish_screen_chunk > 0 and evaluator.bounded
              and len(ops.problem.tasks) >= config.polish_screen_min_tasks)
    current = start
    for _ in range(config.polish_passes):
        if stop is not None and stop():
            break
        current = evaluator.complete([current])[0]  # the window needs its start times
        candidates = neighbours(ops, current.schedule, current.expected_start,
                                config.polish_window)
        limit = current.objective - 1e-12 * max(1.0, abs(current.objective))
        best = None
        for chunk in (screened(candidates, evaluator, limit, config) if screen
                      else [candidates] if candidates else []):
            best = min(evaluator.evaluate(chunk), key=lambda e: e.objective)
            if best.objective < limit:
                break
        if best is None or not best.objective < limit:
            break
        current = best
    return current


def screened(candidates: list[Schedule], evaluator: Evaluator, limit: float, config: GAConfig
             ) -> Iterator[list[Schedule]]:
    """``candidates`` whose lower bound (:meth:`Evaluator.lower_bounds`) is below ``limit``,
    most promising first, ``polish_screen_chunk`` at a time; with ``polish_screen_orders``
    (and the order search on), first the shortest orders of every allocation among all
    ``candidates`` not searched before whose agent-load bound is below ``limit``. The others
    cannot improve on ``limit``: on 64 tasks about half of a neighbourhood, whose full
    evaluation the polish then skips. The bound's ranking puts the best neighbour first in
    most passes."""
    bound, load = evaluator.lower_bounds(candidates)
    slack = 1e-9 * max(1.0, abs(limit))  # rounding of the bounds' sums against the samples'
    if config.polish_screen_orders and config.order_search_nodes:
        # what evaluating them all would add, less the allocations whose load cannot improve
        orders = evaluator.shortest_orders([s for s, b in zip(candidates, load, strict=True)
                                            if b < limit + slack])
        if orders:
            yield orders
    order = [int(k) for k in np.argsort(bound, kind="stable") if bound[k] < limit + slack]
    for lo in range(0, len(order), config.polish_screen_chunk):
        yield [candidates[k] for k in order[lo : lo + config.polish_screen_chunk]]


def polish_runners_up(ops: Operators, config: GAConfig, evaluator: Evaluator,
                      polished: set[Schedule]) -> None:
    """The end of a solve: a polish of the best schedule of each of the
    ``polish_allocations`` best allocations, within ``polish_budget``. The trap it targets:
    the right allocation with an order no single move improves."""
    evaluated = evaluator.evaluated
    limit = (1.0 + config.polish_budget) * len(evaluated)
    best_of: dict[frozenset[str], Evaluation] = {}
    for e in rank(list(evaluated.values())):
        best_of.setdefault(allocation(e.schedule), e)
    for e in list(best_of.values())[: config.polish_allocations]:
        if len(evaluated) > limit:
            return
        if e.schedule not in polished:
            polished.add(e.schedule)
            polish(ops, config, e, evaluator, lambda: len(evaluated) > limit or evaluator.late())
