"""Predicted slowdowns: how long the speed and separation monitor will slow or hold a robot
motion beside the person's concurrent tasks, so that the planner can plan for it.

The monitor (:class:`~rapidds.execution.policies.SpeedSeparation`) moves the robot at the
largest rate r in [0, 1] with d >= S_p(r) (ISO/TS 15066 Eq. 1, :func:`protective_distance`).
A step of the motion that takes dt at full speed takes dt / r at rate r, so it loses
dt (1 / r - 1). The prediction runs that over the steered trajectory, step by step until the
motion is done, with

- d: the distance from each of the robot's body points to the person's path on the concurrent
  task as the learned grid belief has it. The belief holds s(x) = E[exp(-beta |x - path|)]
  (paper Eq. 7), so -ln s(x) / beta is a distance, by Jensen never larger than the expected
  one: the prediction errs on the side of a hold. It is the closest the person comes to x over
  the whole task, not where they are at that instant, so it predicts a hold wherever the robot
  passes the person's route; the learned correction (:mod:`rapidds.human.slowdowns`) scales
  that to what the monitor really does.
- the directed speeds of the monitor (:func:`~rapidds.execution.policies.directed_arrays`,
  the executor's own computation, and its rate :func:`~.policies.monitor_rates`). v_r: each
  robot body point's full-rate velocity along the trajectory towards the person's route (the
  route's nearest point lies along the belief's gradient). v_h: the person's *approach* speed
  at x, :func:`approach_speeds`: on the population's paths of that task, by how much the
  monitor's person term v_h (T_r + T_s), with v_h directed at each instant of the path,
  brings the person closer than their closest approach, over T_r + T_s. A person who walks
  straight at x counts their full speed, one who passes x at a distance little of it: total
  speeds (what the prediction used before) overpredicted the holds of the directed monitor.

A stop (r = 0) is counted as ``floor`` (r = 0.1: a step in the stop zone costs 9 dt more): the
person moves on and the robot resumes, which a path belief cannot time. Everything is
elementwise array arithmetic (no Python loop over trajectories), so it can run as tensor ops.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from rapidds.cache import cached_arrays, code_version, content_key
from rapidds.execution.policies import directed_arrays, monitor_rates, protective_distance
from rapidds.human.slowdowns import SlowdownBelief
from rapidds.human.spatial import SpatialModel
from rapidds.worlds.base import World
from rapidds.worlds.reactions import SafetyLimits

__all__ = ["HoldModel", "approach_speeds", "directed_rates", "lost_time", "predicted_hold"]

FLOOR = 0.1


def predicted_hold(limits: SafetyLimits, separation: np.ndarray, human_speed: np.ndarray,
                   robot_speed: np.ndarray, active: np.ndarray, dt: float,
                   floor: float = FLOOR) -> np.ndarray:
    """Seconds the monitor adds to each motion: (..., H) separations, directed speeds and the
    steps still moving (``active``) -> (...). Broadcasting arrays only."""
    return lost_time(monitor_rates(limits, separation, human_speed, robot_speed), active, dt,
                     floor)


def lost_time(rates: np.ndarray, active: np.ndarray, dt: float,
              floor: float = FLOOR) -> np.ndarray:
    """A step of dt at rate r takes dt / r: the seconds (..., H) rates add to each motion."""
    r = np.maximum(rates, floor)
    return (dt * (1.0 / r - 1.0) * active).sum(axis=-1)


def directed_rates(limits: SafetyLimits, robot: np.ndarray, velocity: np.ndarray,
                   distance: np.ndarray, gradient: np.ndarray,
                   approach: np.ndarray) -> np.ndarray:
    """The monitor's rate at each robot step beside the person's route: robot body points
    (..., P, d) and their full-rate velocities, each point's distance to the route (..., P);
    at the body point nearest to the route, that distance's gradient (..., d) and the person's
    approach speed (...) -> (...). v_r comes from the monitor's own directed speeds with the
    person at the route's point nearest to that body point (along the gradient). Where the
    gradient is flat (no direction to the route), the robot's total speed counts, as the
    monitor counts a speed whose direction it does not know."""
    near = distance.argmin(axis=-1)[..., None]
    d = np.take_along_axis(distance, near, axis=-1)[..., 0]  # (...)
    norm = np.linalg.norm(gradient, axis=-1, keepdims=True)
    at = np.take_along_axis(robot, near[..., None], axis=-2)[..., 0, :]
    route = (at - d[..., None] * gradient / np.maximum(norm, 1e-12))[..., None, :]
    _, _, v_r = directed_arrays(route, np.zeros_like(route), robot, velocity)
    total = np.linalg.norm(velocity, axis=-1).max(axis=-1)
    v_r = np.where(norm[..., 0] <= 1e-9, total, v_r)
    return monitor_rates(limits, d, approach, v_r)


def _tensor_rates(limits: SafetyLimits, separation: Any, human_speed: Any,
                  robot_speed: Any) -> Any:
    """:func:`~rapidds.execution.policies.monitor_rates` as tensor operations."""
    import torch

    still = protective_distance(limits, human_speed, 0.0 * robot_speed)
    per_rate = protective_distance(limits, human_speed, robot_speed) - still
    room = separation - still
    safe = torch.where(per_rate > 0.0, per_rate, torch.ones_like(per_rate))
    r = torch.where(per_rate > 0.0, (room / safe).clamp(max=1.0), torch.ones_like(room))
    return torch.where(room < 0.0, torch.zeros_like(r), r)


def approach_speeds(world: World, spatial: SpatialModel, limits: SafetyLimits,
                    chunk: int = 1024, paths_max: int = 16) -> dict[str, np.ndarray]:
    """Per person's task, the approach speed at each point of the path belief's grid (V,):
    on each of the world's prior paths, the closest approach d* to the point and the
    smallest d - v_h (T_r + T_s) over the path's instants, with d and v_h what
    :func:`~rapidds.execution.policies.directed_arrays` gives for the person beside a still
    robot point there (written out here for one point, ~5x faster; tests/test_slowdowns.py
    checks it against that function); (d* - that) / (T_r + T_s), averaged over the paths
    (at most ``paths_max`` of them, evenly spread: a painting grid has 10648 points, 40 paths
    cost ~10 s of CPU at every run's start, 16 ~3 s). At most the person's fastest speed, 0
    where they never close in."""
    grid = spatial.config.grid()
    react = limits.reaction_time + limits.stopping_time
    chosen = {}
    for task, every in world.prior().paths.items():
        pick = np.unique(np.linspace(0, len(every) - 1, min(len(every), paths_max)).round())
        chosen[task] = [np.asarray(every[int(k)], dtype=float) for k in pick]
    tasks = list(chosen)

    def build() -> dict[str, np.ndarray]:
        out = {}
        for n, paths in enumerate(chosen.values()):
            total = np.zeros(len(grid))
            for arr in paths:
                arr = arr[:, None] if arr.ndim == 2 else arr  # (T, K, d)
                vel = np.concatenate([np.diff(arr, axis=0), np.zeros_like(arr[:1])]) / world.dt
                for lo in range(0, len(grid), chunk):
                    sep, v_h = _towards_point(arr, vel, grid[lo:lo + chunk])
                    total[lo:lo + chunk] += sep.min(axis=-1) - (sep - v_h * react).min(axis=-1)
            out[f"t{n}"] = total / max(len(paths), 1) / react if react > 0 else total
        return out

    # seconds at every run's start under a monitor, the same for the same paths, grid and
    # reactions: built once per machine, then read back bit for bit (rapidds.cache)
    key = content_key(code_version(__file__), grid, float(react), float(world.dt), tasks,
                      *(a for paths in chosen.values() for a in (len(paths), *paths)))
    arrays = cached_arrays("approach-speeds", key, tuple(f"t{n}" for n in range(len(tasks))),
                           build)
    return {task: arrays[f"t{n}"] for n, task in enumerate(tasks)}


def _towards_point(points: np.ndarray, velocity: np.ndarray,
                   x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d and v_h of :func:`~rapidds.execution.policies.directed_arrays` for the person's
    points (T, K, d) and velocities against each single still point x (V, d): (V, T) each."""
    diff = x[:, None, None, :] - points[None]  # (V, T, K, d)
    dist = np.sqrt(np.einsum("vtkd,vtkd->vtk", diff, diff))
    along = np.einsum("vtkd,tkd->vtk", diff, velocity) / np.maximum(dist, 1e-12)
    return dist.min(axis=-1), np.maximum(along.max(axis=-1), 0.0)


@dataclass
class HoldModel:
    """The predicted lost time of robot trajectories beside the person's tasks, from the path
    belief ``spatial`` and the person's approach speeds on its grid (``speeds``,
    :func:`approach_speeds`), corrected by ``belief`` (None: the prediction as it is)."""

    world: World
    spatial: SpatialModel
    limits: SafetyLimits
    speeds: Mapping[str, np.ndarray]
    belief: SlowdownBelief | None = None
    _tables: dict[Any, Any] = field(default_factory=dict, repr=False, compare=False)

    def raw(self, task: str, concurrent: Iterable[str], xi: np.ndarray) -> dict[str, np.ndarray]:
        """Per concurrent person's task, the uncorrected lost time of trajectories xi (N, H, d)
        of robot task ``task`` -> (N,) seconds."""
        xi = np.asarray(xi, dtype=float)
        dt = self.world.dt
        pts = np.asarray(self.world.robot_points(xi), dtype=float)      # (N, H, P, d_ws)
        vel = np.concatenate([np.diff(pts, axis=1) / dt, np.zeros_like(pts[:, :1])], axis=1)
        done = np.asarray(self.world.completion_time(task, xi), dtype=float)  # (N,)
        active = np.arange(xi.shape[1])[None] * dt < done[:, None] - 1e-9
        out = {}
        for i in dict.fromkeys(concurrent):
            dist = self._distance(i, pts)  # (N, H, P)
            near = dist.argmin(axis=-1)[..., None, None]
            x = np.take_along_axis(pts, near, axis=-2)[..., 0, :]  # the nearest body point
            rates = directed_rates(self.limits, pts, vel, dist, self._gradient(i, x),
                                   self._approach(i, x))
            out[i] = lost_time(rates, active, dt)
        return out

    def _approach(self, task: str, x: np.ndarray) -> np.ndarray:
        """The person's approach speed on ``task`` at points (..., d), interpolated on the grid
        (multilinear; points outside it clamped onto it); 0 for a task with none."""
        v = self.speeds.get(task)
        if v is None:
            return np.zeros(x.shape[:-1])
        cfg = self.spatial.config
        axes = [np.linspace(lo, hi, n) for (lo, hi), n in zip(cfg.bounds, cfg.shape, strict=True)]
        lo, hi = np.asarray(cfg.bounds, dtype=float).T
        return RegularGridInterpolator(axes, np.asarray(v).reshape(cfg.shape))(np.clip(x, lo, hi))

    def _distance(self, task: str, x: np.ndarray) -> np.ndarray:
        """The distance -ln s(x) / beta from points (..., d) to the person's route on ``task``
        as the path belief has it."""
        s = np.asarray(self.spatial[task].point_cost(x), dtype=float)
        return -np.log(np.maximum(s, 1e-300)) / self.spatial.config.beta

    def _gradient(self, task: str, x: np.ndarray) -> np.ndarray:
        """The distance's gradient at points (..., d), by central differences a tenth of a grid
        cell wide (the grid is multilinear: its gradient is constant inside a cell)."""
        cfg = self.spatial.config
        lo, hi = np.asarray(cfg.bounds, dtype=float).T
        step = 0.1 * (hi - lo) / (np.asarray(cfg.shape) - 1)
        inside = np.clip(x, lo + step, hi - step)
        dist = self._distance
        return np.stack([(dist(task, inside + h * e) - dist(task, inside - h * e)) / (2 * h)
                         for h, e in zip(step, np.eye(len(lo)), strict=True)], axis=-1)

    def tensor_hold(self, keys: Sequence[tuple[str, frozenset[str]]], per_key: int, xi: Any,
                    points: Any, done: Any) -> Any:
        """:meth:`hold` of every request of a steering batch as tensor operations on the
        device of the steering value's own workspace points (N, H, P, w) and completion times
        (N,) of trajectories xi (N, H, d), request k's being rows k * per_key on: (N,), no copy
        to the host inside the denoising loop, so a GPU scores a monitored plan's candidates
        where it samples them. The prediction depends on the robot's task only through the
        steps still moving and the correction, so it is made once per person's task over the
        rows of every request beside it (each operation a kernel on a GPU). The numpy path's
        arithmetic, rounded apart (tests check the two agree); the host's stays the stored
        records'."""
        import torch

        dt = self.world.dt
        vel = torch.cat([torch.diff(points, dim=1) / dt, torch.zeros_like(points[:, :1])], dim=1)
        step = torch.arange(points.shape[1], device=points.device, dtype=points.dtype) * dt
        active = step[None] < done[:, None] - 1e-9
        out = torch.zeros_like(done)
        b = self.belief
        for i in dict.fromkeys(i for _, near in keys for i in near):
            ks = [k for k, (_, near) in enumerate(keys) if i in near]
            rows = [slice(k * per_key, (k + 1) * per_key) for k in ks]
            lost = self._tensor_lost(i, *(torch.cat([a[r] for r in rows]) if len(rows) > 1
                                          else a[rows[0]] for a in (points, vel, active)))
            for j, (k, r) in enumerate(zip(ks, rows, strict=True)):
                mine = lost[j * per_key:(j + 1) * per_key]
                if b is not None:
                    mine = mine * b.factor(keys[k][0], i)
                out[r] = torch.maximum(out[r], mine)
        return out

    def _tensor_lost(self, task: str, points: Any, vel: Any, active: Any) -> Any:
        """The uncorrected lost time (N,) beside the person's ``task`` of robot points
        (N, H, P, w) with their full-rate velocities and the steps still moving (N, H):
        :meth:`raw`'s per task, as tensor operations."""
        import torch

        dist = self._tensor_distance(task, points)                            # (N, H, P)
        near = dist.argmin(dim=-1, keepdim=True)
        d = dist.gather(-1, near)[..., 0]
        x = points.gather(-2, near[..., None].expand(*near.shape, points.shape[-1]))[..., 0, :]
        grad = self._tensor_gradient(task, x)
        norm = torch.linalg.vector_norm(grad, dim=-1)
        # directed_rates: the robot's directed speed towards the route's point nearest to its
        # nearest body point (directed_arrays with that one point as the person)
        route = x - d[..., None] * grad / norm.clamp(min=1e-12)[..., None]
        to_h = route[..., None, :] - points                                   # (N, H, P, w)
        length = torch.linalg.vector_norm(to_h, dim=-1).clamp(min=1e-12)
        v_r = ((vel * to_h).sum(dim=-1) / length).amax(dim=-1).clamp(min=0.0)
        total = torch.linalg.vector_norm(vel, dim=-1).amax(dim=-1)
        v_r = torch.where(norm <= 1e-9, total, v_r)
        rates = _tensor_rates(self.limits, d, self._tensor_approach(task, x), v_r)
        return (self.world.dt * (1.0 / rates.clamp(min=FLOOR) - 1.0) * active).sum(dim=-1)

    def _tensor_distance(self, task: str, x: Any) -> Any:
        """:meth:`_distance` of points (..., d) as tensor operations on their device."""
        import torch

        s = self.spatial[task].point_cost(x)
        tiny = torch.finfo(s.dtype).tiny  # float32's, where 1e-300 would round to 0
        return -torch.log(s.clamp(min=max(tiny, 1e-300))) / self.spatial.config.beta

    def _tensor_gradient(self, task: str, x: Any) -> Any:
        """:meth:`_gradient` as tensor operations, (..., d): the 2d shifted points in one
        evaluation of the belief. Its constants are copied to the device once (a copy per call
        would make a GPU wait for the host)."""
        import torch

        key = ("gradient", x.device, x.dtype)
        if key not in self._tables:
            cfg = self.spatial.config
            lo, hi = np.asarray(cfg.bounds, dtype=float).T
            step = 0.1 * (hi - lo) / (np.asarray(cfg.shape) - 1)
            at = {"device": x.device, "dtype": x.dtype}
            shifts = np.concatenate([np.diag(step), -np.diag(step)])           # (2d, d)
            self._tables[key] = tuple(torch.as_tensor(a, **at)
                                      for a in (lo + step, hi - step, shifts, 2 * step))
        low, high, shifts, width = self._tables[key]
        d = width.shape[0]
        inside = torch.clamp(x, low, high)[None]                              # (1, ..., d)
        dist = self._tensor_distance(task, inside + shifts.view(2 * d, *[1] * (x.ndim - 1), d))
        return torch.movedim(dist[:d] - dist[d:], 0, -1) / width

    def _tensor_approach(self, task: str, x: Any) -> Any:
        """:meth:`_approach` as tensor operations; the speeds' corner table is copied to the
        device once per task."""
        import torch

        v = self.speeds.get(task)
        if v is None:
            return torch.zeros(x.shape[:-1], device=x.device, dtype=x.dtype)
        model = self.spatial[task]
        key = (task, x.device, x.dtype)
        if key not in self._tables:
            self._tables[key] = model.field_table(v, x.device, x.dtype)
        return model.field_at(self._tables[key], x)

    def hold(self, task: str, concurrent: Iterable[str], xi: np.ndarray) -> np.ndarray:
        """Predicted lost time beside C_j = ``concurrent``: the largest over its tasks of the
        corrected prediction (as the paper's spatial cost takes the largest S_i), (N,)."""
        per = self.raw(task, concurrent, xi)
        if not per:
            return np.zeros(np.asarray(xi).shape[0])
        b = self.belief
        return np.max(np.stack([p * (1.0 if b is None else b.factor(task, i))
                                for i, p in per.items()]), axis=0)

    def value_term(self) -> Callable[[str, Sequence[str], np.ndarray], np.ndarray]:
        """The term steering adds to a motion's value (seconds, like d_j)."""
        return self.hold
