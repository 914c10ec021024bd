"""A robot arm under MuJoCo physics tracking joint trajectories with its position actuators.

The model is the world's (``world.physics_model()``): its position actuators and gains are the
shipped ones (the Panda's kp 870 / 120 N m/rad, force limits 87 / 12 N m, joint damping 100 /
10). ``compensate`` adds what a real arm's controller adds beneath a position interface
(franka_ros2's joint controllers run on the robot's gravity- and Coriolis-compensated torque
loop): the model's bias forces (``qfrc_bias``) and the joint damping times the target
velocity; without it the damping of the shipped model (a time constant of 0.1 s) makes the arm
lag its target by about a tenth of a second of motion. Both are measured in benchmarks/.

A task ends when the trajectory's last point is due and the arm has settled there (every joint
within ``tolerance`` rad and slower than ``still`` rad/s), or ``settle_max`` s after that at
the latest. Contacts between the robot's bodies and the person's (mocap) bodies are reported.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rapidds.errors import RapiddsError

__all__ = ["PhysicsArm", "Touch"]


@dataclass(frozen=True)
class Touch:
    """The robot's body touching a person's body, and how deep (m, > 0 is penetration)."""

    robot: str
    person: str
    depth: float


class PhysicsArm:
    """``model``'s joints ``joint_names`` driven by their position actuators under ``mj_step``."""

    def __init__(self, model: Any, joint_names: tuple[str, ...] | list[str], *,
                 compensate: bool = True, tolerance: float = 0.01, still: float = 0.05,
                 settle_max: float = 2.0):
        import mujoco

        self._mj = mujoco
        self.model, self.data = model, mujoco.MjData(model)
        self.joint_names = tuple(joint_names)
        jid = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in self.joint_names]
        if min(jid, default=-1) < 0:
            missing = [n for n, j in zip(self.joint_names, jid, strict=True) if j < 0]
            raise RapiddsError(f"the physics model has no joint(s) {', '.join(missing)}")
        self._qadr = model.jnt_qposadr[jid]
        self._dadr = model.jnt_dofadr[jid]
        act = {int(model.actuator_trnid[a, 0]): a for a in range(model.nu)
               if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT}
        if any(j not in act for j in jid):
            raise RapiddsError("the physics model has no position actuator on every arm joint")
        self._act = np.array([act[j] for j in jid])
        self._others = [(a, model.jnt_qposadr[j]) for j, a in act.items() if j not in jid]
        self.compensate, self.tolerance, self.still = compensate, tolerance, still
        self.settle_max = settle_max
        self._traj: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None = None
        # speed scaling: the fraction of its trajectory's timing the arm advances at (a hub's
        # speed and separation monitoring); lag: trajectory seconds it has fallen behind so.
        # At 1 the lag stays exactly 0, so an unscaled arm moves as it always did.
        self.speed = 1.0
        self._lag = 0.0
        self._person = {b for b in range(model.nbody) if model.body_mocapid[b] >= 0}
        self._robot = {b for b in range(model.nbody)
                       if model.body_weldid[b] != 0 and b not in self._person}

    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def q(self) -> np.ndarray:
        return self.data.qpos[self._qadr].copy()

    @property
    def qdot(self) -> np.ndarray:
        return self.data.qvel[self._dadr].copy()

    def reset(self, q: np.ndarray) -> None:
        """Arm at rest at ``q``; the other actuated joints (fingers) hold where they are."""
        self._mj.mj_resetData(self.model, self.data)
        self.data.qpos[self._qadr] = q
        self._traj = (0.0, np.zeros(1), np.asarray(q, float)[None], np.zeros((1, len(q))))
        self._lag = 0.0
        self._mj.mj_forward(self.model, self.data)

    def follow(self, positions: np.ndarray, times: np.ndarray) -> None:
        """Track ``positions`` (H, J) reached ``times`` (H,) s from now."""
        q = np.asarray(positions, dtype=float)
        t = np.asarray(times, dtype=float)
        vel = np.gradient(q, t, axis=0) if len(t) > 1 else np.zeros_like(q)
        vel[-1] = 0.0
        self._traj = (self.time, t, q, vel)
        self._lag = 0.0

    def hold(self) -> None:
        """Stop where the arm is now (a stop command)."""
        self._traj = (self.time, np.zeros(1), self.q[None], np.zeros((1, len(self._qadr))))
        self._lag = 0.0

    def target(self, when: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity) the arm is to be at, at sim time ``when`` (default: now)."""
        assert self._traj is not None, "reset() first"
        t0, t, q, v = self._traj
        s = (self.time if when is None else when) - t0 - self._lag
        if s >= t[-1]:
            return q[-1], np.zeros(q.shape[1])
        pos = np.array([np.interp(s, t, q[:, j]) for j in range(q.shape[1])])
        vel = v[min(int(np.searchsorted(t, s, side="right")) - 1, len(t) - 1)] * self.speed
        return pos, vel

    def step(self, seconds: float) -> None:
        """Advance the physics by ``seconds`` (whole model timesteps)."""
        m, d = self.model, self.data
        for _ in range(max(1, round(seconds / m.opt.timestep))):
            pos, vel = self.target()
            d.ctrl[self._act] = pos
            for a, adr in self._others:
                d.ctrl[a] = d.qpos[adr]
            d.qfrc_applied[:] = 0.0
            if self.compensate:
                d.qfrc_applied[:] = d.qfrc_bias
                d.qfrc_applied[self._dadr] += m.dof_damping[self._dadr] * vel
            self._mj.mj_step(m, d)
            self._lag += m.opt.timestep * (1.0 - self.speed)

    def remaining(self) -> float:
        """Seconds until the trajectory's last point is due (<= 0 once it is)."""
        assert self._traj is not None
        t0, t, _, _ = self._traj
        return t0 + float(t[-1]) + self._lag - self.time

    def settled(self) -> bool:
        """The trajectory is over and the arm has come to rest on its end (or settle_max s
        have passed since its end)."""
        left = self.remaining()
        if left > 0:
            return False
        err = np.abs(self.q - self.target()[0]).max()
        return bool((err < self.tolerance and np.abs(self.qdot).max() < self.still)
                    or -left >= self.settle_max)

    def tracking_error(self) -> float:
        """Largest joint error now (rad)."""
        return float(np.abs(self.q - self.target()[0]).max())

    def touches(self) -> list[Touch]:
        """The robot's bodies touching the person's bodies now."""
        m, d, name = self.model, self.data, self._mj.mj_id2name
        out = []
        c = d.contact  # the active contacts, as arrays
        for g1, g2, dist in zip(c.geom1[:d.ncon], c.geom2[:d.ncon], c.dist[:d.ncon], strict=True):
            b1, b2 = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
            if b1 in self._person:
                b1, b2 = b2, b1
            if b1 in self._robot and b2 in self._person:
                out.append(Touch(name(m, self._mj.mjtObj.mjOBJ_BODY, b1) or str(b1),
                                 name(m, self._mj.mjtObj.mjOBJ_BODY, b2) or str(b2),
                                 float(-dist)))
        return out
