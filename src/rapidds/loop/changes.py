"""Change detection inside the loop: a task whose durations changed restarts its beliefs from
the observations since the change (paper section on limitations; docs/design-notes.md), a change
seen on several tasks may move the whole person's (fatigue, practice), and the person may be
asked first. Split from :mod:`rapidds.loop.run` so that the cycle's steps read on their own."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rapidds.human.changes import detect_change
from rapidds.human.temporal import DEFAULT_ALPHA, DEFAULT_NU, DurationModel, NIGPrior
from rapidds.loop.config import RunConfig
from rapidds.loop.deploy import Deployment
from rapidds.loop.model import HumanModel
from rapidds.worlds.base import SimulatedTeammate, Teammate

__all__ = ["detect_changes"]


def detect_changes(cfg: RunConfig, model: HumanModel, teammate: Teammate, cycle: int,
                   deployment: Deployment, learn_space: bool) -> list[dict[str, Any]]:
    """Change detection on the tasks observed this cycle; on a change (not denied by the
    person) the task's beliefs restart from the observations since it. What happened goes
    into the cycle's record."""
    log, out = model.changes, []
    olds: dict[str, NIGPrior] = {}  # the old person's belief of each reset task
    for task, ex in deployment.human.items():
        dm = model.temporal.models[task]
        ch = detect_change(dm, hazard=cfg.hazard, threshold=cfg.detect_threshold)
        if ch is None or ch.index < log.unchanged_until.get(task, 0):
            continue
        since = log.cycles[task][ch.index]
        entry: dict[str, Any] = {
            "task": task, "since_cycle": since, "probability": ch.probability,
            "mean_before": ch.before, "mean_after": ch.after}
        if cfg.ask:
            entry["question"] = (f"you seem {ch.direction} on {task} since cycle {since} "
                                 f"({ch.before:.1f} s -> {ch.after:.1f} s): has something "
                                 "changed?")
            entry["answer"] = answer = _answer(teammate, task, log.cycles[task][ch.index - 1],
                                                    cycle)
            if answer is False:  # the person says they are who they were: an outlier
                log.unchanged_until[task] = len(dm.observations)
                entry["action"] = "kept"
                out.append(entry)
                continue
        olds[task] = dm.fold(dm.observations[dm.start:ch.index], dm.base)
        dm.restart(ch.index)
        if learn_space:  # older paths are not kept: restart from the latest one
            model.spatial[task].reset()
            model.spatial.observe(task, ex.trajectory)
        log.last_change = cycle
        entry["action"] = "reset"
        out.append(entry)
    if cfg.whole_person and olds:
        out.append(_person_change(cfg, model, teammate, cycle, olds, [e for e in out
                                                      if e["action"] == "reset"]))
    return out

def _person_change(cfg: RunConfig, model: HumanModel, teammate: Teammate, cycle: int,
                   olds: dict[str, NIGPrior], resets: list[dict[str, Any]]) -> dict[str, Any]:
    """The change on the tasks just reset (``olds``: their beliefs of the old person) taken
    as the whole person's (fatigue, practice). Their durations scaled by a ratio r: each
    reset task's r_i is the mean of what the new person did on it over the old belief's
    mean (not the reset belief's, which the population prior pulls back). Every other task
    with observations of the old person starts a new segment at the change from its old
    belief moved by r = the geometric mean of the r_i (mean and spread times r), as
    confident as the population prior of a new person (nu, alpha), updated with the
    task's observations since; a reset task does the same with the other reset tasks' r
    when there are any (so no observation counts twice). With ``ask`` the person is asked
    first; a denial leaves it at the per-task resets."""
    log, models = model.changes, model.temporal.models
    since = min(e["since_cycle"] for e in resets)
    logr = {t: math.log(float(np.mean(models[t].observations[models[t].start:])) / b.mu)
            for t, b in olds.items()}
    ratio = math.exp(float(np.mean(list(logr.values()))))
    entry: dict[str, Any] = {"person": True, "since_cycle": since, "ratio": ratio,
                             "from_tasks": sorted(olds)}
    if cfg.ask:
        entry["question"] = (f"you seem {'slower' if ratio > 1 else 'faster'} overall since "
                             f"cycle {since} (durations x{ratio:.2f} on "
                             f"{', '.join(sorted(olds))}): on your other tasks too?")
        entry["answer"] = answer = _answer_person(model, teammate, since - 1, cycle, ratio)
        if answer is False:
            entry["action"] = "kept"
            return entry

    def moved(old: NIGPrior, dm: DurationModel, r: float) -> NIGPrior:
        var = old.expected_variance
        std = math.sqrt(var if math.isfinite(var) else dm.prior.expected_variance)
        return NIGPrior.from_moments(r * old.mu, r * std, DEFAULT_NU, DEFAULT_ALPHA)

    out = []
    for task, dm in models.items():
        if task in olds:
            others = [v for t, v in logr.items() if t != task]
            if others:
                dm.restart(dm.start, moved(olds[task], dm, math.exp(float(np.mean(others)))))
                out.append(task)
            continue
        seen = log.cycles.get(task, [])
        index = next((i for i, c in enumerate(seen) if c >= since), len(seen))
        if index <= dm.start:  # its segment holds nothing of the old person
            continue
        dm.restart(index, moved(dm.fold(dm.observations[dm.start:index], dm.base), dm, ratio))
        out.append(task)
    entry["tasks"] = out
    entry["action"] = "moved"
    return entry

def _answer_person(model: HumanModel, teammate: Teammate, then: int, now: int,
                   ratio: float) -> bool | None:
    """The person's answer to "are you slower (ratio > 1) or faster on all your tasks now
    than in cycle ``then``?": a simulated person answers truthfully (every task's true mean
    moved by more than 10 % that way); a live one through ``confirm_person_change(then)``
    if they offer it, else None (the detector is trusted)."""
    if isinstance(teammate, SimulatedTeammate):
        before = teammate.at(then).true_mean_durations()
        after = teammate.at(now).true_mean_durations()
        moved = [after[t] / before[t] for t in model.temporal.models]
        return all(m > 1.1 for m in moved) if ratio > 1 else all(m < 1 / 1.1 for m in moved)
    confirm = getattr(teammate, "confirm_person_change", None)
    return None if confirm is None else bool(confirm(then))

def _answer(teammate: Teammate, task: str, then: int, now: int) -> bool | None:
    """The person's answer to "are you different on ``task`` now than in cycle ``then``
    (the last observation before the suspected change)?": a simulated person answers
    truthfully (their true mean moved by more than 10 %); a live one through
    ``confirm_change(task, then)`` if they offer it, else None (no answer: the detector
    is trusted)."""
    if isinstance(teammate, SimulatedTeammate):
        before = teammate.at(then).true_mean_durations()[task]
        after = teammate.at(now).true_mean_durations()[task]
        return bool(abs(after / before - 1) > 0.1)
    confirm = getattr(teammate, "confirm_change", None)
    return None if confirm is None else bool(confirm(task, then))
