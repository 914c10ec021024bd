"""The painting cell's steering value terms as tensor operations on any device.

:meth:`PaintingWorld.completion_time <rapidds.worlds.painting.world.PaintingWorld.completion_time>`
and the arm's forward kinematics work on numpy arrays on the host. Steering on a GPU would copy
every denoising step's candidates to the host and wait for them there; this module computes
the same terms where the candidates already are: forward kinematics to the 12 arm points
(batched 3 x 3 products), the goal boxes in order, the joint ranges and speeds, and the
collision test, all dense (no ``nonzero``, no ``.item()``), so nothing synchronises the device.

The host functions stay the reference and the CPU's path (their records are the stored ones);
these agree with them to float64 rounding (tests compare both on random and demonstrated
paths: completion times equal, points within 1e-12 m).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

from rapidds.worlds.painting.kinematics import POINT_RADII, TOOL, ArmKinematics
from rapidds.worlds.tensor_rows import task_rows


@dataclass(frozen=True)
class CellValues:
    """What the value terms read of a painting cell (its world hands them over): the arm, the
    row time dt (s), horizon H, the never-completes penalty (s), the joint-speed margin, the
    shortfall rate (s per metre), the rest radius (m) and tool position (3,), the goal boxes
    per robot task in order, and the obstacles (lows (B, 3), highs (B, 3), open to the tool
    (B,))."""

    kinematics: ArmKinematics
    dt: float
    horizon: int
    penalty: float
    speed_margin: float
    shortfall: float
    rest_radius: float
    rest_tool: np.ndarray
    goals: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]]
    obstacles: tuple[np.ndarray, np.ndarray, np.ndarray]


class _Arm:
    """:class:`ArmKinematics` as float64 tensors on one device."""

    def __init__(self, kin: ArmKinematics, device: torch.device):
        def t(a: np.ndarray) -> Tensor:
            return torch.as_tensor(np.array(a, dtype=np.float64), device=device)

        cross = [np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
                 for a in kin.axis]
        # fixed @ rot(axis, q) = fixed + sin q (fixed K) + (1 - cos q) (fixed K^2)
        self.fixed = t(kin.fixed)                                         # (7, 3, 3)
        self.fk = t(np.stack([f @ k for f, k in zip(kin.fixed, cross, strict=True)]))
        self.fk2 = t(np.stack([f @ k @ k for f, k in zip(kin.fixed, cross, strict=True)]))
        self.offset, self.anchor = t(kin.offset), t(kin.anchor)          # (7, 3)
        self.hinged = [bool(np.any(a)) for a in kin.anchor]
        self.base_pos, self.base_rot = t(kin.base_pos), t(kin.base_rot)
        # the points grouped by link: (link, (3, m) offsets), and where each point lands
        links = sorted(set(int(k) for k in kin.point_link))
        members = [[i for i, k in enumerate(kin.point_link) if k == link] for link in links]
        self.links = [(link, t(np.asarray(kin.point_offset)[idx].T))
                      for link, idx in zip(links, members, strict=True)]
        grouped = [i for idx in members for i in idx]
        self.point_order = torch.as_tensor(np.argsort(grouped), device=device)
        self.lower, self.upper, self.velocity = t(kin.lower), t(kin.upper), t(kin.velocity)

    def points(self, q: Tensor) -> Tensor:
        """Arm points (n, P, 3) of joint vectors (n, 7), as mj_kinematics places them; the
        points of one link from one product (its rotation times its points' offsets), as
        each operation is a kernel the host launches on a GPU."""
        n = q.shape[0]
        pos = [self.base_pos.expand(n, 3)]
        rot = [self.base_rot.expand(n, 3, 3)]
        s, c1 = torch.sin(q), 1.0 - torch.cos(q)
        for k in range(7):
            local = (self.fixed[k] + self.fk[k] * s[:, k, None, None]
                     + self.fk2[k] * c1[:, k, None, None])                # (n, 3, 3)
            r = rot[k]
            p = pos[k] + r @ self.offset[k]
            r_new = r @ local
            if self.hinged[k]:  # hinge about an off-origin anchor
                p = p + (r @ self.fixed[k] - r_new) @ self.anchor[k]
            pos.append(p)
            rot.append(r_new)
        # (n, 3, m) points of each link, then in the points' order
        parts = [pos[link][:, :, None] + rot[link] @ offsets for link, offsets in self.links]
        return torch.cat(parts, dim=2).transpose(1, 2)[:, self.point_order]


class PaintingTensorValues:
    """The painting world's value terms on tensors of one device (built per device by
    :func:`tensor_terms`): :meth:`points` for the spatial cost and :meth:`completion_times`,
    the tensor twin of the world's ``completion_time``, which takes the points already
    computed."""

    def __init__(self, cell: CellValues, device: torch.device):
        def t(a: Any) -> Tensor:
            return torch.as_tensor(np.array(a, dtype=np.float64), device=device)

        self.device, self.cell = device, cell
        self.arm = _Arm(cell.kinematics, device)
        self.dt, self.horizon, self.penalty = cell.dt, cell.horizon, cell.penalty
        self.speed_margin, self.shortfall = cell.speed_margin, cell.shortfall
        self.rest_radius, self.rest_tool = cell.rest_radius, t(cell.rest_tool)
        # (G, 3) goal boxes' corners per task, every task's list padded to the longest with
        # the whole space, so the batch's rows gather theirs in one operation
        most = max(len(boxes) for boxes in cell.goals.values())
        pad = [(np.full(3, -np.inf), np.full(3, np.inf))]
        padded = {task: list(boxes) + pad * (most - len(boxes))
                  for task, boxes in cell.goals.items()}
        self.goal_lo, self.goal_hi = ({task: t([box[i] for box in boxes])
                                       for task, boxes in padded.items()} for i in (0, 1))
        lows, highs, open_to_tool = cell.obstacles
        self.lows, self.highs = t(lows), t(highs)
        self.top = float(np.max(highs[:, 2]))
        self.radius = t(POINT_RADII)
        is_tool = torch.zeros(len(POINT_RADII), dtype=torch.bool, device=device)
        is_tool[TOOL] = True
        # (P, B): may point p touch box b (the tool tip may enter trays, bowl and piece)
        self.may_touch = ~(is_tool[:, None]
                           & torch.as_tensor(open_to_tool, device=device)[None])

    def points(self, traj: Tensor) -> Tensor:
        """(N, H, 7) joint trajectories -> (N, H, P, 3) arm points."""
        n, h, _ = traj.shape
        return self.arm.points(traj.reshape(n * h, 7)).reshape(n, h, -1, 3)

    def collides(self, pts: Tensor) -> Tensor:
        """(N,) bool for arm points (N, H, P, 3): the world's ``collides`` without its
        shortcuts (every low point against every box), so the same booleans, no sync."""
        bottom = pts[..., 2] - self.radius                                # (N, H, P)
        hit = (bottom < 0.0).flatten(1).any(dim=1)
        c = pts[..., None, :]                                             # (N, H, P, 1, 3)
        gap = (self.lows - c).clamp(min=0.0) + (c - self.highs).clamp(min=0.0)
        touch = (gap * gap).sum(dim=-1) <= (self.radius * self.radius)[:, None]
        touch &= self.may_touch & (bottom < self.top)[..., None]
        return hit | touch.flatten(1).any(dim=1)

    def executable(self, traj: Tensor, pts: Tensor) -> Tensor:
        """(N,) bool: in the joint ranges, no joint faster than the margin, no collision."""
        arm = self.arm
        in_range = ((traj >= arm.lower) & (traj <= arm.upper)).flatten(1).all(dim=1)
        speed = (traj[:, 1:] - traj[:, :-1]).abs() / self.dt
        slow = (speed <= self.speed_margin * arm.velocity).flatten(1).all(dim=1)
        return in_range & slow & ~self.collides(pts)

    def completion_times(self, tasks: Sequence[str], traj: Tensor, pts: Tensor) -> Tensor:
        """(N,) seconds for (N, H, 7) trajectories with their points (N, H, P, 3), the rows in
        ``len(tasks)`` equal blocks, block k doing ``tasks[k]``: the world's
        ``completion_time`` as tensor operations, one pass for the whole steering batch (a
        task with fewer goals than another has its list padded with the whole space, whose
        gap is 0 and changes nothing)."""
        for task in tasks:
            if task not in self.goal_lo:
                raise ValueError(f"{task!r} is not a robot task of the painting cell")
        n, h = traj.shape[:2]
        lo, hi = task_rows(self.goal_lo, tasks, n), task_rows(self.goal_hi, tasks, n)
        tool = pts[:, :, TOOL]                                            # (N, H, 3)
        reached = torch.ones((n, h), dtype=torch.bool, device=tool.device)
        short = torch.zeros(n, dtype=torch.float64, device=tool.device)
        rest = (torch.linalg.vector_norm(tool - self.rest_tool, dim=-1)
                - self.rest_radius).clamp(min=0.0)
        goal_gaps = _box_gap(tool[:, None], lo[:, :, None], hi[:, :, None])  # (N, G, H)
        for gap in [*goal_gaps.unbind(dim=1), rest]:
            after = reached | ~reached.any(dim=1, keepdim=True)
            short = short + torch.where(after, gap, torch.inf).amin(dim=1)
            reached = (((gap <= 0.0) & reached).to(torch.int32).cumsum(dim=1) > 0)
        done = reached.any(dim=1)
        k = torch.argmax(reached.to(torch.int8), dim=1).to(torch.float64)
        t = torch.where(done, torch.round(k * self.dt, decimals=9),
                        self.penalty + self.shortfall * short)
        bad = ~self.executable(traj, pts)
        return torch.where(bad, self.penalty + self.horizon * self.dt + self.shortfall * short, t)


def _box_gap(points: Tensor, lo: Tensor, hi: Tensor) -> Tensor:
    """Distance (...,) of points (..., 3) to the box [lo, hi]; 0 inside."""
    out = (lo - points).clamp(min=0.0) + (points - hi).clamp(min=0.0)
    return torch.linalg.vector_norm(out, dim=-1)


def tensor_terms(cell: CellValues, device: torch.device | str,
                 cache: dict[torch.device, PaintingTensorValues]) -> PaintingTensorValues:
    """The cell's tensor terms on ``device``, built once per device into ``cache``."""
    dev = torch.device(device)
    if dev not in cache:
        cache[dev] = PaintingTensorValues(cell, dev)
    return cache[dev]


__all__ = ["CellValues", "PaintingTensorValues", "tensor_terms"]
