"""Plain-text views of a plan for the terminal: sequences, a Gantt chart, makespan statistics.

Every function returns a ``str`` without colour codes, so output reads the same in a terminal, a
pipe, a log file or a test. Tables are laid out by rich; the Gantt chart is drawn by hand because
it needs one character per time slot.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence

import numpy as np
from rich import box
from rich.console import Console
from rich.table import Table

from rapidds.problem import AGENTS, Agent
from rapidds.schedule import Item, Timeline, Wait

WAIT_CHAR = "~"
"""Fills the time an agent stands idle because of a wait token."""


def _to_text(renderable: object, width: int) -> str:
    console = Console(
        file=io.StringIO(), width=width, color_system=None, force_terminal=False,
        highlight=False, emoji=False,
    )
    console.print(renderable)
    out = console.file.getvalue()  # type: ignore[attr-defined]
    return "\n".join(line.rstrip() for line in out.splitlines())


def wait_intervals(
    timeline: Timeline, agent: Agent, sample: int = 0
) -> list[tuple[Wait, float, float]]:
    """(wait, from, until) for each wait token of ``agent``: from the moment the agent was free
    to the moment the waited task finished (until == from when the wait cost nothing)."""
    idx = timeline.problem.index
    finish = timeline.finish[sample]
    free = 0.0
    out: list[tuple[Wait, float, float]] = []
    for item in timeline.schedule.sequence(agent):
        if isinstance(item, Wait):
            until = max(free, float(finish[idx[item.task]]))
            out.append((item, free, until))
            free = until
        else:
            free = float(finish[idx[item]])
    return out


def _item_times(timeline: Timeline, agent: Agent, sample: int) -> list[tuple[Item, float, float]]:
    idx = timeline.problem.index
    start, finish = timeline.start[sample], timeline.finish[sample]
    waits = iter(wait_intervals(timeline, agent, sample))
    rows: list[tuple[Item, float, float]] = []
    for item in timeline.schedule.sequence(agent):
        if isinstance(item, Wait):
            _, a, b = next(waits)
            rows.append((item, a, b))
        else:
            rows.append((item, float(start[idx[item]]), float(finish[idx[item]])))
    return rows


def render_sequences(timeline: Timeline, sample: int = 0, width: int = 80) -> str:
    """Per-agent listing of tasks and waits with their start and end in timeline ``sample``.

    A wait's times are when the agent began standing idle and when the waited task finished.
    """
    table = Table(box=box.SIMPLE_HEAD, pad_edge=False, show_edge=False)
    for col, justify in (("agent", "left"), ("#", "right"), ("item", "left"),
                         ("start", "right"), ("end", "right"), ("", "left")):
        table.add_column(col, justify=justify)  # type: ignore[arg-type]
    for agent in AGENTS:
        rows = _item_times(timeline, agent, sample)
        if not rows:
            table.add_row(agent, "", "(nothing)", "", "", "")
        for k, (item, a, b) in enumerate(rows):
            if isinstance(item, Wait):
                note = f"idle {b - a:.1f} s" if b > a + 1e-9 else "no delay"
                label = f"wait for {item.task}"
            else:
                note, label = "", item
            table.add_row(agent if k == 0 else "", str(k + 1), label, f"{a:.1f}", f"{b:.1f}", note)
        if agent != AGENTS[-1]:
            table.add_section()
    return _to_text(table, width)


def _nice_step(span: float, slots: int) -> float:
    """A 1/2/5 x 10^k tick spacing giving about ``slots`` ticks over ``span``."""
    raw = span / max(slots, 1)
    mag = 10 ** math.floor(math.log10(raw)) if raw > 0 else 1.0
    return next((m * mag for m in (1, 2, 5, 10) if m * mag >= raw), 10 * mag)


def _bar(label: str, n: int) -> str:
    """A task bar of exactly ``n`` characters: ``[label---]``, truncated when short."""
    if n <= 0:
        return ""
    if n == 1:
        return label[:1]
    if n == 2:
        return "[]" if len(label) > 1 else f"[{label}"[:2]
    inner = label[: n - 2]
    return "[" + inner + "-" * (n - 2 - len(inner)) + "]"


def render_gantt(
    timeline: Timeline, width: int = 72, sample: int = 0, title: str | None = None
) -> str:
    """Text Gantt chart of timeline ``sample``: one row per agent, ``width`` characters for the
    time from 0 to the makespan. Tasks are ``[id---]`` bars, idle time caused by a wait token is
    ``~``, other idle time is blank."""
    width = max(width, 10)
    idx = timeline.problem.index
    start, finish = timeline.start[sample], timeline.finish[sample]
    end = float(finish.max()) if finish.size else 0.0
    scale = width / end if end > 0 else 0.0

    def cell(t: float) -> int:
        return min(width, max(0, round(t * scale)))

    name_w = max(len(a) for a in AGENTS)
    lines = [title] if title else []
    step = _nice_step(end, 6) if end > 0 else 1.0
    axis = [" "] * (width + 8)
    ticks = [" "] * (width + 1)
    t = 0.0
    while t <= end + 1e-9:
        c = cell(t)
        ticks[c] = "|"
        label = f"{t:g}"
        if all(ch == " " for ch in axis[c : c + len(label) + 1]):
            axis[c : c + len(label)] = list(label)
        t += step
    lines.append(" " * (name_w + 1) + "".join(axis).rstrip() + "  s")
    for agent in AGENTS:
        row = [" "] * width
        for _, a, b in wait_intervals(timeline, agent, sample):
            for c in range(cell(a), cell(b)):
                row[c] = WAIT_CHAR
        for task in timeline.schedule.tasks(agent):
            c0, c1 = cell(float(start[idx[task]])), cell(float(finish[idx[task]]))
            if c1 == c0 and c0 < width:
                c1 = c0 + 1  # a very short task still shows
            row[c0:c1] = list(_bar(task, c1 - c0))
        lines.append(f"{agent:<{name_w}} " + "".join(row).rstrip())
    lines.append(" " * (name_w + 1) + "".join(ticks).rstrip())
    lines.append(f"{' ' * (name_w + 1)}[id--] task   {WAIT_CHAR} waiting for the other agent")
    return "\n".join(lines)


def makespan_stats(makespans: Sequence[float] | np.ndarray) -> dict[str, float]:
    """Mean, standard deviation (ddof 0, as :class:`~rapidds.scheduler.Evaluation` reports it),
    5th and 95th percentile of makespan samples."""
    m = np.asarray(makespans, dtype=float).ravel()
    if m.size == 0:
        raise ValueError("no makespan samples")
    return {
        "mean": float(m.mean()),
        "std": float(m.std()),
        "p5": float(np.percentile(m, 5)),
        "p95": float(np.percentile(m, 95)),
    }


def makespan_line(makespans: Sequence[float] | np.ndarray) -> str:
    """``expected makespan 23.4 s (sd 1.2, p5–p95 21.0–25.9)`` from Monte-Carlo makespans."""
    s = makespan_stats(makespans)
    return (
        f"expected makespan {s['mean']:.1f} s "
        f"(sd {s['std']:.1f}, p5–p95 {s['p5']:.1f}–{s['p95']:.1f})"
    )


def key_value_table(rows: Sequence[tuple[str, str]], width: int = 80) -> str:
    """Two aligned columns, for summaries (objective terms, solver facts)."""
    table = Table(box=None, show_header=False, pad_edge=False)
    table.add_column(justify="left")
    table.add_column(justify="left")
    for k, v in rows:
        table.add_row(k, v)
    return _to_text(table, width)
