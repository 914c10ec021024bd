"""Kinematics of the Panda in the painting cell: batched forward kinematics to points along the
arm's links (numpy, from the MjModel's own body tree) and inverse kinematics with ``mink``.

Forward kinematics replays what ``mujoco.mj_kinematics`` does for the arm's serial chain (body
offset, body rotation, hinge rotation about the joint axis through the joint anchor), for any
batch of joint vectors at once: the steering loop scores tens of thousands of configurations per
GA generation, and one ``mj_kinematics`` call per configuration would be the bottleneck. The
test suite checks it against ``mj_kinematics`` to 1e-9 m.

Arm points (P = 12), each fixed in one link's frame, chosen so the arm's bodies are covered at
the spacing of the spatial model's decay length (about 0.1 m): shoulder, the middle and top of
the upper arm, the elbow, two points along the forearm, the wrist, the flange, the hand, the two
sides of the gripper (it is 0.2 m wide) and the tool tip (the model's ``end_effector`` site,
where the held brush or spoon touches paint). ``POINT_RADII`` are the link radii the collision
check uses.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from functools import cache
from typing import TYPE_CHECKING

import numpy as np

from rapidds.worlds.painting.scene import (
    ARM_BODIES,
    ARM_JOINTS,
    LAYOUT,
    CellLayout,
    load_model,
    model_key,
)

if TYPE_CHECKING:
    import mujoco

__all__ = [
    "POINT_NAMES",
    "POINT_RADII",
    "TOOL",
    "ArmKinematics",
    "arm_kinematics",
    "mirror_joints",
    "solve_ik",
    "tool_path_ik",
]

# (name, link index into ARM_BODIES, offset in that link's frame in metres, collision radius).
# The tool tip's offset is replaced by the model's end_effector site.
_POINTS: tuple[tuple[str, int, tuple[float, float, float], float], ...] = (
    ("shoulder", 2, (0.0, 0.0, 0.0), 0.09),
    ("upper_arm", 2, (0.0, -0.158, 0.0), 0.07),
    ("elbow_top", 3, (0.0, 0.0, 0.0), 0.07),
    ("elbow", 4, (0.0, 0.0, 0.0), 0.07),
    ("forearm_a", 4, (-0.0275, 0.128, 0.0), 0.06),
    ("forearm_b", 4, (-0.055, 0.256, 0.0), 0.06),
    ("wrist", 5, (0.0, 0.0, 0.0), 0.07),
    ("flange", 7, (0.0, 0.0, 0.0), 0.06),
    ("hand", 7, (0.0, 0.0, 0.107), 0.05),
    ("gripper_a", 7, (0.0566, 0.0566, 0.13), 0.03),
    ("gripper_b", 7, (-0.0566, -0.0566, 0.13), 0.03),
    ("tool", 7, (0.0, 0.0, 0.21), 0.0),
)
POINT_NAMES: tuple[str, ...] = tuple(p[0] for p in _POINTS)
POINT_RADII: np.ndarray = np.array([p[3] for p in _POINTS])
TOOL: int = POINT_NAMES.index("tool")
# Joints whose sign flips when the arm is mirrored in the vertical plane through its base
# (the rotations about the base's vertical and the forearm's own axes); 2, 4, 6 bend in that
# plane and keep their sign.
_MIRROR_SIGN = np.array([-1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0])


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def mirror_joints(q: np.ndarray) -> np.ndarray:
    """Joint vectors (..., 7) of the arm reflected in the plane x = 0 (the robot base lies on
    it): joints 1, 3, 5, 7 change sign."""
    return np.asarray(q, dtype=float) * _MIRROR_SIGN


@dataclass(frozen=True, eq=False)
class ArmKinematics:
    """The Panda's serial chain as arrays taken from an MjModel.

    base_pos, base_rot: world pose of link0. offset (7, 3), fixed (7, 3, 3): each moving link's
    position and rotation in its parent's frame. axis (7, 3), anchor (7, 3): hinge axis and
    anchor in the link's frame. point_link (P,), point_offset (P, 3): the arm points.
    lower, upper (7,): joint limits (rad). velocity (7,): joint speed limits (rad/s).
    """

    base_pos: np.ndarray
    base_rot: np.ndarray
    offset: np.ndarray
    fixed: np.ndarray
    axis: np.ndarray
    anchor: np.ndarray
    point_link: np.ndarray
    point_offset: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    _last_points: list = field(default_factory=list, repr=False)  # [(joints, points)], last call

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> ArmKinematics:
        """Read the chain of ``ARM_BODIES`` out of ``model`` (fixed ancestors folded into the
        base pose)."""
        import mujoco

        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in ARM_BODIES]
        # Pose of link0: compose the fixed bodies from the world down to it.
        chain, b = [], ids[0]
        while b != 0:
            chain.append(b)
            b = int(model.body_parentid[b])
        pos, rot = np.zeros(3), np.eye(3)
        for b in reversed(chain):
            pos = pos + rot @ model.body_pos[b]
            rot = rot @ _quat_to_mat(model.body_quat[b])
        offset, fixed, axis, anchor, lower, upper = [], [], [], [], [], []
        for k, b in enumerate(ids[1:]):
            if int(model.body_parentid[b]) != ids[k] or int(model.body_jntnum[b]) != 1:
                raise ValueError(f"{ARM_BODIES[k + 1]} is not a one-hinge child of "
                                 f"{ARM_BODIES[k]}")
            j = int(model.body_jntadr[b])
            if model.joint(j).name != ARM_JOINTS[k]:
                raise ValueError(f"{ARM_BODIES[k + 1]} moves by {model.joint(j).name}, "
                                 f"expected {ARM_JOINTS[k]}")
            offset.append(model.body_pos[b].copy())
            fixed.append(_quat_to_mat(model.body_quat[b]))
            a = model.jnt_axis[j]
            axis.append(a / np.linalg.norm(a))
            anchor.append(model.jnt_pos[j].copy())
            lower.append(model.jnt_range[j][0])
            upper.append(model.jnt_range[j][1])
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "end_effector")
        links = np.array([p[1] for p in _POINTS])
        offsets = np.array([p[2] for p in _POINTS], dtype=float)
        if site >= 0 and int(model.site_bodyid[site]) == ids[7]:
            offsets[TOOL] = model.site_pos[site]
        return cls(pos, rot, np.array(offset), np.array(fixed), np.array(axis),
                   np.array(anchor), links, offsets, np.array(lower), np.array(upper),
                   FRANKA_VELOCITY.copy())

    @property
    def n_points(self) -> int:
        return len(self.point_link)

    def _frames(self, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Link poses for (n, 7) joint vectors, component-major: positions (8, 3, n) and
        rotations (8, 3, 3, n). Every product is written out over contiguous (n,) vectors,
        which is several times faster than batched 3 x 3 matmuls of (n, 3, 3) arrays."""
        n = flat.shape[0]
        qt = np.ascontiguousarray(flat.T)                              # (7, n)
        pos = np.empty((8, 3, n))
        rot = np.empty((8, 3, 3, n))
        pos[0] = self.base_pos[:, None]
        rot[0] = self.base_rot[:, :, None]
        for k in range(7):
            a = self.axis[k]
            cross = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
            # fixed @ rot(axis, q) = fixed + sin q (fixed K) + (1 - cos q) (fixed K^2)
            f = self.fixed[k]
            fk, fk2 = f @ cross, f @ cross @ cross
            s, c1 = np.sin(qt[k]), 1.0 - np.cos(qt[k])
            local = f[:, :, None] + fk[:, :, None] * s + fk2[:, :, None] * c1     # (3, 3, n)
            r = rot[k]
            p = pos[k] + np.einsum("ijn,j->in", r, self.offset[k])
            r_new = rot[k + 1]
            for i in range(3):
                for j in range(3):
                    r_new[i, j] = r[i, 0] * local[0, j] + r[i, 1] * local[1, j] + \
                        r[i, 2] * local[2, j]
            if self.anchor[k].any():  # hinge about an off-origin anchor, as mj_kinematics does
                r_fixed = np.einsum("ikn,kj->ijn", r, f)
                p = p + np.einsum("ijn,j->in", r_fixed - r_new, self.anchor[k])
            pos[k + 1] = p
        return pos, rot

    def _flat(self, q: np.ndarray) -> tuple[np.ndarray, tuple[int, ...]]:
        qa = np.asarray(q, dtype=float)
        if qa.shape[-1:] != (7,):
            raise ValueError(f"joint vectors must have shape (..., 7), got {qa.shape}")
        return qa.reshape(-1, 7), qa.shape[:-1]

    def link_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World pose of link0..link7 for joint vectors (..., 7): positions (..., 8, 3) and
        rotation matrices (..., 8, 3, 3)."""
        flat, lead = self._flat(q)
        pos, rot = self._frames(flat)
        return (pos.transpose(2, 0, 1).reshape(*lead, 8, 3),
                rot.transpose(3, 0, 1, 2).reshape(*lead, 8, 3, 3))

    def points(self, q: np.ndarray) -> np.ndarray:
        """Workspace points of the arm for joint vectors (..., 7): (..., P, 3).

        The last answer is kept: steering asks for the same candidates' points twice per step
        (completion time, then spatial cost), and forward kinematics was a fifth of a painting
        cycle. The key is a copy of the joints, compared byte for byte (20 times faster than
        hashing them), so equal input gives this very answer."""
        arr = np.ascontiguousarray(q, dtype=float)
        memo = self._last_points
        last = memo[0] if memo else None  # one (joints, points) tuple, read at once (threads)
        if (last is not None and last[0].shape == arr.shape
                and np.array_equal(last[0].view(np.uint64), arr.view(np.uint64))):
            return last[1].copy()
        out = self._points(arr)
        memo[:] = [(arr.copy(), out.copy())]  # callers may write into theirs
        return out

    def _points(self, q: np.ndarray) -> np.ndarray:
        flat, lead = self._flat(q)
        pos, rot = self._frames(flat)
        out = np.empty((flat.shape[0], self.n_points, 3))
        for p, (link, off) in enumerate(zip(self.point_link, self.point_offset, strict=True)):
            r = rot[link]
            for i in range(3):
                out[:, p, i] = pos[link, i] + r[i, 0] * off[0] + r[i, 1] * off[1] + \
                    r[i, 2] * off[2]
        return out.reshape(*lead, self.n_points, 3)

    def tool(self, q: np.ndarray) -> np.ndarray:
        """Tool-tip positions (..., 3) for joint vectors (..., 7)."""
        flat, lead = self._flat(q)
        pos, rot = self._frames(flat)
        off = self.point_offset[TOOL]
        tip = pos[7] + np.einsum("ijn,j->in", rot[7], off)
        return tip.T.reshape(*lead, 3)


# Franka Emika Panda joint speed limits, rad/s (Franka "Robot and interface specifications",
# the same numbers as the comments of the gymnasium-robotics actuator.xml): joints 1-4 2.1750,
# joints 5-7 2.6100.
FRANKA_VELOCITY = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])
# and its acceleration (rad/s^2) and jerk (rad/s^3) limits, the same table
# (frankaemika/docs control-parameters-joint-panda.csv)
FRANKA_ACCELERATION = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])
FRANKA_JERK = np.array([7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0])


@cache
def arm_kinematics(layout: CellLayout = LAYOUT) -> ArmKinematics:
    """The arm of the scene model of ``layout``, its arrays kept across runs in rapidds's
    cache (:mod:`rapidds.cache`): read back, they need neither MuJoCo's import nor the model's
    compile, 0.9 s of a painting process that plans and renders nothing in MuJoCo."""
    from rapidds.cache import cached_arrays, code_version, content_key

    def build() -> dict[str, np.ndarray]:
        arm = ArmKinematics.from_model(load_model(layout))
        return {f: getattr(arm, f) for f in _ARM_FIELDS}

    key = content_key(code_version(__file__), model_key(layout))
    return ArmKinematics(**cached_arrays("painting-arm", key, _ARM_FIELDS, build))


_ARM_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(ArmKinematics) if f.init
                                     and not f.name.startswith("_"))


def solve_ik(target: Sequence[float], seed: Sequence[float], *, layout: CellLayout = LAYOUT,
             tol: float = 1e-3) -> np.ndarray:
    """Joint vector (7,) putting the tool tip at ``target`` (world, metres) with the tool
    pointing straight down (its yaw left free), by differential IK with ``mink`` (QP solver
    daqp) from ``seed``. A posture task towards the seed, relaxed in three stages of 60 steps
    (cost 1e-1, 1e-2, 1e-4), keeps the solution on the seed's branch (elbow up, wrist as in the
    seed), so nearby targets from one seed get nearby joint vectors; the last stage makes the
    error negligible (about 1e-6 m on this cell's targets).

    Raises ValueError when the tip ends farther than ``tol`` from the target, the tool is
    tilted by more than 0.01 rad, or a joint leaves its range (an unreachable target).
    """
    import mink

    model = load_model(layout)
    kin = arm_kinematics(layout)
    cfg = mink.Configuration(model)
    q0 = np.zeros(model.nq)
    q0[:7] = np.asarray(seed, dtype=float)
    cfg.update(q0)
    goal = np.asarray(target, dtype=float)
    # Tool z axis down (the world rotated by pi about x); zero cost on the local z rotation
    # frees the yaw about the tool axis.
    frame = mink.FrameTask("end_effector", "site", position_cost=1.0,
                           orientation_cost=(1.0, 1.0, 0.0), lm_damping=1e-3)
    frame.set_target(mink.SE3.from_rotation_and_translation(
        mink.SO3.from_matrix(np.diag([1.0, -1.0, -1.0])), goal))
    posture = mink.PostureTask(model, cost=1e-1)
    posture.set_target(q0)
    limits = [mink.ConfigurationLimit(model)]
    for cost in (1e-1, 1e-2, 1e-4):
        posture.set_cost(cost)
        for _ in range(60):
            vel = mink.solve_ik(cfg, [frame, posture], 0.05, "daqp", damping=1e-4,
                                limits=limits)
            cfg.integrate_inplace(vel, 0.05)
    q = cfg.q[:7].copy()
    miss = float(np.linalg.norm(kin.tool(q) - goal))
    _, rot = kin.link_frames(q)
    tilt = float(np.arccos(np.clip(-rot[7][2, 2], -1.0, 1.0)))
    if miss > tol or tilt > 0.01 or np.any(q < kin.lower) or np.any(q > kin.upper):
        raise ValueError(f"IK did not reach {tuple(round(float(v), 3) for v in goal)}: tool "
                         f"{miss * 1000:.1f} mm away, tilted {tilt:.3f} rad")
    return q


def tool_path_ik(positions: np.ndarray, seed: Sequence[float], *,
                 layout: CellLayout = LAYOUT) -> np.ndarray:
    """Joint vectors (T, 7) for tool-tip positions (T, 3) given in the arm's base frame (link0):
    :func:`solve_ik` row by row, each seeded with the previous answer (the first with
    ``seed``), so the path stays on one branch. ValueError naming the first unreachable row."""
    kin = arm_kinematics(layout)
    world = np.asarray(positions, dtype=float) @ kin.base_rot.T + kin.base_pos
    out, q = [], np.asarray(seed, dtype=float)
    for k, target in enumerate(world):
        try:
            q = solve_ik(target, q, layout=layout)
        except ValueError as exc:
            raise ValueError(f"row {k + 1}: {exc}") from None
        out.append(q)
    return np.array(out)
