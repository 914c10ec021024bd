"""Simulated teammates who change over the cycles: fatigue, practice, a new habit.

The paper's teammates are the same person in every cycle. :class:`ChangingTeammate` wraps any
world's simulated teammates into one who becomes another archetype at given cycles (a speed
change: fatigue or practice; a route or hand change: a new habit) and whose pace drifts by a
fixed fraction per cycle (gradual fatigue, > 0, or practice, < 0). It is a
:class:`~rapidds.worlds.base.SimulatedTeammate` like the others, so ``at(cycle)`` is the ground
truth the oracle plans with in that cycle.

Spec strings (the CLI's ``--change``): ``NAME@CYCLE``, several joined by commas, e.g.
``slow-outside@12`` or ``slow-outside@8,fast-outside@16``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from pydantic import Field

from rapidds.settings import Int, Positive, Real, settings_dataclass
from rapidds.worlds.base import (
    HumanExecution,
    SimulatedTeammate,
    World,
    body_points,
    perform_all,
)

__all__ = ["ChangingTeammate", "Paced", "changing_teammate", "parse_changes"]

_SPEC = re.compile(r"^\s*([A-Za-z0-9_.-]+)@(\d+)\s*$")


def parse_changes(spec: str) -> list[tuple[str, int]]:
    """``"NAME@CYCLE,..."`` -> [(name, cycle), ...] in cycle order; ValueError on bad text."""
    out = []
    for part in spec.split(","):
        m = _SPEC.match(part)
        if m is None:
            raise ValueError(f"a change is NAME@CYCLE (e.g. slow-outside@12), got {part.strip()!r}")
        out.append((m.group(1), int(m.group(2))))
    cycles = [c for _, c in out]
    if any(c < 1 for c in cycles) or len(set(cycles)) != len(cycles):
        raise ValueError(f"change cycles must be distinct and >= 1, got {spec!r}")
    return sorted(out, key=lambda p: p[1])


@dataclass(frozen=True)
class Paced:
    """``base`` taking ``factor`` times as long for everything (> 1: slower), on the same paths:
    each path is re-timed, row k at time k * dt of the longer (or shorter) execution."""

    base: SimulatedTeammate
    factor: float
    dt: float

    @property
    def name(self) -> str:
        return f"{self.base.name}x{self.factor:.3f}"

    def at(self, cycle: int) -> Paced:
        return self

    def execute(self, cycle: int, tasks: Sequence[str],
                rng: np.random.Generator) -> dict[str, HumanExecution]:
        return perform_all(self, tasks, rng)

    def perform(self, task: str, rng: np.random.Generator) -> tuple[float, np.ndarray]:
        d, path = self.base.perform(task, rng)
        p = body_points(path)
        t_old = np.minimum(np.arange(p.shape[0]) * self.dt, d)
        d_new = d * self.factor
        t_new = np.minimum(np.arange(math.ceil(d_new / self.dt - 1e-9) + 1) * self.dt, d_new)
        flat = p.reshape(p.shape[0], -1)
        out = np.stack([np.interp(t_new / self.factor, t_old, flat[:, j])
                        for j in range(flat.shape[1])], axis=-1)
        out = out.reshape(len(t_new), *p.shape[1:])
        return d_new, out if np.ndim(path) == 3 else out[:, 0, :]

    def true_mean_durations(self) -> dict[str, float]:
        return {t: v * self.factor for t, v in self.base.true_mean_durations().items()}

    def true_std_durations(self) -> dict[str, float]:
        return {t: v * self.factor for t, v in self.base.true_std_durations().items()}


@settings_dataclass("ChangingTeammate")
class ChangingTeammate:
    """A person who is ``phases[k][1]`` from cycle ``phases[k][0]`` on (the first phase starts
    at 0), and whose durations grow by a factor (1 + drift) per cycle from ``drift_from`` on."""

    phases: Annotated[tuple[tuple[Annotated[Int, Field(ge=0)], SimulatedTeammate], ...],
                      Field(min_length=1)]
    drift: Annotated[Real, Field(gt=-0.5, lt=0.5)] = 0.0  # a fraction per cycle
    drift_from: Annotated[Int, Field(ge=0)] = 0
    dt: Positive = 0.1

    def __post_init__(self) -> None:
        if self.phases[0][0] != 0:
            raise ValueError("the first phase of a changing teammate starts at cycle 0")

    @property
    def name(self) -> str:
        label = self.phases[0][1].name + "".join(f">{p.name}@{c}" for c, p in self.phases[1:])
        return label + (f"~{self.drift:+g}@{self.drift_from}" if self.drift else "")

    def at(self, cycle: int) -> SimulatedTeammate:
        person = [p for c, p in self.phases if c <= cycle][-1]
        steps = max(0, cycle - self.drift_from)
        if self.drift == 0 or steps == 0:
            return person
        # capped so that a long run of practice cannot reach a duration of zero
        return Paced(person, max((1 + self.drift) ** steps, 0.2), self.dt)

    def execute(self, cycle: int, tasks: Sequence[str],
                rng: np.random.Generator) -> dict[str, HumanExecution]:
        return perform_all(self.at(cycle), tasks, rng)

    def perform(self, task: str, rng: np.random.Generator) -> tuple[float, np.ndarray]:
        """As the person is at the start (the protocol's single-person view)."""
        return self.at(0).perform(task, rng)

    def true_mean_durations(self) -> dict[str, float]:
        return self.at(0).true_mean_durations()

    def true_std_durations(self) -> dict[str, float]:
        return self.at(0).true_std_durations()


def changing_teammate(world: World, human: str, change: str | None, drift: float = 0.0,
                      drift_from: int = 0) -> SimulatedTeammate:
    """The world's teammate ``human``, changing as ``change`` (spec) and ``drift`` say; the
    plain teammate when neither is set. ValueError on an unknown name or a bad spec."""
    first = world.teammate(human)
    if change is None and drift == 0:
        return first
    phases: list[tuple[int, SimulatedTeammate]] = [(0, first)]
    for name, cycle in parse_changes(change) if change else []:
        if name not in world.teammate_names:
            raise ValueError(f"unknown teammate {name!r} in the change {change!r}; one of "
                             f"{', '.join(world.teammate_names)}")
        phases.append((cycle, world.teammate(name)))
    return ChangingTeammate(tuple(phases), drift, drift_from, world.dt)
