"""Simulated people at the painting cell: the ground truth the planner has to learn.

A person's body is K = 4 points, in this order: left hand, right hand, left elbow, right elbow
(the forearms are the segments between them). Hands follow per-task keyframes; each elbow
follows from its hand by two-link inverse kinematics from a fixed shoulder (upper arm 0.30 m,
forearm 0.28 m, elbow bent down and outwards).

Tasks (keyframe phases are fractions of the task's duration):

* ``prep_vise``: both hands go to the vise's screw handle, turn it (two circles of 3 cm) and
  come back to rest.
* ``secure_piece``: the chosen hand reaches to the workpiece rack on its own side, which stands
  in front of that side's paint tray, picks the piece, carries it over to the vise and holds it
  while the jaws close, then returns; the other hand stays at rest.
* ``brush``: the chosen hand brushes along the piece's top (five strokes) and returns.

Everyone is generated left-handed and mirrored in the plane x = 0 when right-handed (x negated,
left and right body points swapped), random draws included, so a right-handed person is the
exact mirror image of the left-handed twin with the same seeds: no hand is special-cased.

A person has true mean durations per task; one execution lasts Normal(mean, (cv * mean)^2)
truncated below at half the mean (as in the fetch world). Their habit, a fixed deviation of
every keyframe (``habit_sd``, seeded by ``habit_seed``), makes their paths their own; every
execution adds fresh keyframe noise (``path_noise``). A hand that waits at rest through a task
gets a quarter of both: it shifts a little, it does not wander.

Archetypes: the hand used x brushing faster or slower than the robot (its direct brush takes
4.65 s)::

    archetype    hand   prep (s)  secure (s)  brush (s)
    left-fast    left   6.0       5.0         3.4
    left-slow    left   6.0       5.0         6.6
    right-fast   right  6.0       5.0         3.4
    right-slow   right  6.0       5.0         6.6

:func:`population`: half of the people left-, half right-handed, brushing in U(3.0, 6.6) s
(mean 4.8 s, the robot's pace), prep U(5.6, 6.4) s, secure U(4.6, 5.4) s, cv U(0.06, 0.15).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from rapidds.worlds.base import SteadyPerson
from rapidds.worlds.painting.scene import LAYOUT, CellLayout

__all__ = [
    "ARCHETYPES",
    "BODY_POINTS",
    "HANDS",
    "HUMAN_TASKS",
    "SPEEDS",
    "PaintingTeammate",
    "archetype",
    "individual",
    "mirror_body",
    "population",
    "rest_points",
]

HUMAN_TASKS: tuple[str, ...] = ("prep_vise", "secure_piece", "brush")
HANDS: tuple[str, ...] = ("left", "right")
BODY_POINTS: tuple[str, ...] = ("left_hand", "right_hand", "left_elbow", "right_elbow")
_SWAP = np.array([1, 0, 3, 2])       # left <-> right body points
_MIN_FRACTION = 0.5                   # durations truncated below at this fraction of the mean
REST_HAND = (-0.16, -0.29, 0.03)      # left hand at rest on the table edge (right: mirrored)
ARCHETYPES: dict[str, tuple[str, float]] = {
    "left-fast": ("left", 3.4),
    "left-slow": ("left", 6.6),
    "right-fast": ("right", 3.4),
    "right-slow": ("right", 6.6),
}
_PREP, _SECURE = 6.0, 5.0


def mirror_body(points: np.ndarray) -> np.ndarray:
    """Body points (..., K, 3) reflected in the plane x = 0: x negated, left and right swapped."""
    p = np.asarray(points, dtype=float)[..., _SWAP, :].copy()
    p[..., 0] *= -1.0
    return p


def _elbows(hands: np.ndarray, layout: CellLayout) -> np.ndarray:
    """(T, 2, 3) elbow positions for (T, 2, 3) left / right hand positions."""
    out = np.empty_like(hands)
    a, b = layout.upper_arm, layout.forearm
    for side, (shoulder, outward) in enumerate(((layout.left_shoulder, -1.0),
                                                (layout.right_shoulder, 1.0))):
        s = np.asarray(shoulder, dtype=float)
        v = hands[:, side] - s
        d = np.clip(np.linalg.norm(v, axis=-1), abs(a - b) + 1e-6, a + b - 1e-6)
        u = v / np.linalg.norm(v, axis=-1, keepdims=True)
        along = (a * a - b * b + d * d) / (2.0 * d)
        h = np.sqrt(np.maximum(a * a - along * along, 0.0))
        pole = np.array([0.5 * outward, 0.0, -1.0])
        w = pole - (u @ pole)[:, None] * u
        w /= np.linalg.norm(w, axis=-1, keepdims=True)
        out[:, side] = s + along[:, None] * u + h[:, None] * w
    return out


def rest_points(layout: CellLayout = LAYOUT) -> np.ndarray:
    """(K, 3) the body points of a person at rest, hands on the table's edge."""
    left = np.array(REST_HAND)
    hands = np.stack([left, left * np.array([-1.0, 1.0, 1.0])])[None]
    return np.concatenate([hands, _elbows(hands, layout)], axis=1)[0]


def _v(x: float, y: float, z: float) -> np.ndarray:
    return np.array([x, y, z])


def _keyframes(task: str, layout: CellLayout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left-handed keyframes of ``task``: (F,) phases in [0, 1] and (F, 3) positions of the
    left and of the right hand."""
    rest_l = np.array(REST_HAND)
    rest_r = rest_l * np.array([-1.0, 1.0, 1.0])
    if task == "prep_vise":
        handle = np.array(layout.vise_handle.center) + np.array([0.0, -0.02, 0.02])
        turn = np.linspace(0.0, 4.0 * np.pi, 9)[1:-1]
        circle = 0.03 * np.stack([np.cos(turn), np.zeros_like(turn), np.sin(turn)], -1)
        grip_l, grip_r = handle + _v(-0.035, 0.0, 0.0), handle + _v(0.035, 0.0, 0.0)
        phase = np.concatenate([[0.0, 0.2], np.linspace(0.25, 0.75, len(turn)), [0.8, 1.0]])
        left = np.vstack([rest_l, grip_l, grip_l + circle, grip_l, rest_l])
        right = np.vstack([rest_r, grip_r, grip_r - circle * _v(1.0, 1.0, -1.0), grip_r, rest_r])
        return phase, left, right
    if task == "secure_piece":
        rack = np.array(layout.left_rack.center) + _v(0.0, 0.0, layout.left_rack.half[2] + 0.03)
        jaws = np.array(layout.workpiece.center) + _v(-0.07, 0.0, 0.0)
        phase = np.array([0.0, 0.18, 0.28, 0.38, 0.58, 0.68, 0.85, 1.0])
        left = np.vstack([rest_l, rack + _v(0.0, 0.0, 0.06), rack, rack + _v(0.0, 0.0, 0.08),
                          jaws + _v(0.0, 0.0, 0.10), jaws, jaws, rest_l])
        right = np.repeat(rest_r[None], len(phase), axis=0)
        return phase, left, right
    if task == "brush":
        top = np.array(layout.workpiece.center) + _v(0.0, -0.03, layout.workpiece.half[2] + 0.06)
        ends = [top + _v(-0.04, 0.0, 0.0), top + _v(0.04, 0.0, 0.0)]
        strokes = [ends[k % 2] for k in range(6)]
        phase = np.concatenate([[0.0], np.linspace(0.15, 0.85, 6), [1.0]])
        left = np.vstack([rest_l, *strokes, rest_l])
        right = np.repeat(rest_r[None], len(phase), axis=0)
        return phase, left, right
    raise ValueError(f"unknown human task {task!r}; tasks are {', '.join(HUMAN_TASKS)}")


def _idle_scale(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """(2, 1, 1) deviation scale per hand: a quarter for a hand that waits at rest through the
    task (it shifts a little, it does not wander), 1 for a hand that works."""
    idle = [bool(np.ptp(h, axis=0).max() == 0.0) for h in (left, right)]
    return np.where(idle, 0.25, 1.0)[:, None, None]


def _smooth(u: np.ndarray) -> np.ndarray:
    """Minimum-jerk progress between two keyframes (zero speed at each)."""
    return u ** 3 * (10.0 - 15.0 * u + 6.0 * u ** 2)


@dataclass(frozen=True, eq=False)
class PaintingTeammate(SteadyPerson):
    """One simulated person at the painting cell (see the module docstring).

    name: label. hand: "left" or "right", used for Secure Piece and Brush. means: task ->
    true mean duration (s); tasks not named take the archetypes' 6.0 / 5.0 / 5.0 s. cv:
    duration standard deviation / mean. habit_seed, habit_sd: the person's fixed deviation of
    every keyframe (m). path_noise: fresh keyframe noise per execution (m). dt: seconds per
    path row (the world's). layout: the cell.
    """

    name: str
    hand: str
    means: Mapping[str, float] = field(default_factory=dict)
    cv: float = 0.1
    habit_seed: int = 0
    habit_sd: float = 0.02
    path_noise: float = 0.01
    dt: float = 0.15
    layout: CellLayout = field(default=LAYOUT, repr=False)
    _habits: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.hand not in HANDS:
            raise ValueError(f"PaintingTeammate.hand must be 'left' or 'right', got {self.hand!r}")
        for attr in ("cv", "dt"):
            v = getattr(self, attr)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"PaintingTeammate.{attr} must be a finite number > 0, got {v!r}")
        for attr in ("habit_sd", "path_noise"):
            v = getattr(self, attr)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"PaintingTeammate.{attr} must be a finite number >= 0, "
                                 f"got {v!r}")
        unknown = sorted(set(self.means) - set(HUMAN_TASKS))
        if unknown:
            raise ValueError(f"PaintingTeammate.means names unknown task(s) {', '.join(unknown)}; "
                             f"tasks are {', '.join(HUMAN_TASKS)}")
        means = {"prep_vise": _PREP, "secure_piece": _SECURE, "brush": 5.0, **self.means}
        for t, m in means.items():
            if not (isinstance(m, int | float) and math.isfinite(m) and m > 0):
                raise ValueError(f"PaintingTeammate.means[{t!r}] must be a finite number > 0, "
                                 f"got {m!r}")
        object.__setattr__(self, "means", {t: float(means[t]) for t in HUMAN_TASKS})
        habits = {}
        for i, task in enumerate(HUMAN_TASKS):
            phase, left, right = _keyframes(task, self.layout)
            rng = np.random.default_rng([self.habit_seed, i])
            dev = rng.normal(0.0, self.habit_sd, size=(2, *left.shape)) * _idle_scale(left, right)
            dev[:, [0, -1]] = 0.0  # every task starts and ends at rest
            habits[task] = (phase, left + dev[0], right + dev[1])
        object.__setattr__(self, "_habits", habits)

    # -- the SimulatedTeammate protocol (at and execute: SteadyPerson) -------------------------
    def true_mean_durations(self) -> dict[str, float]:
        """task -> true mean duration (s)."""
        return dict(self.means)

    def true_std_durations(self) -> dict[str, float]:
        """task -> true standard deviation of the duration (s)."""
        return {t: self.cv * m for t, m in self.means.items()}

    def perform(self, task: str, rng: np.random.Generator) -> tuple[float, np.ndarray]:
        """One execution: (duration s, path (T, K, 3)), row k at time min(k * dt, duration),
        T = ceil(duration / dt) + 1, first and last row at rest."""
        if task not in self._habits:
            raise ValueError(f"unknown painting human task {task!r}; tasks are "
                             f"{', '.join(HUMAN_TASKS)}")
        mu = self.means[task]
        d = mu
        for _ in range(100):
            d = float(rng.normal(mu, self.cv * mu))
            if d > _MIN_FRACTION * mu:
                break
        else:
            d = mu
        phase, left, right = self._habits[task]
        noise = rng.normal(0.0, self.path_noise, size=(2, *left.shape)) * _idle_scale(left, right)
        noise[:, [0, -1]] = 0.0
        times = np.minimum(np.arange(math.ceil(d / self.dt - 1e-9) + 1) * self.dt, d)
        path = self._path(times / d, phase, left + noise[0], right + noise[1])
        return d, path

    # -- geometry -------------------------------------------------------------------------------
    def nominal_path(self, task: str, n: int = 41) -> np.ndarray:
        """(n, K, 3): the person's habitual path of ``task`` (no per-execution noise) at n
        evenly spaced phases."""
        phase, left, right = self._habits[task]
        return self._path(np.linspace(0.0, 1.0, n), phase, left, right)

    def _path(self, u: np.ndarray, phase: np.ndarray, left: np.ndarray, right: np.ndarray,
              ) -> np.ndarray:
        """(T, K, 3) body points at phases ``u``; keyframes are those of a left-handed person
        and are mirrored for a right-handed one."""
        k = np.clip(np.searchsorted(phase, u, side="right") - 1, 0, len(phase) - 2)
        frac = _smooth(np.clip((u - phase[k]) / (phase[k + 1] - phase[k]), 0.0, 1.0))
        hands = np.stack([left[k] + frac[:, None] * (left[k + 1] - left[k]),
                          right[k] + frac[:, None] * (right[k + 1] - right[k])], axis=1)
        body = np.concatenate([hands, _elbows(hands, self.layout)], axis=1)
        return body if self.hand == "left" else mirror_body(body)


def archetype(name: str, *, dt: float = 0.15, layout: CellLayout = LAYOUT) -> PaintingTeammate:
    """One of "left-fast", "left-slow", "right-fast", "right-slow": the hand used for Secure
    Piece and Brush x brushing faster or slower than the robot. Mirror twins (left-fast and
    right-fast) share their seeds, so one is exactly the other's mirror image."""
    if name not in ARCHETYPES:
        raise ValueError(f"unknown painting teammate {name!r}; choose from "
                         f"{', '.join(ARCHETYPES)}")
    hand, brush = ARCHETYPES[name]
    speed = name.split("-")[1]
    return PaintingTeammate(name=name, hand=hand, means={"brush": brush},
                            habit_seed=2000 + ("fast", "slow").index(speed), dt=dt, layout=layout)


def population(n: int, rng: np.random.Generator, *, dt: float = 0.15,
               layout: CellLayout = LAYOUT) -> list[PaintingTeammate]:
    """``n`` other people, the source of the priors: exactly half left-handed (the extra one of
    an odd n is drawn), in random order; brushing U(3.0, 6.6) s, prep U(5.6, 6.4) s, secure
    U(4.6, 5.4) s, cv U(0.06, 0.15), own habits."""
    if n < 1:
        raise ValueError(f"population size must be >= 1, got {n}")
    hands = ["left"] * (n // 2) + ["right"] * (n // 2)
    if n % 2:
        hands.append(str(rng.choice(HANDS)))
    hands = [hands[i] for i in rng.permutation(n)]
    people = []
    for i, hand in enumerate(hands):
        means = {"prep_vise": float(rng.uniform(5.6, 6.4)),
                 "secure_piece": float(rng.uniform(4.6, 5.4)),
                 "brush": float(rng.uniform(3.0, 6.6))}
        people.append(PaintingTeammate(
            name=f"person-{i}", hand=hand, means=means, cv=float(rng.uniform(0.06, 0.15)),
            habit_seed=int(rng.integers(2**31)), dt=dt, layout=layout))
    return people


SPEEDS: dict[str, tuple[float, float]] = {"fast": (3.0, 3.8), "slow": (6.2, 7.0)}
"""Brushing time range (s) of a person primed to brush fast or slow: around the archetypes'
3.4 s and 6.6 s, on either side of the robot's 4.65 s."""


def individual(name: str, hand: str, speed: str, rng: np.random.Generator, *,
               dt: float = 0.15, layout: CellLayout = LAYOUT) -> PaintingTeammate:
    """One person primed to use ``hand`` and brush ``speed`` ("fast" / "slow"), otherwise their
    own: brushing U(SPEEDS[speed]) s, prep U(5.6, 6.4) s, secure U(4.6, 5.4) s, cv U(0.06,
    0.15) and their own habits (paths), as :func:`population` draws them. A simulated study
    participant."""
    if hand not in HANDS:
        raise ValueError(f"hand must be one of {', '.join(HANDS)}, got {hand!r}")
    if speed not in SPEEDS:
        raise ValueError(f"speed must be one of {', '.join(SPEEDS)}, got {speed!r}")
    means = {"prep_vise": float(rng.uniform(5.6, 6.4)),
             "secure_piece": float(rng.uniform(4.6, 5.4)),
             "brush": float(rng.uniform(*SPEEDS[speed]))}
    return PaintingTeammate(name=name, hand=hand, means=means, cv=float(rng.uniform(0.06, 0.15)),
                            habit_seed=int(rng.integers(2**31)), dt=dt, layout=layout)


def population_statistics(
    people: Sequence[PaintingTeammate], n_samples: int, rng: np.random.Generator,
) -> tuple[dict[str, list[float]], dict[str, list[np.ndarray]]]:
    """Every person performs every human task ``n_samples`` times: task -> durations and
    (T, K, 3) paths, person-major."""
    if n_samples < 1:
        raise ValueError(f"n_samples must be >= 1, got {n_samples}")
    durations: dict[str, list[float]] = {t: [] for t in HUMAN_TASKS}
    paths: dict[str, list[np.ndarray]] = {t: [] for t in HUMAN_TASKS}
    for person in people:
        for task in HUMAN_TASKS:
            for _ in range(n_samples):
                d, path = person.perform(task, rng)
                durations[task].append(d)
                paths[task].append(path)
    return durations, paths
