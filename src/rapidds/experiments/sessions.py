"""``DIR/sessions.jsonl``: one line per invocation of a study on Dask (the ablation, the
simulated user study) saying how long it took, on what, and how much it ran. The one writer and
reader of that log, so both studies' lines have the same keys."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

__all__ = ["SESSIONS_NAME", "log_session", "read_sessions"]

SESSIONS_NAME = "sessions.jsonl"


def log_session(out: Path, outcome: Any, where: str, **extra: Any) -> dict[str, Any]:
    """Append this invocation's line and return it. ``outcome``: the study's counts (total,
    skipped, ran, wall_s, workers, trial_seconds, failed); ``where``: the cluster; ``extra``:
    more keys (the ablation stores its settings under ``study``)."""
    line = {"finished": time.strftime("%Y-%m-%d %H:%M:%S"), "wall_s": round(outcome.wall_s, 2),
            "ran": outcome.ran, "skipped": outcome.skipped, "total": outcome.total,
            "workers": outcome.workers, "cluster": where,
            "trial_seconds_sum": round(sum(outcome.trial_seconds), 2),
            "failed": len(outcome.failed),
            "load_average": [round(x, 2) for x in os.getloadavg()], **extra}
    with open(out / SESSIONS_NAME, "a") as fh:  # append-only: a line per invocation
        fh.write(json.dumps(line) + "\n")
    return line


def read_sessions(out: Path) -> list[dict[str, Any]]:
    """Every line of ``out``'s log (none if there is no log); a line cut short by a kill is
    skipped, the others still count."""
    log = out / SESSIONS_NAME
    sessions = []
    if log.is_file():
        for line in log.read_text().splitlines():
            try:
                sessions.append(json.loads(line))
            except ValueError:
                continue
    return sessions
