"""The fetch world's steering value terms as tensor operations on any device: the twin of
:meth:`FetchWorld.completion_time <rapidds.worlds.fetch.world.FetchWorld.completion_time>`
(reach the object, then home; the penalty for a path through a wall or off the map) with the
slab test of :func:`rapidds.worlds.geometry.segments_hit_rects`, dense, so scoring a steering
step's candidates never waits for the host. The robot is a point: its workspace points are
its positions. Tests compare it with the numpy terms, which stay the CPU's path.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
import torch
from torch import Tensor

from rapidds.worlds.tensor_rows import task_rows


class FetchTensorValues:
    """Completion time and workspace points of fetch trajectories (N, H, 2) on one device.

    goals: task -> object position (2,); home (2,), reach radius (m), dt (s), penalty (s),
    the map's bounds lo, hi (2,) and its walls (R, 4) [xmin, ymin, xmax, ymax]."""

    def __init__(self, goals: Mapping[str, np.ndarray], home: np.ndarray, radius: float,
                 dt: float, penalty: float, bounds: tuple[np.ndarray, np.ndarray],
                 walls: np.ndarray, device: torch.device):
        def t(a: object) -> Tensor:
            return torch.as_tensor(np.array(a, dtype=np.float64), device=device)

        self.goals = {task: t(g) for task, g in goals.items()}
        self.home, self.radius, self.dt, self.penalty = t(home), float(radius), dt, penalty
        self.lo, self.hi = t(bounds[0]), t(bounds[1])
        walls = np.asarray(walls, dtype=np.float64).reshape(-1, 4)
        self.wall_lo, self.wall_hi = t(walls[:, :2]), t(walls[:, 2:])

    def points(self, xi: Tensor) -> Tensor:
        """(N, H, 2) -> (N, H, 1, 2): the point robot's one workspace point per row."""
        return xi[:, :, None, :]

    def collides(self, xi: Tensor) -> Tensor:
        """(N,) bool: a point off the map, or a segment between rows meeting a wall."""
        outside = ((xi < self.lo) | (xi > self.hi)).flatten(1).any(dim=1)
        if self.wall_lo.shape[0] == 0:
            return outside
        a = xi[:, :-1, None, :]                                   # (N, S, 1, 2)
        d = (xi[:, 1:] - xi[:, :-1])[:, :, None, :]
        t1 = (self.wall_lo - a) / d
        t2 = (self.wall_hi - a) / d
        parallel = d == 0
        inside = (a >= self.wall_lo) & (a <= self.wall_hi)
        inf = torch.tensor(torch.inf, dtype=xi.dtype, device=xi.device)
        t_enter = torch.where(parallel, torch.where(inside, -inf, inf), torch.minimum(t1, t2))
        t_exit = torch.where(parallel, torch.where(inside, inf, -inf), torch.maximum(t1, t2))
        enter = t_enter.amax(dim=-1).clamp(min=0.0)
        leave = t_exit.amin(dim=-1).clamp(max=1.0)
        return outside | (enter <= leave).flatten(1).any(dim=1)

    def completion_times(self, tasks: Sequence[str], xi: Tensor,
                         points: Tensor | None = None) -> Tensor:
        """(N,) seconds: the first row back home after the object, k * dt; the penalty for a
        path that never does both or that collides. The rows are ``len(tasks)`` equal
        blocks, block k fetching ``tasks[k]``'s object (a steering batch in one pass)."""
        for task in tasks:
            if task not in self.goals:
                raise ValueError(f"unknown fetch task {task!r}")
        goal = task_rows(self.goals, tasks, xi.shape[0])[:, None, :]
        near_goal = torch.linalg.vector_norm(xi - goal, dim=-1) <= self.radius
        near_home = torch.linalg.vector_norm(xi - self.home, dim=-1) <= self.radius
        done = (near_goal.to(torch.int32).cumsum(dim=-1) > 0) & near_home
        k = torch.argmax(done.to(torch.int8), dim=-1).to(xi.dtype)
        t = torch.where(done.any(dim=-1), torch.round(k * self.dt, decimals=9), self.penalty)
        return torch.where(self.collides(xi), self.penalty, t)


def tensor_terms(cache: dict[torch.device, FetchTensorValues], device: torch.device | str,
                 build: Callable[[torch.device], FetchTensorValues]) -> FetchTensorValues:
    """The terms on ``device`` from ``build(device)``, kept in ``cache`` per device."""
    dev = torch.device(device)
    if dev not in cache:
        cache[dev] = build(dev)
    return cache[dev]
