"""The two seams every job plugs into: a :class:`World` (everything specific to one job cell) and
a :class:`Teammate` (whoever does the human's tasks: a simulated person, someone in a browser, an
experimenter typing observations).

Nothing outside a world's folder knows its name: the loop, the CLI, the plots and the studies
reach it through this contract and :mod:`rapidds.worlds.registry`.

Spaces and shapes
    Robot trajectory xi: (H, d) in the robot's own coordinates (fetch: its (x, y) position;
    painting: 7 joint angles), row k at time k * dt, row 0 the start pose; batched (..., H, d).

    Workspace: the physical space robot and person share, ``workspace_dim`` coordinates (fetch 2,
    painting 3). The spatial model (paper Eqs. 7-11) and every distance live there.
    :meth:`World.robot_points` maps robot trajectories into it: (..., H, P, d_ws), P body points
    per row (fetch: the robot itself, P = 1; an arm: points along its links by forward
    kinematics), so S_i(xi) is the max of s_i over all of them. The last of the P points is
    the robot's tool (end effector): what pictures draw as its path.

    Human path: (T, K, d_ws), K body points over time (fetch: K = 1; painting: hands and
    forearms), row t at time t * dt after the task started, the last row when it ended. A
    (T, d_ws) array is the K = 1 shorthand (:func:`body_points`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NamedTuple, Protocol, runtime_checkable

import numpy as np
from pydantic import Field

from rapidds.problem import Problem
from rapidds.settings import Int

if TYPE_CHECKING:
    from matplotlib.axes import Axes

__all__ = [
    "Horizon",
    "HumanExecution",
    "PopulationPrior",
    "RobotDemos",
    "SimulatedTeammate",
    "Teammate",
    "World",
    "body_point_names",
    "body_points",
    "joint_names",
]

Horizon = Annotated[Int, Field(gt=0, multiple_of=8)]
"""Rows of a robot trajectory: the diffusion policy's U-Net halves it three times."""


def body_points(path: np.ndarray) -> np.ndarray:
    """A human path as (T, K, d_ws); a (T, d_ws) path is one body point (K = 1)."""
    p = np.asarray(path, dtype=float)
    if p.ndim == 2:
        return p[:, None, :]
    if p.ndim != 3:
        raise ValueError(f"a human path must have shape (T, d) or (T, K, d), got {p.shape}")
    return p


@dataclass(frozen=True)
class HumanExecution:
    """What the person did for one task in one cycle: how long it took (s) and where their body
    points were meanwhile, (T, K, d_ws) or (T, d_ws), sampled at the world's ``dt``."""

    task: str
    duration: float
    trajectory: np.ndarray


@dataclass(frozen=True)
class PopulationPrior:
    """What is known about people before meeting this one: other people doing every task.

    durations: task -> their observed durations (s), the temporal prior (mean and spread).
    paths: task -> their paths, the spatial prior (paper Eq. 9).
    Every world draws both from ONE population, so planning and the CLI start from one belief.
    """

    durations: Mapping[str, Sequence[float]]
    paths: Mapping[str, Sequence[np.ndarray]]


class RobotDemos(NamedTuple):
    """Robot demonstrations, one per row; unpacks as (trajectories, task_index, task_names, modes).

    trajectories: (N, H, d) float64, row 0 the robot's start pose.
    task_index: (N,) int64 into ``task_names`` (the policy's one-hot order).
    task_names: the world's robot task ids.
    modes: (N,) str, the motion mode of each row (e.g. "middle", "outside", "direct",
        "avoidant"), so tests and plots can check that every mode is covered; the policy itself
        never sees it.
    """

    trajectories: np.ndarray
    task_index: np.ndarray
    task_names: tuple[str, ...]
    modes: np.ndarray


@runtime_checkable
class Teammate(Protocol):
    """Whoever does the human's tasks. The loop asks it what the person did in one cycle."""

    @property
    def name(self) -> str: ...

    def execute(
        self, cycle: int, tasks: Sequence[str], rng: np.random.Generator
    ) -> dict[str, HumanExecution]:
        """What the person did in cycle ``cycle`` for their ``tasks`` (in planned order):
        task -> :class:`HumanExecution`. A live person returns what was observed."""
        ...


@runtime_checkable
class SimulatedTeammate(Teammate, Protocol):
    """A simulated person: the ground truth a planner has to learn, and that an oracle knows."""

    def at(self, cycle: int) -> SimulatedTeammate:
        """The person as they are in ``cycle`` (themselves, unless they change over time)."""
        ...

    def perform(self, task: str, rng: np.random.Generator) -> tuple[float, np.ndarray]:
        """One execution of ``task``: (duration s, path (T, K, d_ws) or (T, d_ws))."""
        ...

    def true_mean_durations(self) -> dict[str, float]:
        """task -> true mean duration (s)."""
        ...

    def true_std_durations(self) -> dict[str, float]:
        """task -> true standard deviation of the duration (s)."""
        ...


@runtime_checkable
class World(Protocol):
    """One job cell: its problem, its people, its robot's motions and how to draw it."""

    @property
    def name(self) -> str:
        """Registry name, e.g. "fetch"."""
        ...

    @property
    def variant(self) -> str:
        """Which variant of the job (one of ``variants``), e.g. painting's "constrained"."""
        ...

    @property
    def variants(self) -> tuple[str, ...]:
        """Variants this world offers, the default first."""
        ...

    @property
    def task_ids(self) -> tuple[str, ...]:
        """Task ids in problem order; available without building the problem."""
        ...

    @property
    def dt(self) -> float:
        """Seconds per trajectory row (robot and human)."""
        ...

    @property
    def horizon(self) -> int:
        """H, rows per robot trajectory; a multiple of 8 (the U-Net halves it three times)."""
        ...

    @property
    def state_dim(self) -> int:
        """d, coordinates of one robot trajectory row."""
        ...

    @property
    def workspace_dim(self) -> int:
        """d_ws, coordinates of one workspace point."""
        ...

    @property
    def workspace_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo (d_ws,), hi (d_ws,)): the box the spatial model's grid spans."""
        ...

    @property
    def spatial_beta(self) -> float:
        """beta of Eq. 7 in 1 / workspace unit (fetch: 1 per metre on a 10 m map)."""
        ...

    @property
    def spatial_grid(self) -> int:
        """Grid points per workspace axis of the spatial model (V = this ** d_ws)."""
        ...

    @property
    def teammate_names(self) -> tuple[str, ...]:
        """Names of the simulated teammates this world offers (its vocabulary for --human)."""
        ...

    @property
    def policy_defaults(self) -> Mapping[str, Any]:
        """DiffusionConfig fields this world's policy is trained with (network size, steps)."""
        ...

    @property
    def views(self) -> Mapping[str, tuple[int, int]]:
        """Named 2-D views for pictures: view -> (horizontal, vertical) workspace axes."""
        ...

    def problem(self) -> Problem:
        """Tasks, precedence, human priors from :meth:`prior`, robot nominal durations and the
        objective's default weights (gamma, lambda)."""
        ...

    def prior(self) -> PopulationPrior:
        """The population of other people, the one source of the temporal and spatial priors."""
        ...

    def teammate(self, name: str) -> SimulatedTeammate:
        """The simulated teammate ``name`` (one of ``teammate_names``); ValueError otherwise."""
        ...

    def robot_points(self, traj: np.ndarray) -> np.ndarray:
        """Workspace points of robot trajectories: (..., H, d) -> (..., H, P, d_ws)."""
        ...

    def robot_rest(self) -> np.ndarray:
        """(d,) the robot's pose while it has no task; every robot task starts and ends there."""
        ...

    def human_rest(self) -> np.ndarray:
        """(K, d_ws) where the person's body points are while they have no task."""
        ...

    def completion_time(self, task: str, traj: np.ndarray) -> np.ndarray:
        """d_j^r: seconds after which robot trajectories (..., H, d) have finished ``task``; a
        large finite penalty for one that never does (or cannot be executed)."""
        ...

    def robot_demonstrations(self, n_per_mode: int, rng: np.random.Generator) -> RobotDemos:
        """``n_per_mode`` noisy, executable demonstrations of every motion mode of every robot
        task: the policy's training set."""
        ...

    def bundled_policy(self) -> Path | None:
        """Directory of the policy checkpoint shipped with this world, if there is one."""
        ...

    def motion_label(self, task: str, traj: np.ndarray) -> str:
        """A short name for the motion a (H, d) robot trajectory takes, for reports (fetch:
        "middle" or "outside"); not used for planning."""
        ...

    def draw(self, ax: Axes, view: str) -> None:
        """Draw the static scene (walls, tables, trays, homes) into ``ax`` in ``view``."""
        ...

    # Optional, read through :func:`joint_names` and :func:`body_point_names` (not members of
    # the protocol, so a user's world without them still is a World):
    #   joint_names: tuple[str, ...], the d coordinates of a robot row as its driver names them;
    #   body_point_names: tuple[str, ...], the K body points of a human path, as frame names;
    #   tracking_mapping: Path, the YAML mapping of a tracker's frames to those body points
    #   (rapidds.bridge.recorded);
    #   robot_limits: rapidds.motion.timing.JointLimits, the robot's joint limits (what its
    #   trajectories are time-parameterized within when they leave rapidds);
    #   robot_duration(task, traj) -> float: the planner's d_j^r of one (H, d) trajectory when
    #   it is not ``completion_time`` (the painting arm's: the parameterized time);
    #   end_effector_ik(positions (T, 3) in the robot's base frame) -> (T, d): the robot's
    #   joints putting its tool there (rapidds.bridge.poses, CSV demonstrations).


def joint_names(world: World) -> tuple[str, ...]:
    """The names of the robot's ``state_dim`` coordinates (a JointTrajectory's joint names):
    the world's ``joint_names`` if it declares them, else ``joint1`` .. ``joint{d}``."""
    names = getattr(world, "joint_names", None)
    if names is None:
        return tuple(f"joint{k}" for k in range(1, world.state_dim + 1))
    if len(names) != world.state_dim:
        raise ValueError(f"{world.name} declares {len(names)} joint names for a "
                         f"{world.state_dim}-D robot")
    return tuple(names)


def body_point_names(world: World) -> tuple[str, ...]:
    """The names of the K body points of a human path (tracked frames): the world's
    ``body_point_names`` if it declares them, else ``point1`` .. ``point{K}``."""
    k = np.asarray(world.human_rest()).reshape(-1, world.workspace_dim).shape[0]
    names = getattr(world, "body_point_names", None)
    if names is None:
        return tuple(f"point{i}" for i in range(1, k + 1))
    if len(names) != k:
        raise ValueError(f"{world.name} declares {len(names)} body point names for {k} points")
    return tuple(names)
