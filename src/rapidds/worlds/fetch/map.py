"""The fetch game, the paper's running example ("Example Environment", Fig. 2).

A human and a robot fetch four objects and bring each home before the next; the bottom objects
(t2, t3) must be fetched before the top ones (t0, t1). Map, in metres (y up, 5 columns per m)::

    10 +--------------------------------------------------+
       |    t0     ~ ~ far outside routes (y 9.4) ~ ~  t1  |
   8.2 |       ##                                ##       |  ## fences
       |       ##  H                           R ##       |  H, R homes
       |       ##                                ##       |
   5.2 |       ##############        ##############       |  ## blocks
       |   :   ##############   ||   ##############   :   |  || central corridor
   2.4 |   :   ##############   ||   ##############   :   |  :  edge lanes
       |   :                                          :   |
       |          t2                          t3          |
     0 +--------------------------------------------------+
       0                        5                        10

Points: human home H (2.2, 7.0), robot home R (7.8, 7.0); objects t0 (1.0, 9.4), t1 (9.0, 9.4),
t2 (2.2, 1.0), t3 (7.8, 1.0). Walls: two blocks, y in [2.4, 5.2], x in [1.4, 4.2] and
[5.8, 8.6], leave three passages from the upper room to the bottom room: the 1.6 m central
corridor (x in [4.2, 5.8]) and one lane along each edge. Two fences (x in [1.4, 1.7] and
[8.3, 8.6], y in [5.2, 8.2]) shut the edge lanes off from the homes, so an edge lane can only be
entered over the top of its fence.

Routes (human's given; the robot's are the mirror image x -> 10 - x with t0<->t1, t2<->t3):

* "middle" (t2, t3): home -> corridor top (5, 5.5) -> corridor bottom (5, 1.9) -> object;
  round trip 19.4 m. Both agents' middle routes share the corridor: run at once at equal
  speeds they meet in it (time-synchronised distance 0).
* "outside" (t2, t3): along the edge lane on the object's side of the map. For the object on
  the agent's own side (human t2, robot t3) it climbs over the fence and runs down the lane:
  round trip 23.8 m, 23 % longer than the middle route. It never comes nearer than 2.9 m to the
  other agent's middle route as a path, and at equal times it stays more than 3 m from the
  other agent walking the middle route at any speed from 2 to 5.5 m/s against the robot's 4.
  For the object on the far side it crosses the top of the map (y = 9.4) and runs down the
  other agent's edge lane (round trip 37.3 m). It passes within 1.5 m of the other agent's
  home, so it avoids that agent only while the agent is away: by more than 3 m at equal
  speeds, by about 2.3 m at the worst mix of speeds.
* "direct" (t0, t1): the only route; the far top object is reached diagonally, 2 m above the
  other agent's home.

This reproduces the paper's trade-off. At the robot's 4 m/s the middle route to its own bottom
object takes 4.8 s and the outside one 6.0 s. With beta = 1/m, the spatial cost S of the robot's
middle route against a population-mixed prior is about 0.4 and against a person who takes the
middle route about 0.85 (outside: below 0.05), so gamma * dS is about 0.65 s before the person
is known (the middle route wins) and about 1.4 s once they are known to take the middle route
(the outside route wins when the robot's task is on the critical path).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from rapidds.problem import Agent
from rapidds.worlds.geometry import Rect

__all__ = [
    "DESCRIPTIONS",
    "HOMES",
    "HUMAN_VIA",
    "MIRROR_TASK",
    "MODES",
    "OBJECTS",
    "PRECEDENCE",
    "SIZE",
    "TASK_IDS",
    "WALLS",
    "Route",
    "mirror",
]

SIZE = 10.0
TASK_IDS: tuple[str, ...] = ("t0", "t1", "t2", "t3")
PRECEDENCE: tuple[tuple[str, str], ...] = (("t2", "t0"), ("t2", "t1"), ("t3", "t0"), ("t3", "t1"))
MODES: dict[str, tuple[str, ...]] = {
    "t0": ("direct",),
    "t1": ("direct",),
    "t2": ("middle", "outside"),
    "t3": ("middle", "outside"),
}
WALLS: tuple[Rect, ...] = (
    Rect(1.4, 2.4, 4.2, 5.2),  # left block
    Rect(5.8, 2.4, 8.6, 5.2),  # right block
    Rect(1.4, 5.2, 1.7, 8.2),  # left fence
    Rect(8.3, 5.2, 8.6, 8.2),  # right fence
)
HOMES: dict[Agent, tuple[float, float]] = {"human": (2.2, 7.0), "robot": (7.8, 7.0)}
OBJECTS: dict[str, tuple[float, float]] = {
    "t0": (1.0, 9.4),
    "t1": (9.0, 9.4),
    "t2": (2.2, 1.0),
    "t3": (7.8, 1.0),
}
DESCRIPTIONS = {
    "t0": "fetch the top-left object",
    "t1": "fetch the top-right object",
    "t2": "fetch the bottom-left object",
    "t3": "fetch the bottom-right object",
}
# Human (left-side) one-way routes between home and object; the robot's are mirrored.
HUMAN_VIA: dict[tuple[str, str], tuple[tuple[float, float], ...]] = {
    ("t0", "direct"): ((2.2, 8.7),),
    ("t1", "direct"): (),
    ("t2", "middle"): ((5.0, 5.5), (5.0, 1.9)),
    ("t3", "middle"): ((5.0, 5.5), (5.0, 1.9)),
    ("t2", "outside"): ((2.2, 8.7), (0.7, 8.7), (0.7, 1.6)),
    ("t3", "outside"): ((2.5, 9.4), (9.3, 9.4), (9.3, 1.6)),
}
MIRROR_TASK = {"t0": "t1", "t1": "t0", "t2": "t3", "t3": "t2"}


def mirror(p: np.ndarray) -> np.ndarray:
    q = np.array(p, dtype=float)
    q[..., 0] = SIZE - q[..., 0]
    return q


@dataclass(frozen=True, eq=False)
class Route:
    """A round trip home -> object -> home as a polyline, walked at constant speed.

    points: (W, 2) waypoints, first and last the home. goal: index of the object in ``points``.
    Positions are looked up by arc length, so one route serves any speed or timing.
    """

    points: np.ndarray
    goal: int

    @cached_property
    def cumulative(self) -> np.ndarray:
        """(W,) arc length at each waypoint."""
        seg = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        return np.concatenate([[0.0], np.cumsum(seg)])

    @property
    def length(self) -> float:
        return float(self.cumulative[-1])

    @property
    def goal_arc(self) -> float:
        """Arc length at which the object is reached."""
        return float(self.cumulative[self.goal])

    def jittered(self, rng: np.random.Generator, sd: float) -> Route:
        """Every via point moved by N(0, sd^2) per axis; home and object stay exact."""
        pts = self.points.copy()
        movable = np.ones(len(pts), dtype=bool)
        movable[[0, self.goal, len(pts) - 1]] = False
        pts[movable] += rng.normal(0.0, sd, size=(int(movable.sum()), 2))
        return Route(pts, self.goal)

    def at(self, arc: np.ndarray, wobble: np.ndarray | None = None) -> np.ndarray:
        """(T, 2) positions at arc lengths ``arc`` (T,), clipped to [0, length].

        wobble: optional (2, K, 2) smooth noise, leg (out, back) x harmonic x axis:
        offset = sum_k wobble[leg, k] * sin((k + 1) pi u), u the fraction of the leg walked, so
        it vanishes at home and at the object and never spoils reaching them.
        """
        s = np.clip(np.asarray(arc, dtype=float), 0.0, self.length)
        cum = self.cumulative
        pos = np.stack([np.interp(s, cum, self.points[:, i]) for i in range(2)], axis=-1)
        if wobble is None:
            return pos
        g = self.goal_arc
        back = s > g
        u = np.where(back, (s - g) / max(self.length - g, 1e-9), s / max(g, 1e-9))
        k = np.arange(1, wobble.shape[1] + 1)
        basis = np.sin(np.pi * u[:, None] * k[None, :])  # (T, K)
        amp = wobble[back.astype(int)]  # (T, K, 2)
        return pos + np.einsum("tk,tkd->td", basis, amp)
