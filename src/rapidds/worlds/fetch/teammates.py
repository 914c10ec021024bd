"""Simulated people for the fetch game: the ground truth the planner has to learn.

A :class:`FetchTeammate` is one person's TRUE model. Per task they take one route (their choice of
"middle" or "outside" for t2 and t3), walk at their own speed and spend a handling time at the
object; their duration is Normal(mean, (cv * mean)^2) with mean = route length / speed +
handling, truncated below at half the mean (nobody fetches twice as fast as they usually do;
the truncation raises the mean by under 0.03 % for cv <= 0.15, under 1e-6 for cv = 0.1).
Every person also has a habit: their own fixed small deviation from the nominal route (seeded),
on top of which every cycle adds fresh path noise, so an individual's spatial cost is learnable
and differs from the population's.

The four archetypes of the paper's ablation cross speed with route::

    archetype      speed (m/s)  handling (s)  route for t2 and t3
    fast-middle    4.8          0.25          middle (the shared central corridor)
    fast-outside   4.8          0.25          outside (the edge lane on the object's side)
    slow-middle    2.6          0.8           middle
    slow-outside   2.6          0.8           outside

The robot moves at 4 m/s without handling time. Bottom objects by the middle route: fast
4.3 s, robot 4.8 s, slow 8.0 s. Top objects: an agent's own one is quick (human t0: fast 1.6 s,
slow 3.2 s; robot t1: 1.6 s), the other's takes longer (human t1: 3.3 / 6.4 s; robot t0: 3.6 s).
An outside walker's far bottom object takes long (t3: fast 8.1 s, slow 15.4 s). So who should
do what depends on the person.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from rapidds.worlds.base import SteadyPerson
from rapidds.worlds.fetch.map import MODES, TASK_IDS, Route
from rapidds.worlds.geometry import segments_hit_rects

if TYPE_CHECKING:
    from rapidds.worlds.fetch.world import FetchWorld

__all__ = [
    "ARCHETYPES",
    "FetchTeammate",
    "archetype",
    "population",
]

_FAST = (4.8, 0.25)
_SLOW = (2.6, 0.8)
ARCHETYPES: dict[str, tuple[tuple[float, float], str]] = {
    "fast-middle": (_FAST, "middle"),
    "fast-outside": (_FAST, "outside"),
    "slow-middle": (_SLOW, "middle"),
    "slow-outside": (_SLOW, "outside"),
}
_MIN_FRACTION = 0.5  # durations are truncated below at this fraction of the mean
_HABIT_CLEARANCE = 0.15  # metres a habitual route keeps from walls, room for per-cycle noise


@dataclass(frozen=True, eq=False)
class FetchTeammate(SteadyPerson):
    """One simulated person.

    name: label. speed: walking speed, m/s. handling: seconds spent at the object in a cycle of
    mean duration (scaled with the cycle's duration). routes: task -> mode; tasks not named
    take their first (shortest) mode. cv: duration standard deviation / mean. habit_seed,
    habit_sd: the person's fixed deviation of every via point (metres). path_noise: fresh
    via-point noise per cycle (metres; a smooth wobble of half that size is added too).
    world: the fetch world whose routes they walk.
    """

    name: str
    speed: float
    handling: float
    routes: Mapping[str, str] = field(default_factory=dict)
    cv: float = 0.1
    habit_seed: int = 0
    habit_sd: float = 0.15
    path_noise: float = 0.08
    world: FetchWorld = field(kw_only=True, repr=False)
    _habits: dict[str, Route] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        for attr in ("speed", "cv"):
            v = getattr(self, attr)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"FetchTeammate.{attr} must be a finite number > 0, got {v!r}")
        for attr in ("handling", "habit_sd", "path_noise"):
            v = getattr(self, attr)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"FetchTeammate.{attr} must be a finite number >= 0, got {v!r}")
        routes = {t: self.routes.get(t, MODES[t][0]) for t in TASK_IDS}
        for t in self.routes:
            if t not in MODES:
                raise ValueError(f"FetchTeammate.routes names unknown task {t!r}")
        for t, m in routes.items():
            if m not in MODES[t]:
                raise ValueError(f"FetchTeammate.routes[{t!r}] = {m!r}; modes are {MODES[t]}")
        object.__setattr__(self, "routes", routes)
        habits = {
            t: self._habit(t, np.random.default_rng([self.habit_seed, i]))
            for i, t in enumerate(TASK_IDS)
        }
        object.__setattr__(self, "_habits", habits)

    def route(self, task: str) -> Route:
        """The person's habitual round trip for ``task`` (their mode, their deviation)."""
        return self._habits[task]

    def duration_mean(self, task: str) -> float:
        """True mean duration of ``task``, seconds."""
        return self.route(task).length / self.speed + self.handling

    def duration_sd(self, task: str) -> float:
        return self.cv * self.duration_mean(task)

    def true_mean_durations(self) -> dict[str, float]:
        """task -> true mean duration (s): what an oracle planner knows."""
        return {t: self.duration_mean(t) for t in TASK_IDS}

    def true_std_durations(self) -> dict[str, float]:
        return {t: self.duration_sd(t) for t in TASK_IDS}

    def perform(self, task: str, rng: np.random.Generator) -> tuple[float, np.ndarray]:
        """One cycle of ``task``: (duration seconds, trajectory (T, 2)).

        Row k of the trajectory is the position at time min(k * dt, duration), T =
        ceil(duration / dt) + 1, so the first row is at home and the last row is back home. The
        person walks out, stays at the object for their handling time and walks back, at the
        constant speed that makes the whole take exactly the sampled duration. No segment
        between rows crosses a wall.
        """
        if task not in self._habits:
            raise ValueError(f"unknown fetch task {task!r}; tasks are {', '.join(TASK_IDS)}")
        mu, sd = self.duration_mean(task), self.duration_sd(task)
        d = mu
        for _ in range(100):
            d = float(rng.normal(mu, sd))
            if d > _MIN_FRACTION * mu:
                break
        else:
            d = mu
        dwell = self.handling * d / mu
        walking = d - dwell
        dt = self.world.dt
        times = np.minimum(np.arange(math.ceil(d / dt - 1e-9) + 1) * dt, d)
        habit = self.route(task)
        for _ in range(50):
            noisy = habit.jittered(rng, self.path_noise)
            wobble = rng.normal(0.0, self.path_noise / 2, size=(2, 2, 2))
            traj = noisy.at(_arc_at(times, noisy, walking, dwell), wobble)
            if not self.world.collides(traj):
                return d, traj
        return d, habit.at(_arc_at(times, habit, walking, dwell))

    def _habit(self, task: str, rng: np.random.Generator) -> Route:
        nominal = self.world.route("human", task, self.routes[task])
        if self.habit_sd == 0:
            return nominal
        for _ in range(100):
            r = nominal.jittered(rng, self.habit_sd)
            dense = r.at(np.linspace(0.0, r.length, int(r.length / 0.05) + 2))
            lo, hi = self.world.bounds
            inside = bool(((dense >= lo + _HABIT_CLEARANCE) & (dense <= hi - _HABIT_CLEARANCE))
                          .all())
            if inside and not _near_wall(self.world, dense):
                return r
        return nominal


def _near_wall(world: FetchWorld, dense: np.ndarray) -> bool:
    return bool(segments_hit_rects(dense, world.obstacles(), margin=_HABIT_CLEARANCE))


def _arc_at(times: np.ndarray, route: Route, walking: float, dwell: float) -> np.ndarray:
    """(T,) arc length along ``route`` at ``times``: out at constant speed, wait ``dwell`` at
    the object, back at the same speed; the walk takes ``walking`` seconds in total."""
    v = route.length / walking
    g = route.goal_arc
    arrive = g / v
    return np.where(
        times <= arrive, v * times,
        np.where(times <= arrive + dwell, g, g + v * (times - arrive - dwell)),
    )


def archetype(name: str, world: FetchWorld) -> FetchTeammate:
    """One of the paper's four archetypes: "fast-middle", "fast-outside", "slow-middle",
    "slow-outside" (speed x route for t2 and t3; see the module docstring)."""
    if name not in ARCHETYPES:
        raise ValueError(f"unknown archetype {name!r}; choose from {', '.join(ARCHETYPES)}")
    (speed, handling), mode = ARCHETYPES[name]
    return FetchTeammate(
        name=name,
        speed=speed,
        handling=handling,
        routes={"t2": mode, "t3": mode},
        habit_seed=1000 + list(ARCHETYPES).index(name),
        world=world,
    )


def population(n: int, rng: np.random.Generator,
               world: FetchWorld) -> list[FetchTeammate]:
    """``n`` other people, the source of the priors: speed U(2.4, 5.0) m/s, handling
    U(0.2, 1.0) s, cv U(0.06, 0.15), and for t2 and t3 independently the middle or the
    outside route with probability 1/2 each, so the population is mixed in both."""
    if n < 1:
        raise ValueError(f"population size must be >= 1, got {n}")
    people = []
    for i in range(n):
        people.append(
            FetchTeammate(
                name=f"person-{i}",
                speed=float(rng.uniform(2.4, 5.0)),
                handling=float(rng.uniform(0.2, 1.0)),
                routes={t: str(rng.choice(MODES[t])) for t in ("t2", "t3")},
                cv=float(rng.uniform(0.06, 0.15)),
                habit_seed=int(rng.integers(2**31)),
                world=world,
            )
        )
    return people
