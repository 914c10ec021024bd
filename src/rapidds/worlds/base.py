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

A world in three parts (docs/architecture.md, "Where a new world goes")
    :class:`WorldSpec`, its constants and names as data; the behaviour every world has (the
    :class:`World` protocol's methods); and named optional capabilities it declares in its spec
    (:mod:`rapidds.worlds.capabilities`), asked for by name, never probed. :class:`WorldBase`
    derives the protocol's data members from the spec, so a world writes each constant once.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, NamedTuple, Protocol, runtime_checkable

import numpy as np
from pydantic import Field

from rapidds.problem import Problem
from rapidds.settings import Int, Positive, settings_dataclass

if TYPE_CHECKING:
    from matplotlib.axes import Axes

__all__ = [
    "Capability",
    "Horizon",
    "HumanExecution",
    "PopulationPrior",
    "RobotDemos",
    "SimulatedTeammate",
    "SteadyPerson",
    "Teammate",
    "World",
    "WorldBase",
    "WorldBehaviour",
    "WorldSpec",
    "body_point_names",
    "body_points",
    "joint_names",
    "perform_all",
    "shipped_policies",
]

Horizon = Annotated[Int, Field(gt=0, multiple_of=8)]
"""Rows of a robot trajectory: the diffusion policy's U-Net halves it three times."""

Capability = Literal["browser_play", "physics", "participants", "priming", "reactions",
                     "robot_limits", "robot_timing", "end_effector_ik", "tracking_mapping",
                     "tensor_values", "point_values"]
"""The optional capabilities a world may declare (:mod:`rapidds.worlds.capabilities` says what
each one promises and who asks for it)."""

Names = tuple[str, ...]


@settings_dataclass("WorldSpec", eq=False)
class WorldSpec:
    """A world's constants and names: data, no behaviour, checked when built (one line).

    name: the registry name. task_ids: task ids in problem order. state_dim: d, coordinates of
    one robot row. workspace_dim: d_ws. workspace_bounds: (lo, hi), the box the spatial model's
    grid spans. spatial_beta: beta of Eq. 7, 1 / workspace unit. spatial_grid: grid points per
    workspace axis. teammate_names: its simulated teammates (the vocabulary of --human).
    variants: the job's variants, the default first. views: named 2-D views for pictures, view
    -> (horizontal, vertical) workspace axes. policy_defaults: DiffusionConfig fields its policy
    is trained with. joint_names, body_point_names: the robot's d coordinates and the person's
    K body points as a driver and a tracker name them (None: ``joint1`` .., ``point1`` ..).
    capabilities: what it can do beyond the contract. resources: the package holding its
    ``policy/`` checkpoint and ``tracking.yaml`` (None: it ships neither).
    """

    name: Annotated[str, Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_-]*$")]
    task_ids: Annotated[Names, Field(min_length=1)]
    state_dim: Annotated[Int, Field(ge=1)]
    workspace_dim: Annotated[Int, Field(ge=1)]
    workspace_bounds: tuple[tuple[float, ...], tuple[float, ...]]
    spatial_beta: Positive
    spatial_grid: Annotated[Int, Field(ge=2)]
    teammate_names: Annotated[Names, Field(min_length=1)]
    variants: Annotated[Names, Field(min_length=1)] = ("default",)
    views: dict[str, tuple[int, int]] = field(default_factory=lambda: {"top": (0, 1)})
    policy_defaults: dict[str, Any] = field(default_factory=dict)
    joint_names: Names | None = None
    body_point_names: Names | None = None
    capabilities: tuple[Capability, ...] = ()
    resources: str | None = None

    def __post_init__(self) -> None:
        lo, hi = (np.asarray(b, dtype=float) for b in self.workspace_bounds)
        if lo.shape != (self.workspace_dim,) or hi.shape != lo.shape or not np.all(lo < hi):
            raise ValueError(f"workspace_bounds must be two {self.workspace_dim}-vectors with "
                             f"lo < hi, got {self.workspace_bounds}")
        if self.joint_names is not None and len(self.joint_names) != self.state_dim:
            raise ValueError(f"{len(self.joint_names)} joint names for a {self.state_dim}-D "
                             "robot")
        for view, axes in self.views.items():
            if not all(0 <= a < self.workspace_dim for a in axes):
                raise ValueError(f"view {view!r} names axes {axes} of a "
                                 f"{self.workspace_dim}-D workspace")


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


def perform_all(person: SimulatedTeammate, tasks: Sequence[str],
                rng: np.random.Generator) -> dict[str, HumanExecution]:
    """``person`` performs ``tasks`` in order: task -> :class:`HumanExecution`."""
    out = {}
    for task in tasks:
        d, path = person.perform(task, rng)
        out[task] = HumanExecution(task, float(d), np.asarray(path, dtype=float))
    return out


class SteadyPerson:
    """``at`` and ``execute`` of a simulated person who is the same in every cycle: they only
    write ``perform`` and their true durations."""

    def at(self, cycle: int) -> Any:
        """The same person in every cycle."""
        return self

    def execute(self, cycle: int, tasks: Sequence[str],
                rng: np.random.Generator) -> dict[str, HumanExecution]:
        """The person as they are in ``cycle`` performs ``tasks`` in order."""
        return perform_all(self.at(cycle), tasks, rng)


@runtime_checkable
class WorldBehaviour(Protocol):
    """What every world must do: its spec, its settings (variant, dt, horizon) and behaviour.
    A world that subclasses :class:`WorldBase` writes only these."""

    @property
    def spec(self) -> WorldSpec:
        """Its constants and names."""
        ...

    @property
    def variant(self) -> str:
        """Which variant of the job (one of ``spec.variants``), e.g. painting's "constrained"."""
        ...

    @property
    def dt(self) -> float:
        """Seconds per trajectory row (robot and human)."""
        ...

    @property
    def horizon(self) -> int:
        """H, rows per robot trajectory; a multiple of 8 (the U-Net halves it three times)."""
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

    def motion_label(self, task: str, traj: np.ndarray) -> str:
        """A short name for the motion a (H, d) robot trajectory takes, for reports (fetch:
        "middle" or "outside"); not used for planning."""
        ...

    def draw(self, ax: Axes, view: str) -> None:
        """Draw the static scene (walls, tables, trays, homes) into ``ax`` in ``view``."""
        ...


@runtime_checkable
class World(WorldBehaviour, Protocol):
    """One job cell as the loop, the CLI and the pictures read it: the behaviour, and the spec's
    data as members (what :class:`WorldBase` derives). Optional abilities are capabilities
    (:func:`rapidds.worlds.capabilities.capability`), not members."""

    @property
    def name(self) -> str: ...

    @property
    def variants(self) -> tuple[str, ...]: ...

    @property
    def task_ids(self) -> tuple[str, ...]: ...

    @property
    def state_dim(self) -> int: ...

    @property
    def workspace_dim(self) -> int: ...

    @property
    def workspace_bounds(self) -> tuple[np.ndarray, np.ndarray]: ...

    @property
    def spatial_beta(self) -> float: ...

    @property
    def spatial_grid(self) -> int: ...

    @property
    def teammate_names(self) -> tuple[str, ...]: ...

    @property
    def policy_defaults(self) -> Mapping[str, Any]: ...

    @property
    def views(self) -> Mapping[str, tuple[int, int]]: ...

    @property
    def penalty(self) -> float:
        """The completion time of a robot trajectory that never completes its task."""
        ...

    def bundled_policy(self) -> Path | None:
        """Directory of the policy checkpoint shipped with this world, if there is one."""
        ...


class WorldBase:
    """The members every world derives from its :class:`WorldSpec` the same way (fetch and
    painting had each written them out). A subclass provides ``spec`` (a cached property or a
    field), ``dt``, ``horizon`` and the behaviour of :class:`WorldBehaviour`."""

    @property
    def spec(self) -> WorldSpec:
        raise NotImplementedError(f"{type(self).__name__} must provide its spec")

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def variants(self) -> tuple[str, ...]:
        return self.spec.variants

    @property
    def task_ids(self) -> tuple[str, ...]:
        return self.spec.task_ids

    @property
    def state_dim(self) -> int:
        return self.spec.state_dim

    @property
    def workspace_dim(self) -> int:
        return self.spec.workspace_dim

    @property
    def workspace_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.spec.workspace_bounds
        return np.array(lo, dtype=float), np.array(hi, dtype=float)

    @property
    def spatial_beta(self) -> float:
        return self.spec.spatial_beta

    @property
    def spatial_grid(self) -> int:
        return self.spec.spatial_grid

    @property
    def teammate_names(self) -> tuple[str, ...]:
        return self.spec.teammate_names

    @property
    def policy_defaults(self) -> dict[str, Any]:
        return dict(self.spec.policy_defaults)

    @property
    def views(self) -> dict[str, tuple[int, int]]:
        return dict(self.spec.views)

    @property
    def penalty(self) -> float:
        """Completion time given to a trajectory that never completes its task: 2 * H * dt."""
        return 2.0 * self.horizon * self.dt  # type: ignore[attr-defined]

    def bundled_policy(self) -> Path | None:
        """``policy/`` of the spec's resources package, when it holds a checkpoint."""
        path = self.resource("policy")
        return path if path is not None and (path / "config.json").is_file() else None

    @property
    def tracking_mapping(self) -> Path:
        """The YAML mapping of tracked frames to the body points (the ``tracking_mapping``
        capability): ``tracking.yaml`` of the spec's resources package."""
        path = self.resource("tracking.yaml")
        if path is None:
            raise ValueError(f"world {self.name} ships no resources package")
        return path

    def resource(self, name: str) -> Path | None:
        """``name`` inside the spec's resources package (None: the world ships none)."""
        package = self.spec.resources
        return None if package is None else Path(str(files(package) / name))


def shipped_policies(world: World) -> dict[str, Path]:
    """The checkpoints ``world`` ships, by name: "paper", its bundled policy (the paper's
    network), and "NAME" for each ``policy-NAME/`` beside it (painting: "distilled")."""
    bundled = world.bundled_policy()
    if bundled is None:
        return {}
    return {"paper": bundled} | {d.name.removeprefix("policy-"): d
                                 for d in sorted(bundled.parent.glob("policy-*"))
                                 if (d / "config.json").is_file()}


def joint_names(world: World) -> tuple[str, ...]:
    """The names of the robot's ``state_dim`` coordinates (a JointTrajectory's joint names):
    the spec's ``joint_names`` if it states them, else ``joint1`` .. ``joint{d}``."""
    names = world.spec.joint_names
    if names is None:
        return tuple(f"joint{k}" for k in range(1, world.state_dim + 1))
    return tuple(names)


def body_point_names(world: World) -> tuple[str, ...]:
    """The names of the K body points of a human path (tracked frames): the spec's
    ``body_point_names`` if it states them, else ``point1`` .. ``point{K}``."""
    k = np.asarray(world.human_rest()).reshape(-1, world.workspace_dim).shape[0]
    names = world.spec.body_point_names
    if names is None:
        return tuple(f"point{i}" for i in range(1, k + 1))
    if len(names) != k:
        raise ValueError(f"{world.name} declares {len(names)} body point names for {k} points")
    return tuple(names)
