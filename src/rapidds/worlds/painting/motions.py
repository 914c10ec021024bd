"""The robot's demonstrated motions in the painting cell: waypoints, inverse kinematics, timing.

Every robot task has two modes, each a chain of tool-tip waypoints solved once by inverse
kinematics (cached) and joined in joint space:

* ``mix_l`` "direct": rest -> 8 cm above the near (person-side) half of the left tray -> dip
  -> up -> above the bowl -> dip -> up -> rest. "avoidant": the same through the far (robot-side)
  half of the tray, from 30 cm above it and 25 cm above the bowl, so the arm stays higher and
  farther from where the person's left hand works.
* ``mix_r``: the mirror image of ``mix_l`` (joints 1, 3, 5, 7 negated), so nothing favours
  either side.
* ``brush`` "direct": rest -> 6 cm above one end of the workpiece -> three strokes along its
  top -> up -> rest; "avoidant": the same, entering and leaving through a point 25 cm above
  and 12 cm behind the piece (on the robot's side).

Timing: the joints move along the polyline through the waypoints, stopping only at rest, in
the containers and at the ends of brush strokes (passing the waypoints above them without
stopping). Along a section between two stops the progress s (seconds the section would take
with the slowest joint always at its limit: ds = max_i |dq_i| / v_i, v_i the Franka limits
2.175 rad/s for joints 1-4 and 2.61 rad/s for joints 5-7) follows a trapezoidal speed profile
with half-cosine ramps over a quarter of the section at each end, peaking at f = ``PACE[mode]``;
so no joint ever exceeds f times its limit. The direct motions move at f = 0.7, the avoidant
ones at f = 0.39: a robot that keeps its distance also slows down, as speed and separation
monitoring (ISO/TS 15066) asks near people. Dips pause ``DWELL`` s; a brush stroke takes
``STROKE`` s.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np

from rapidds.worlds.painting.kinematics import (
    arm_kinematics,
    mirror_joints,
    solve_ik,
)
from rapidds.worlds.painting.scene import LAYOUT, CellLayout, model_key

__all__ = [
    "MODES",
    "PACE",
    "REST_TOOL",
    "ROBOT_TASKS",
    "Motion",
    "nominal_motion",
    "rest_pose",
]

ROBOT_TASKS: tuple[str, ...] = ("mix_l", "mix_r", "brush")
MODES: tuple[str, ...] = ("direct", "avoidant")
PACE: dict[str, float] = {"direct": 0.7, "avoidant": 0.39}  # peak fraction of the speed limits
RAMP = 0.25           # fraction of a section spent speeding up (and again slowing down)
DWELL = 0.35          # s, scooping in a tray, pouring into the bowl
STROKE = 0.8          # s, one brush stroke along the piece
REST_TOOL = (0.0, 0.25, 0.35)   # tool tip at rest: above the robot's half of the table
_REST_SEED = (0.0, -0.9, 0.0, -2.5, 0.0, 0.1, 0.0)
DIP = 0.02            # m, how deep the tool goes below a container's rim
NEAR_FAR = 0.07       # m, the dip's offset from the tray centre, towards / away from the person
LOW, HIGH = 0.08, 0.30  # m above a rim: direct and avoidant approach heights
STROKE_HALF = 0.035   # m, half the length of a brush stroke along x
BRUSH_HIGH = 0.25     # m above the piece, and
BRUSH_BACK = 0.12     # m behind it (robot side): where the avoidant brush enters and leaves


def _progress(t: np.ndarray, total: float) -> np.ndarray:
    """Fraction of a section done at times ``t`` in [0, total]: trapezoidal speed with
    half-cosine ramps of RAMP * total at both ends (mean speed = (1 - RAMP) * peak)."""
    tr = RAMP * total
    peak = 1.0 / (total - tr)

    def up(x: np.ndarray) -> np.ndarray:
        return 0.5 * peak * (x - tr / np.pi * np.sin(np.pi * x / tr))

    t = np.clip(t, 0.0, total)
    return np.where(t < tr, up(t), np.where(t > total - tr, 1.0 - up(total - t),
                                            0.5 * peak * tr + peak * (t - tr)))


@dataclass(frozen=True, eq=False)
class Motion:
    """A nominal robot motion through joint waypoints (W, 7), first and last at rest.

    stop (W,): the arm halts there (rest, dips, stroke ends); dwell (W,): seconds it pauses;
    fixed (W,): a section ending at this stop takes exactly this long when > 0 (brush strokes).
    pace: peak fraction of the joint speed limits.
    """

    waypoints: np.ndarray
    stop: np.ndarray
    dwell: np.ndarray
    fixed: np.ndarray
    pace: float

    def section_times(self, speed: float = 1.0, waypoints: np.ndarray | None = None,
                      ) -> np.ndarray:
        """Seconds of each section between consecutive stops, at ``speed`` times the pace."""
        wp = self.waypoints if waypoints is None else waypoints
        lengths = (np.abs(np.diff(wp, axis=0)) / arm_kinematics().velocity).max(axis=1)
        stops = np.flatnonzero(self.stop)
        out = []
        for a, b in itertools.pairwise(stops):
            t = lengths[a:b].sum() / ((1.0 - RAMP) * self.pace)
            out.append(self.fixed[b] if self.fixed[b] > 0 else t)
        return np.array(out) / speed

    def duration(self, speed: float = 1.0) -> float:
        """Seconds from leaving rest to being back, at ``speed`` times the pace."""
        return float(self.section_times(speed).sum() + self.dwell.sum() / speed)

    def sample(self, dt: float, rows: int, speed: float = 1.0,
               waypoints: np.ndarray | None = None, dwell_scale: float = 1.0) -> np.ndarray:
        """(rows, 7): the motion sampled every ``dt`` s from t = 0, at rest once done.

        waypoints: a (W, 7) replacement (a jittered copy), timed from its own joint distances;
        speed: pace factor; dwell_scale: multiplies every pause.
        """
        wp = self.waypoints if waypoints is None else np.asarray(waypoints, dtype=float)
        lengths = (np.abs(np.diff(wp, axis=0)) / arm_kinematics().velocity).max(axis=1)
        cum = np.concatenate([[0.0], np.cumsum(lengths)])
        stops = np.flatnonzero(self.stop)
        sections = self.section_times(speed, wp)
        dwell = self.dwell * dwell_scale / speed
        t = np.arange(rows) * dt
        out = np.repeat(wp[-1:], rows, axis=0)
        clock = dwell[stops[0]]
        out[t <= clock] = wp[stops[0]]
        for (a, b), total in zip(itertools.pairwise(stops), sections, strict=True):
            m = (t > clock) & (t < clock + total)
            arc = cum[a] + _progress(t[m] - clock, total) * (cum[b] - cum[a])
            out[m] = np.stack([np.interp(arc, cum[a:b + 1], wp[a:b + 1, i]) for i in range(7)],
                              axis=-1)
            clock += total
            out[(t >= clock) & (t <= clock + dwell[b])] = wp[b]
            clock += dwell[b]
        return out


def _ik_cached(what: str, layout: CellLayout, solve: Callable[[], np.ndarray]) -> np.ndarray:
    """``solve()``'s joint vectors, kept across runs in rapidds's cache (:mod:`rapidds.cache`):
    the nominal motions' IK took 0.7 s of every painting process. The key holds what the IK
    reads: this module's and the kinematics' source, the scene model (:func:`model_key`), and
    the IK libraries' versions."""
    from importlib.metadata import version

    from rapidds.cache import cached_arrays, code_version, content_key
    from rapidds.worlds.painting import kinematics

    key = content_key(code_version(__file__, kinematics.__file__), what, model_key(layout),
                      version("mink"), version("daqp"))
    return cached_arrays("painting-ik", key, ("q",), lambda: {"q": solve()})["q"]


@cache
def rest_pose(layout: CellLayout = LAYOUT) -> np.ndarray:
    """(7,) the robot's rest configuration: tool at ``REST_TOOL`` pointing down, arm in its
    vertical mid-plane (joints 1, 3, 5, 7 exactly 0, so it is its own mirror image)."""
    def solve() -> np.ndarray:
        q = solve_ik(REST_TOOL, _REST_SEED, layout=layout)
        q[[0, 2, 4, 6]] = 0.0
        return q

    return _ik_cached("rest", layout, solve)


def _tool_targets(task: str, mode: str, layout: CellLayout,
                  ) -> list[tuple[np.ndarray, float, bool, float]]:
    """(tool target, dwell, stop, fixed section time) per waypoint after rest, for the
    left-side version of ``task``."""
    if task == "mix_l":
        low, high = (LOW, LOW + 0.02) if mode == "direct" else (HIGH, HIGH - 0.05)
        tray, bowl = layout.left_tray, layout.bowl
        dy = -NEAR_FAR if mode == "direct" else NEAR_FAR
        tx, ty, top = tray.center[0], tray.center[1] + dy, tray.hi[2]
        bx, by, btop = bowl.center[0], bowl.center[1], bowl.hi[2]
        pts = [((tx, ty, top + low), 0.0, False), ((tx, ty, top - DIP), DWELL, True),
               ((tx, ty, top + low), 0.0, False), ((bx, by, btop + high), 0.0, False),
               ((bx, by, btop - DIP), DWELL, True), ((bx, by, btop + high), 0.0, False)]
        return [(np.array(p, dtype=float), d, h, 0.0) for p, d, h in pts]
    if task == "brush":
        px, py, ptop = layout.workpiece.center[0], layout.workpiece.center[1], \
            layout.workpiece.hi[2]
        a, b = (px - STROKE_HALF, py, ptop + 0.005), (px + STROKE_HALF, py, ptop + 0.005)
        out = [((a[0], py, ptop + 0.06), 0.0, False, 0.0)]
        if mode == "avoidant":  # come in from above the robot's side of the piece
            out.insert(0, ((a[0], py + BRUSH_BACK, ptop + BRUSH_HIGH), 0.0, False, 0.0))
        out.append((a, 0.0, True, 0.0))
        out += [(end, 0.0, True, STROKE) for end in (b, a, b)]
        out.append(((b[0], py, ptop + 0.06), 0.0, False, 0.0))
        if mode == "avoidant":
            out.append(((b[0], py + BRUSH_BACK, ptop + BRUSH_HIGH), 0.0, False, 0.0))
        return [(np.array(p, dtype=float), d, h, f) for p, d, h, f in out]
    raise ValueError(f"no left-side motion for task {task!r}")


@cache
def nominal_motion(task: str, mode: str, layout: CellLayout = LAYOUT) -> Motion:
    """The noise-free motion of ``task`` in ``mode`` (IK solved once, cached)."""
    if task not in ROBOT_TASKS:
        raise ValueError(f"unknown robot task {task!r}; robot tasks are {', '.join(ROBOT_TASKS)}")
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r} of {task}; modes are {', '.join(MODES)}")
    if task == "mix_r":
        left = nominal_motion("mix_l", mode, layout)
        return Motion(mirror_joints(left.waypoints), left.stop, left.dwell, left.fixed, left.pace)
    rest = rest_pose(layout)
    targets = _tool_targets(task, mode, layout)

    def solve() -> np.ndarray:
        qs = [rest]
        for target, *_ in targets:
            qs.append(solve_ik(target, qs[-1], layout=layout))
        return np.array(qs[1:])

    qs = np.vstack([rest, _ik_cached(f"{task}/{mode}", layout, solve), rest])
    _, dwell, stop, fixed = zip(*targets, strict=True)
    return Motion(qs, np.array([True, *stop, True]), np.array([0.0, *dwell, 0.0]),
                  np.array([0.0, *fixed, 0.0]), PACE[mode])
