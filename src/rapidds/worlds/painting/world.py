"""The collaborative-painting world, the paper's robot case ("Collaborative Painting"): a Franka
Emika Panda and a person at one table (scene: :mod:`rapidds.worlds.painting.scene`).

Tasks: ``prep_vise`` (open the vise) then ``secure_piece`` (clamp the workpiece), the person's
only; ``mix_l`` and ``mix_r`` (paint from the left / right tray into the bowl), the robot's
only; ``brush`` (paint the piece), either agent's, after the piece is secured and both paints
are mixed. The ``constrained`` variant adds Mix R before Mix L.

Robot trajectories are (H, 7) joint vectors (the fingers stay fixed), row k at time k * dt;
``robot_points`` maps them to 12 points along the arm (forward kinematics), where the spatial
model, in the 3-D workspace, scores them. People are 4 body points (hands and elbows).

Completion time d_j^r: the first row k (reported as k * dt) at which the tool tip is back
within ``rest_radius`` of its rest position after visiting the task's goals in order (mix: the
paint in its tray, then the bowl; brush: one end of the workpiece's top, then the other). A
trajectory that never does so takes ``penalty`` = 2 * H * dt plus ``SHORTFALL_RATE`` (100 s per
metre) times how far it stays short (the distance still to go to each goal it misses, from the
rows after the earlier goals); one that cannot be executed takes H * dt more: leaving a joint's
range, a joint faster than 1.1 times its speed limit between rows, or any arm point (a sphere
of its link's radius) touching the table top or a fixed object; only the tool tip may enter the
trays, the bowl and the workpiece. The graded penalty matters for steering: early in the
reverse process every candidate's clean estimate misses the goals, and with one flat penalty
the spatial term alone would pick among them, which always favours the avoidant mode.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import field
from functools import cached_property
from typing import TYPE_CHECKING, Annotated, ClassVar, Literal, get_args

import numpy as np
from pydantic import Field

from rapidds.problem import Objective, Problem, Task
from rapidds.settings import Int, NonNegative, Positive, settings_dataclass
from rapidds.worlds.base import Horizon, PopulationPrior, RobotDemos, WorldBase, WorldSpec
from rapidds.worlds.painting.reactions import REACTIONS, SAFETY
from rapidds.worlds.painting.scene import ARM_JOINTS, LAYOUT, Box, CellLayout
from rapidds.worlds.reactions import ReactionPopulation, SafetyLimits

if TYPE_CHECKING:
    import mujoco
    import torch
    from matplotlib.axes import Axes

    from rapidds.motion.timing import JointLimits
    from rapidds.worlds.painting.kinematics import ArmKinematics
    from rapidds.worlds.painting.motions import Motion
    from rapidds.worlds.painting.teammates import PaintingTeammate
    from rapidds.worlds.painting.tensor_value import PaintingTensorValues

__all__ = [
    "PRECEDENCE",
    "TASK_IDS",
    "VARIANTS",
    "PaintingWorld",
]

TASK_IDS: tuple[str, ...] = ("prep_vise", "secure_piece", "mix_l", "mix_r", "brush")
Variant = Literal["unconstrained", "constrained"]
VARIANTS: tuple[str, ...] = get_args(Variant)
PRECEDENCE: tuple[tuple[str, str], ...] = (
    ("prep_vise", "secure_piece"),
    ("secure_piece", "brush"),
    ("mix_l", "brush"),
    ("mix_r", "brush"),
)
_DESCRIPTIONS = {
    "prep_vise": "open the vise",
    "secure_piece": "clamp the workpiece in the vise",
    "mix_l": "transfer paint from the left tray to the bowl",
    "mix_r": "transfer paint from the right tray to the bowl",
    "brush": "brush the mixed paint onto the piece",
}
_ALLOWED = {"prep_vise": ("human",), "secure_piece": ("human",), "mix_l": ("robot",),
            "mix_r": ("robot",), "brush": ("human", "robot")}
_ROBOT_TASKS = ("mix_l", "mix_r", "brush")
_SPEED_MARGIN = 1.1   # a row-to-row joint speed above this times the limit cannot be executed
_GOAL_INSET = 0.015   # m, goal footprints are the containers' inner areas shrunk by this
SHORTFALL_RATE = 100.0  # s per metre a trajectory that never completes stays short of doing so

# Diffusion policy of this world. The fetch network ([16, 32, 64]) is too small for 7-D joint
# trajectories: trained 6000 steps it completed 7 % of its mix samples (the tool ended 10 cm from
# rest); [24, 48, 96] completes over 90 % after 3000 steps (docs/benchmarks.md, "Painting
# policy").
POLICY_DEFAULTS: dict[str, object] = {
    "down_dims": [24, 48, 96],
    "num_inference_steps": 10,
    "steps": 5000,
    "batch_size": 64,
    "lr": 2e-3,
}


@settings_dataclass("PaintingWorld", eq=False)
class PaintingWorld(WorldBase):
    """The painting cell (module docstring).

    variant: "unconstrained" (mix order free) or "constrained" (Mix R before Mix L).
    dt: seconds per trajectory row; horizon: H, a multiple of 8, long enough for the slowest
    demonstration. rest_radius: metres within which the tool is back at rest. gamma, lam: the
    objective's default weights (the paper's painting runs use gamma 12, 25 and 85; lambda 10
    explores the one shared task, Brush; see docs/design-notes.md, "The painting cell").
    beta: spatial decay, 1/m. grid: spatial grid points per axis. prior_people,
    prior_samples, prior_seed: the population the priors come from. layout: the cell.
    """

    # how its people react and how its robot stops (its ``reactions`` capability)
    reaction_population: ClassVar[ReactionPopulation] = REACTIONS
    safety_limits: ClassVar[SafetyLimits] = SAFETY

    variant: Variant = "unconstrained"
    dt: Positive = 0.15
    horizon: Horizon = 64
    rest_radius: Positive = 0.03
    gamma: NonNegative = 12.0
    lam: NonNegative = 10.0
    beta: Positive = 14.0
    grid: Annotated[Int, Field(ge=2)] = 22
    prior_people: Annotated[Int, Field(ge=2)] = 40
    prior_samples: Annotated[Int, Field(ge=1)] = 1
    prior_seed: Int = 0
    layout: CellLayout = field(default=LAYOUT, repr=False)

    # -- the World protocol ---------------------------------------------------------------------
    @cached_property
    def spec(self) -> WorldSpec:
        """Workspace: the table's working volume, where arm and hands can come close (higher
        arm points are clamped onto its top face by the spatial model, where people are > 0.4 m
        away). Joints: the Panda's seven as the shipped MJCF names them
        (``robot:panda0_joint1..7``; franka_ros2 calls the same joints ``fr3_joint1..7``, in
        this order: README, "In a real cell"). Body points: left hand, right hand, left elbow,
        right elbow as ROS4HRI-like frames, a hand tracked at its wrist as ROS4HRI has it."""
        from rapidds.worlds.painting.teammates import ARCHETYPES

        return WorldSpec(
            name="painting", task_ids=TASK_IDS, variants=VARIANTS, state_dim=7,
            workspace_dim=3, workspace_bounds=((-0.7, -0.65, -0.05), (0.7, 0.7, 0.65)),
            spatial_beta=self.beta, spatial_grid=self.grid, teammate_names=tuple(ARCHETYPES),
            views={"top": (0, 1), "side": (1, 2)}, policy_defaults=dict(POLICY_DEFAULTS),
            joint_names=ARM_JOINTS, body_point_names=("l_wrist", "r_wrist", "l_elbow", "r_elbow"),
            resources="rapidds.worlds.painting",
            capabilities=("physics", "participants", "priming", "reactions", "robot_limits",
                          "robot_timing", "end_effector_ik", "tracking_mapping",
                          "tensor_values", "point_values"))

    @property
    def priming_factors(self) -> dict[str, tuple[str, ...]]:
        """A user study's priming factors: their factorial names :attr:`teammate_names`."""
        return {"hand": ("left", "right"), "speed": ("fast", "slow")}

    def problem(self) -> Problem:
        return self._problem

    @cached_property
    def _problem(self) -> Problem:
        prior = self.prior()
        tasks = []
        for task in TASK_IDS:
            allowed = _ALLOWED[task]
            mean = std = robot = None
            if "human" in allowed:
                d = np.asarray(prior.durations[task], dtype=float)
                mean, std = round(float(d.mean()), 2), round(float(d.std(ddof=1)), 2)
            if "robot" in allowed:
                robot = self.robot_duration(task, self.robot_trajectory(task))
            tasks.append(Task(id=task, allowed=frozenset(allowed), human_mean=mean,
                              human_std=std, robot_duration=robot,
                              description=_DESCRIPTIONS[task]))
        precedence = PRECEDENCE + ((("mix_r", "mix_l"),) if self.variant == "constrained" else ())
        name = "painting" if self.variant == "unconstrained" else f"painting-{self.variant}"
        return Problem(name, tuple(tasks), precedence, Objective(self.gamma, self.lam))

    def prior(self) -> PopulationPrior:
        return self._prior

    @cached_property
    def _prior(self) -> PopulationPrior:
        from rapidds.worlds.painting.teammates import population, population_statistics

        rng = np.random.default_rng(self.prior_seed)
        people = population(self.prior_people, rng, dt=self.dt, layout=self.layout)
        durations, paths = population_statistics(people, self.prior_samples, rng)
        return PopulationPrior(durations, paths)

    def teammate(self, name: str) -> PaintingTeammate:
        from rapidds.worlds.painting.teammates import archetype

        return archetype(name, dt=self.dt, layout=self.layout)

    def participant(self, name: str, levels: Mapping[str, str],
                    rng: np.random.Generator) -> PaintingTeammate:
        """A simulated study participant primed as ``levels`` (``hand``: left / right,
        ``speed``: fast / slow, the user study's priming factors), drawn around that group:
        their own durations and paths (:func:`.teammates.individual`)."""
        from rapidds.worlds.painting.teammates import individual

        missing = [f for f in ("hand", "speed") if f not in levels]
        if missing:
            raise ValueError(f"a painting participant needs the priming factor(s) "
                             f"{', '.join(missing)} (hand: left/right, speed: fast/slow)")
        return individual(name, levels["hand"], levels["speed"], rng, dt=self.dt,
                          layout=self.layout)

    def robot_points(self, traj: np.ndarray) -> np.ndarray:
        """(..., H, 7) joint trajectories -> (..., H, 12, 3) points along the arm."""
        return self.kinematics.points(traj)

    def tensor_terms(self, device: torch.device | str) -> PaintingTensorValues:
        """The steering value's terms as tensor operations on ``device`` (points, completion
        time: :mod:`rapidds.worlds.painting.tensor_value`), built once per device."""
        from rapidds.worlds.painting.tensor_value import CellValues, tensor_terms

        cell = CellValues(self.kinematics, self.dt, self.horizon, self.penalty, _SPEED_MARGIN,
                          SHORTFALL_RATE, float(self.rest_radius), self._rest_tool,
                          self._goal_table, self._obstacle_arrays)
        return tensor_terms(cell, device, self._tensor_cache)

    @cached_property
    def _tensor_cache(self) -> dict[torch.device, PaintingTensorValues]:
        return {}

    def end_effector_ik(self, positions: np.ndarray) -> np.ndarray:
        """Joint path (T, 7) putting the tool tip at ``positions`` (T, 3), given in the arm's
        base frame (link0, Franka's ``O`` frame, as ``O_T_EE`` is recorded), tool pointing
        down; each row seeded with the previous answer, the first with the rest pose
        (:func:`~rapidds.worlds.painting.kinematics.tool_path_ik`)."""
        from rapidds.worlds.painting.kinematics import tool_path_ik

        return tool_path_ik(positions, self.robot_rest(), layout=self.layout)

    @property
    def robot_limits(self) -> JointLimits:
        """The arm's joint limits: the MJCF's ranges and the Panda datasheet's velocity,
        acceleration and jerk (what :mod:`rapidds.motion.timing` parameterizes within)."""
        from rapidds.motion.timing import JointLimits
        from rapidds.worlds.painting.kinematics import FRANKA_ACCELERATION, FRANKA_JERK

        kin = self.kinematics
        return JointLimits(kin.lower, kin.upper, kin.velocity, FRANKA_ACCELERATION, FRANKA_JERK)

    def robot_rest(self) -> np.ndarray:
        from rapidds.worlds.painting.motions import rest_pose

        return rest_pose(self.layout).copy()

    def human_rest(self) -> np.ndarray:
        from rapidds.worlds.painting.teammates import rest_points

        return rest_points(self.layout)

    def completion_time(self, task: str, traj: np.ndarray) -> np.ndarray:
        """(...,) seconds for (..., H, 7) robot trajectories (module docstring). One that never
        completes ``task`` gets ``penalty`` plus ``SHORTFALL_RATE`` seconds per metre it stays
        short (module docstring), and ``horizon * dt`` more when it cannot be executed."""
        return self.completion_time_from_points(task, traj, None)

    def completion_time_from_points(self, task: str, traj: np.ndarray,
                                    points: np.ndarray | None) -> np.ndarray:
        """:meth:`completion_time` given the trajectories' arm points (..., H, P, 3) (their
        :meth:`robot_points`; None: computed here)."""
        goals = self._goals(task)
        q = np.asarray(traj, dtype=float)
        if q.ndim < 2 or q.shape[-1] != 7:
            raise ValueError(f"painting trajectories must have shape (..., H, 7), got {q.shape}")
        lead, h = q.shape[:-2], q.shape[-2]
        flat = q.reshape(-1, h, 7)
        pts = (self.kinematics.points(flat) if points is None                 # (N, H, P, 3)
               else np.asarray(points, dtype=float).reshape(flat.shape[0], h, -1, 3))
        tool = pts[:, :, -1]
        reached = np.ones((flat.shape[0], h), dtype=bool)
        short = np.zeros(flat.shape[0])
        rest = np.maximum(np.linalg.norm(tool - self._rest_tool, axis=-1) - self.rest_radius, 0.0)
        for gap in [_box_gap(tool, lo, hi) for lo, hi in goals] + [rest]:
            # distance still to go to this goal, from the rows after the earlier goals were met
            # (from any row when they never were)
            after = reached | ~reached.any(axis=1, keepdims=True)
            short += np.where(after, gap, np.inf).min(axis=1)
            reached = np.logical_or.accumulate((gap <= 0.0) & reached, axis=1)
        done = reached.any(axis=1)
        k = np.argmax(reached, axis=1)
        t = np.where(done, np.round(k * self.dt, 9), self.penalty + SHORTFALL_RATE * short)
        bad = ~self.executable(flat, pts)
        t = np.where(bad, self.penalty + self.horizon * self.dt + SHORTFALL_RATE * short, t)
        return t.reshape(lead).astype(float)

    def robot_duration(self, task: str, traj: np.ndarray) -> float:
        """The planner's d_j^r of one (H, 7) trajectory: the time the arm takes, within its
        limits (:attr:`robot_limits`), to follow the path up to the row that completes
        ``task`` (:func:`rapidds.motion.timing.row_times`); the penalty as
        :meth:`completion_time` gives it when the path never completes the task."""
        from rapidds.motion.timing import row_times

        q = np.asarray(traj, dtype=float)
        done = float(self.completion_time(task, q[None])[0])
        if done >= self.penalty:
            return done
        k = max(round(done / self.dt), 1)
        return round(float(row_times(q[:k + 1], self.dt, self.robot_limits)[k]), 9)

    def robot_demonstrations(self, n_per_mode: int, rng: np.random.Generator) -> RobotDemos:
        """``n_per_mode`` demonstrations of each mode ("direct", "avoidant") of each robot task
        (mix_l, mix_r, brush), in (task, mode) order.

        Noise, as in fetch: every waypoint between rest and rest is jittered in joint space
        (N(0, 0.03^2) rad; 0.004 rad at the dips and stroke ends, so goals stay reached), the
        pace by a factor N(1, 0.04) clipped to [0.92, 1.08] and the pauses by U(0.8, 1.2). A draw
        that is not executable or misses its task is redrawn, so every row is collision-free
        and completes its task.
        """
        from rapidds.worlds.painting.motions import MODES, nominal_motion

        if n_per_mode < 1:
            raise ValueError(f"n_per_mode must be >= 1, got {n_per_mode}")
        trajs, index, modes = [], [], []
        for i, task in enumerate(_ROBOT_TASKS):
            for mode in MODES:
                motion = nominal_motion(task, mode, self.layout)
                for _ in range(n_per_mode):
                    trajs.append(self._noisy(task, motion, rng))
                    index.append(i)
                    modes.append(mode)
        return RobotDemos(np.stack(trajs), np.array(index, dtype=np.int64), _ROBOT_TASKS,
                          np.array(modes))

    def motion_label(self, task: str, traj: np.ndarray) -> str:
        """"direct" or "avoidant": the mode whose nominal tool path lies closer to this
        trajectory's (mean distance from each tool position to the nearest point of the
        nominal path, both ways). For reports, not for planning."""
        from rapidds.worlds.painting.motions import MODES

        self._goals(task)
        tool = self.kinematics.tool(np.asarray(traj, dtype=float).reshape(-1, 7))
        best, label = math.inf, MODES[0]
        for mode in MODES:
            ref = self._nominal_tool[task, mode]
            gap = np.linalg.norm(tool[:, None] - ref[None], axis=-1)
            score = gap.min(axis=1).mean() + gap.min(axis=0).mean()
            if score < best:
                best, label = score, mode
        return label

    def draw(self, ax: Axes, view: str = "top") -> None:
        """Table, trays, bowl, vise, racks, robot base and the person at rest, seen from
        ``view`` ("top": x right, y away from the person; "side": y, z from the person's
        left)."""
        from matplotlib.patches import Circle, Rectangle

        if view not in self.views:
            raise ValueError(f"unknown view {view!r}; views are {', '.join(self.views)}")
        h, v = self.views[view]
        lay = self.layout
        colours = {"table": "0.85", "vise": "0.35", "vise_handle": "0.2", "workpiece": "tan",
                   "bowl": "0.95", "left_tray": "tab:blue", "right_tray": "tab:orange",
                   "left_rack": "0.55", "right_rack": "0.55"}
        boxes: dict[str, Box] = {"table": lay.table, **lay.obstacles()}
        for name, box in boxes.items():
            lo, hi = box.lo, box.hi
            # the table is an outline: drawn filled, it hid the heat map under it
            ax.add_patch(Rectangle((lo[h], lo[v]), hi[h] - lo[h], hi[v] - lo[v],
                                   facecolor="none" if name == "table" else colours[name],
                                   edgecolor="0.6" if name == "table" else "0.1",
                                   lw=1.0 if name == "table" else 0.6,
                                   zorder=1 if name == "table" else 2))
        base = np.array(lay.robot_base)
        ax.add_patch(Circle((base[h], base[v] + (0.0 if view == "top" else 0.05)), 0.07,
                            facecolor="0.3", edgecolor="k", zorder=3))
        ax.annotate("robot", (base[h], base[v]), xytext=(6, 6), textcoords="offset points",
                    fontsize=8)
        body = self.human_rest()
        shoulders = np.array([lay.left_shoulder, lay.right_shoulder])
        for k, side in enumerate(("left", "right")):
            arm = np.array([shoulders[k], body[2 + k], body[k]])
            ax.plot(arm[:, h], arm[:, v], "-o", color="tab:red", ms=3, lw=2, zorder=4,
                    label="person at rest" if side == "left" else None)
        ax.set_aspect("equal")
        names = "xyz"
        ax.set_xlabel(f"{names[h]} (m)")
        ax.set_ylabel(f"{names[v]} (m)")

    # -- physics (the reference robot of a live cell, rapidds.bridge.nodes) ---------------------
    def physics_model(self) -> mujoco.MjModel:
        """The cell compiled for ``mj_step``: the Panda's shipped position actuators, and the
        person's hands and forearms colliding with the arm (a fresh model per call)."""
        from rapidds.worlds.painting.scene import build_model

        return build_model(self.layout, physics=True)

    def place_person(self, model: mujoco.MjModel, data: mujoco.MjData,
                     points: np.ndarray) -> None:
        """Move the person's mocap hands and forearms to body points (K, 3), the order of
        :data:`~rapidds.worlds.painting.teammates.BODY_POINTS`."""
        from rapidds.worlds.painting.render import place_person

        place_person(model, data, np.asarray(points, dtype=float))

    # -- geometry and motions -------------------------------------------------------------------
    @property
    def kinematics(self) -> ArmKinematics:
        """The arm's forward kinematics (loads the MuJoCo scene on first use)."""
        from rapidds.worlds.painting.kinematics import arm_kinematics

        return arm_kinematics(self.layout)

    @cached_property
    def _nominal_tool(self) -> dict[tuple[str, str], np.ndarray]:
        """(task, mode) -> (H, 3) tool path of the noise-free motion."""
        return {(t, m): self.kinematics.tool(self.robot_trajectory(t, m))
                for t in _ROBOT_TASKS for m in self.modes(t)}

    @cached_property
    def _rest_tool(self) -> np.ndarray:
        return self.kinematics.tool(self.robot_rest())

    def modes(self, task: str) -> tuple[str, ...]:
        """Motion modes of a robot task, the default (fastest) first."""
        from rapidds.worlds.painting.motions import MODES

        if task not in _ROBOT_TASKS:
            raise ValueError(f"{task!r} is not a robot task of the painting world; robot tasks "
                             f"are {', '.join(_ROBOT_TASKS)}")
        return MODES

    def motion(self, task: str, mode: str | None = None) -> Motion:
        """The nominal motion of ``task`` in ``mode`` (default: direct)."""
        from rapidds.worlds.painting.motions import nominal_motion

        return nominal_motion(task, mode or self.modes(task)[0], self.layout)

    def robot_trajectory(self, task: str, mode: str | None = None) -> np.ndarray:
        """(H, 7) the robot's noise-free trajectory of ``task`` in ``mode`` (default direct)."""
        return self.motion(task, mode).sample(self.dt, self.horizon)

    def goal_boxes(self, task: str) -> list[tuple[np.ndarray, np.ndarray]]:
        """(lo, hi) boxes the tool tip must visit in order to do ``task``."""
        return [(lo.copy(), hi.copy()) for lo, hi in self._goals(task)]

    def executable(self, traj: np.ndarray, points: np.ndarray | None = None) -> np.ndarray:
        """(N,) bool for (N, H, 7) trajectories: within joint ranges, no joint faster than
        1.1 times its limit between rows, and no arm point touching the table or an object.
        ``points``: their (N, H, P, 3) arm points, when already computed."""
        kin = self.kinematics
        q = np.asarray(traj, dtype=float)
        in_range = ((q >= kin.lower) & (q <= kin.upper)).all(axis=(-1, -2))
        speed = np.abs(np.diff(q, axis=-2)) / self.dt
        slow = (speed <= _SPEED_MARGIN * kin.velocity).all(axis=(-1, -2))
        pts = kin.points(q) if points is None else points
        return in_range & slow & ~self.collides(pts)

    def collides(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool for arm points (N, H, P, 3): a point's sphere (its link radius) touches
        the table top (z = 0) or an object; the tool tip may enter trays, bowl and piece."""
        from rapidds.worlds.painting.kinematics import POINT_RADII, TOOL

        p = np.asarray(points, dtype=float)
        n = p.shape[0]
        flat = p.reshape(n, -1, 3)
        radius = np.broadcast_to(POINT_RADII, p.shape[1:-1]).reshape(-1)
        tool = np.zeros(p.shape[1:-1], dtype=bool)
        tool[..., TOOL] = True
        tool = tool.reshape(-1)
        bottom = flat[..., 2] - radius                     # lowest z of each point's sphere
        hit = (bottom < 0.0).any(axis=1)
        lows, highs, open_to_tool = self._obstacle_arrays
        # Only points low enough to reach an object need the box test, and only in rows not
        # already touching the table.
        rows, cols = np.nonzero((bottom < highs[:, 2].max()) & ~hit[:, None])
        if rows.size:
            c = flat[rows, cols]                                              # (M, 3)
            r = radius[cols]
            gap = np.maximum(lows[None] - c[:, None], 0.0) + np.maximum(c[:, None] - highs[None],
                                                                        0.0)  # (M, B, 3)
            touch = (gap * gap).sum(axis=-1) <= (r * r)[:, None]
            touch &= ~(tool[cols][:, None] & open_to_tool[None])
            hit[rows[touch.any(axis=1)]] = True
        return hit

    # -- internals ------------------------------------------------------------------------------
    @cached_property
    def _obstacle_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        obstacles = self.layout.obstacles()
        lows = np.array([b.lo for b in obstacles.values()])
        highs = np.array([b.hi for b in obstacles.values()])
        tool_ok = np.array([name in ("workpiece", "bowl", "left_tray", "right_tray")
                            for name in obstacles])
        return lows, highs, tool_ok

    def _goals(self, task: str) -> list[tuple[np.ndarray, np.ndarray]]:
        return self._goal_table[self._check_robot_task(task)]

    @cached_property
    def _goal_table(self) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
        from rapidds.worlds.painting.motions import DIP, STROKE_HALF

        lay = self.layout

        def paint(box: Box) -> tuple[np.ndarray, np.ndarray]:
            """The tool in the container's paint: inside its rim, below the rim by half a dip."""
            lo = box.lo + np.array([_GOAL_INSET, _GOAL_INSET, 0.0])
            hi = box.hi - np.array([_GOAL_INSET, _GOAL_INSET, DIP / 2])
            return lo, hi

        piece = lay.workpiece
        top = piece.hi[2]
        ends = []
        for sign in (-1.0, 1.0):
            c = np.array([piece.center[0] + sign * STROKE_HALF, piece.center[1], top + 0.005])
            half = np.array([0.012, 0.012, 0.01])
            ends.append((c - half, c + half))
        return {"mix_l": [paint(lay.left_tray), paint(lay.bowl)],
                "mix_r": [paint(lay.right_tray), paint(lay.bowl)],
                "brush": ends}

    def _check_robot_task(self, task: str) -> str:
        if task not in _ROBOT_TASKS:
            if task in TASK_IDS:
                raise ValueError(f"{task!r} is the person's task; the robot's are "
                                 f"{', '.join(_ROBOT_TASKS)}")
            raise ValueError(f"unknown painting task {task!r}; tasks are {', '.join(TASK_IDS)}")
        return task

    def _noisy(self, task: str, motion: Motion, rng: np.random.Generator,
               tries: int = 100) -> np.ndarray:
        goal_rows = motion.stop.copy()
        goal_rows[[0, -1]] = False
        for _ in range(tries):
            wp = motion.waypoints.copy()
            sd = np.where(goal_rows, 0.004, 0.03)[:, None]
            jitter = rng.normal(0.0, 1.0, size=wp.shape) * sd
            jitter[[0, -1]] = 0.0
            speed = float(np.clip(rng.normal(1.0, 0.04), 0.92, 1.08))
            pause = float(rng.uniform(0.8, 1.2))
            traj = motion.sample(self.dt, self.horizon, speed, wp + jitter, pause)
            if self.completion_time(task, traj[None])[0] < self.penalty and \
                    motion.duration(speed) < (self.horizon - 2) * self.dt:
                return traj
        return motion.sample(self.dt, self.horizon)  # nominal: tested to be valid


def _box_gap(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Distance (...,) of points (..., 3) to the box [lo, hi]; 0 inside."""
    out = np.maximum(lo - points, 0.0) + np.maximum(points - hi, 0.0)
    return np.linalg.norm(out, axis=-1)
