"""Long commands report progress also when stderr is not a terminal (CI, nohup, a pipe)."""

from __future__ import annotations

import time

from rapidds.cli._progress import progress


def test_without_a_terminal_progress_is_a_log_line_every_few_seconds(capsys):
    with progress("training", 10, every=0.05) as update:
        for step in range(1, 11):
            update(step, f"loss {1 / step:.3f}")
            time.sleep(0.02)
    lines = capsys.readouterr().err.splitlines()
    assert 2 <= len(lines) <= 6, lines  # about one line per 0.05 s, not one per step
    assert lines[-1].startswith("training: 10/10, loss 0.100") and lines[-1].endswith("done)")


def test_quiet_progress_prints_nothing(capsys):
    with progress("generations", 5, quiet=True, every=0) as update:
        for g in range(5):
            update(g, "")
    assert capsys.readouterr().err == ""
