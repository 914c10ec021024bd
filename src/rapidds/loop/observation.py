"""What a person did in one cycle, in one type, and the one way tracked samples become it.

Every source of a person's data (the simulated person, the browser game, the study page, a
tracker file, a bag, the Zenoh link) hands the loop one :class:`Observation`: the person's
task events, what each task was as the loop learns it (a
:class:`~rapidds.worlds.base.HumanExecution`, the duration and the body points sampled at the
world's dt) and what they said about the robot's closeness. A source that tracked body points
turns its samples into executions with :func:`execution_of` (any number of points, any
dimension: the 2-D game avatar, the 3-D tracker), whose rows sit at start + min(k dt,
duration), k = 0 .. ceil(duration / dt), the teammates' convention; :func:`resample` is the one
interpolation behind it, which the sources with their own clocks (a bag's nanoseconds) call on
times they convert themselves.

A source is anything with ``observe(cycle) -> Observation`` (:class:`Source`); the loop's
:meth:`~rapidds.loop.run.AdaptiveRun.step` takes one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from rapidds.worlds.base import HumanExecution

if TYPE_CHECKING:
    from rapidds.execution.deployment import Deployment, Reactions
    from rapidds.loop.cycle import Cycle

__all__ = ["Observation", "Said", "Source", "Track", "execution_of", "resample", "sample_times"]


def sample_times(duration: float, dt: float) -> np.ndarray:
    """The times of a task's path rows from its start: min(k dt, duration),
    k = 0 .. ceil(duration / dt)."""
    return np.minimum(np.arange(math.ceil(duration / dt - 1e-9) + 1) * dt, duration)


def resample(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """(len(at), ...) values at ``at`` from samples (N, ...) at increasing ``times``, linearly
    interpolated per coordinate and held at the ends."""
    values = np.asarray(values, dtype=float)
    flat = values.reshape(len(values), -1)
    cols = [np.interp(at, times, flat[:, j]) for j in range(flat.shape[1])]
    return np.stack(cols, axis=-1).reshape(len(at), *values.shape[1:])


@dataclass(frozen=True)
class Track:
    """One body point's samples: times (N,) on the source's clock (s) and positions (N, d)."""

    times: np.ndarray
    positions: np.ndarray


def execution_of(task: str, start: float, duration: float, tracks: Sequence[Track] | Track,
                 dt: float) -> HumanExecution:
    """What the person did for ``task`` (started at ``start`` on the tracks' clock, lasting
    ``duration`` s): each track resampled at the world's ``dt``; a path (T, K, d) for a sequence
    of K body points, (T, d) for a single track (the game's avatar)."""
    at = start + sample_times(duration, dt)
    if isinstance(tracks, Track):
        return HumanExecution(task, float(duration), resample(tracks.times, tracks.positions, at))
    path = np.stack([resample(t.times, t.positions, at) for t in tracks], axis=1)
    return HumanExecution(task, float(duration), path)


@dataclass(frozen=True)
class Said:
    """What the person said about a cycle: their comfort answer (1-7; None: not asked) and the
    times of their "too close" signals (s into the cycle)."""

    answer: int | None
    too_close: tuple[float, ...] = ()


@dataclass
class Observation:
    """What one cycle's person did, as the loop learns it.

    human: task -> what they did (every human task of the plan the cycle ran); events: task ->
    (start, end) on the source's clock where the source saw them; order: the order they took
    their tasks in when they may choose it (None: the plan's); said: what they said (None:
    nothing, or not asked). A live cell adds what its own execution did: ``played``, a whole
    cycle already played on the loop's executor (the game under reactive execution);
    ``reacted``, the cell's reactive layer's pauses and re-plans; ``robot_durations``, the
    times the robot took per task (the cycle is realised with them); ``live``, what the record
    keeps beyond the deployment.
    """

    human: Mapping[str, HumanExecution] = field(default_factory=dict)
    events: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    order: Sequence[str] | None = None
    said: Said | None = None
    played: Deployment | None = None
    reacted: Reactions | None = None
    robot_durations: Mapping[str, float] | None = None
    live: dict[str, Any] | None = None


@runtime_checkable
class Source(Protocol):
    """Where a cycle's person data comes from: shown the planned ``cycle`` (its plan, its
    random stream, the executor a live cycle runs on), it returns what the person did."""

    def observe(self, cycle: Cycle) -> Observation:
        """What the person did in ``cycle``; blocks until they are done."""
        ...
