"""Progress of long work on stderr: a bar on a terminal, a log line every few seconds otherwise
(CI, ``nohup``, a pipe), so long commands never sit silent for minutes."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from typing import Any

Update = Callable[[int, str], None]
"""update(done, info): ``done`` units of ``total`` finished; ``info`` a short status."""

LOG_EVERY_S = 5.0


@contextmanager
def progress(label: str, total: int, *, quiet: bool = False,
             every: float = LOG_EVERY_S) -> Iterator[Update]:
    """Report ``done / total`` of ``label``; silent when ``quiet`` (e.g. with ``--json``)."""
    if quiet:
        yield lambda done, info: None
        return
    if sys.stderr.isatty():
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        with Progress(TextColumn(label), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[info]}"), TimeElapsedColumn(),
                      TimeRemainingColumn(), console=Console(stderr=True),
                      transient=True) as bar:
            task = bar.add_task(label, total=total, info="")
            yield lambda done, info: bar.update(task, completed=done, info=info)
        return
    t0 = last = time.monotonic()
    state = {"done": 0, "info": ""}

    def log(final: bool = False) -> None:
        tail = f", {state['info']}" if state["info"] else ""
        print(f"{label}: {state['done']}/{total}{tail} ({time.monotonic() - t0:.0f} s"
              f"{', done' if final else ''})", file=sys.stderr, flush=True)

    def update(done: int, info: str) -> None:
        nonlocal last
        state.update(done=done, info=info)
        now = time.monotonic()
        if now - last >= every:
            last = now
            log()

    yield update
    if time.monotonic() - t0 >= every:
        log(final=True)


class TrialProgress:
    """:func:`progress` for a study on Dask (the ablation, the simulated user study): the total
    is known only once the stored trials are counted (``on_start``), and each finished trial
    (``on_trial``) is logged as it is stored, since trials take minutes and logs are read later.
    """

    def __init__(self, noun: str = "trials") -> None:
        self.noun = noun
        self._stack = ExitStack()
        self._update: Update = lambda done, info: None

    def __enter__(self) -> TrialProgress:
        self._stack.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stack.__exit__(*exc)

    def on_start(self, total: int, skipped: int) -> None:
        if skipped:
            print(f"{skipped} of {total} {self.noun} already stored; running the other "
                  f"{total - skipped}", file=sys.stderr, flush=True)
        self._update = self._stack.enter_context(progress(self.noun, total, every=0.0))
        self._update(skipped, "")

    def on_trial(self, result: dict[str, Any], stored: int, total: int) -> None:
        from rapidds.record import CycleRecord  # numpy: not at help time

        last = result["records"][-min(4, len(result["records"])):]
        cost = sum(CycleRecord.from_json(r).realised.cost for r in last) / len(last)
        self._update(stored, f"{result['run_id']} {result['seconds']:.0f} s, "
                             f"last-4 cost {cost:.2f}")
