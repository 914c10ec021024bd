"""What a person's task and tracked motion can plausibly be in a world: one owner for every
source that brings them in (the live hub, ``observe`` on a bag, the study's tracker upload and
typed-in durations).

* **Task bound** (:func:`world_task_bound`): no real task takes longer; a longer one is a typo,
  a wrong file or a forged event, and refusing it also bounds the path the loop allocates
  (duration / dt rows).
* **Plausible tracking** (:class:`Plausibility`): a tracked body point must lie in the world's
  workspace grown by :data:`WORKSPACE_MARGIN` and must not move faster than
  :data:`MAX_BODY_SPEED` (plus :data:`NOISE`) since its last plausible sample. Both worlds here
  are in metres (painting's table, fetch's 10 m map), so these constants are in metres too.
  The speed is ISO 13855's walking speed with a stated margin, not a hand's top speed: a
  tracked point that jumps metres in one sample is a tracker's glitch or a forgery, and a
  margin this wide never drops a real motion of a person at work. A sample is checked against
  the last plausible one of its source, so one glitch is dropped and the real stream goes on;
  a wrong first sample is left behind within a fraction of a second, as the allowed step grows
  with the time since.
* **Mostly implausible** (:func:`mostly_implausible`): a task whose samples were mostly dropped
  is not learned (the source refuses it: the hub stops the cycle, ``observe`` and the study
  name the task).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from rapidds.worlds.base import World

__all__ = [
    "MAX_BODY_SPEED",
    "NOISE",
    "WALKING_SPEED",
    "WORKSPACE_MARGIN",
    "Plausibility",
    "mostly_implausible",
    "plausible_mask",
    "world_task_bound",
]

WALKING_SPEED = 1.6
"""ISO 13855's approach speed of a walking person, m/s."""
SPEED_MARGIN = 5.0
"""Factor on :data:`WALKING_SPEED`: hands move faster than a walk (ISO 13855 takes 2 m/s for a
reaching arm), and a quick reach peaks higher still; five times the walk leaves room for all
of it and is still far below a tracking glitch (a 5 m jump between samples 0.15 s apart is
33 m/s)."""
MAX_BODY_SPEED = WALKING_SPEED * SPEED_MARGIN
"""Fastest plausible body-point speed, m/s (8 m/s)."""
NOISE = 0.05
"""Metres a point may move beyond ``MAX_BODY_SPEED x dt``: a tracker's jitter over samples that
come close together (1 ms apart, 1 cm of noise would read as 10 m/s)."""
WORKSPACE_MARGIN = 0.5
"""Metres a tracked point may lie outside the world's workspace box: an elbow or a step beside
the table is real; a wrist 4 m away from a 1.4 m table is not."""


def world_task_bound(world: World) -> float:
    """Seconds no real task of ``world`` can take: 20 x the longest mean human duration of its
    prior, rounded up to 10 s, at least 60 s (fetch 180 s, painting 120 s). A typed duration,
    a tracked task or a live event pair longer than this is a typo, a wrong file or a forgery,
    and refusing it also bounds the path the loop allocates (duration / dt rows)."""
    means = [t.human_mean for t in world.problem().tasks if t.human_mean is not None]
    return max(60.0, 10.0 * math.ceil(2.0 * max(means, default=0.0)))


def _box(world: World) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = (np.asarray(b, dtype=float) for b in world.workspace_bounds)
    return lo - WORKSPACE_MARGIN, hi + WORKSPACE_MARGIN


class Plausibility:
    """The check of one stream of tracked samples, per source (a body point, a topic): each
    sample is compared with the last plausible one of its source; see the module docstring."""

    def __init__(self, world: World):
        self.lo, self.hi = _box(world)
        self._last: dict[str, tuple[float, np.ndarray]] = {}

    def check(self, source: str, t: float, position: Sequence[float] | np.ndarray) -> str | None:
        """None if the sample at time ``t`` (s) is plausible (it becomes the source's last);
        else why not, in a few words."""
        p = np.asarray(position, dtype=float)
        if p.shape != self.lo.shape or not np.isfinite(p).all():
            return "not a finite point of this world"
        if (p < self.lo).any() or (p > self.hi).any():
            return (f"({', '.join(f'{v:.3g}' for v in p)}) is over {WORKSPACE_MARGIN:g} m "
                    "outside the workspace")
        last = self._last.get(source)
        if last is not None:
            step = float(np.linalg.norm(p - last[1]))
            if step > MAX_BODY_SPEED * max(t - last[0], 0.0) + NOISE:
                return (f"moved {step:.3g} m in {max(t - last[0], 0.0):.3g} s, faster than "
                        f"{MAX_BODY_SPEED:g} m/s")
        self._last[source] = (t, p)
        return None


def plausible_mask(world: World, times: np.ndarray, positions: np.ndarray,
                   ) -> tuple[np.ndarray, str | None]:
    """Which samples of one source (``times`` (N,) s in increasing order, ``positions``
    (N, d)) are plausible, and the first reason a sample was not (None: all were)."""
    check = Plausibility(world)
    keep = np.ones(len(times), dtype=bool)
    first = None
    for i, (t, p) in enumerate(zip(times, positions, strict=True)):
        why = check.check("", float(t), p)
        if why is not None:
            keep[i] = False
            first = first or why
    return keep, first


def mostly_implausible(kept: int, dropped: int) -> bool:
    """A task's samples of one body point were mostly dropped as implausible: not learned."""
    return dropped > kept
