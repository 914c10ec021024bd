"""The fetch game as a :class:`~rapidds.worlds.base.World`: the map of :mod:`.map`, the robot's
demonstrations and completion times, and the population the priors come from.

Time: ``dt`` = 0.2 s per step and ``H`` = 64 steps (12.8 s); the longest robot route (far
outside, 9.3 s) fits with room for the demonstrations' speed noise. A robot trajectory walks
its route at constant speed, then waits at home until row H - 1.

Completion time d_j^r: the first row k at which the trajectory is within ``reach_radius``
(0.5 m) of home after having been within 0.5 m of the object, reported as k * dt seconds (row k
is the pose at time k * dt, row 0 the start; a path back home at row k has finished at k * dt).
A trajectory that never does both, or touches a wall, gets ``2 * H * dt`` (25.6 s): finite, and
longer than any real completion.
"""

from __future__ import annotations

from dataclasses import field
from functools import cache, cached_property
from typing import TYPE_CHECKING, Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field

from rapidds.problem import AGENTS, Agent, Objective, Problem, Task
from rapidds.settings import Int, NonNegative, Positive, settings_dataclass
from rapidds.worlds.base import Horizon, PopulationPrior, RobotDemos, WorldBase, WorldSpec
from rapidds.worlds.fetch.map import (
    DESCRIPTIONS,
    HOMES,
    HUMAN_VIA,
    MIRROR_TASK,
    MODES,
    OBJECTS,
    PRECEDENCE,
    SIZE,
    TASK_IDS,
    WALLS,
    Route,
    mirror,
)
from rapidds.worlds.fetch.reactions import REACTIONS, SAFETY
from rapidds.worlds.fetch.teammates import ARCHETYPES, FetchTeammate, archetype, population
from rapidds.worlds.geometry import Rect, reach_then_return_time, segments_hit_rects
from rapidds.worlds.reactions import ReactionPopulation, SafetyLimits

if TYPE_CHECKING:
    import torch
    from matplotlib.axes import Axes

    from rapidds.motion.timing import JointLimits
    from rapidds.worlds.fetch.tensor_value import FetchTensorValues


__all__ = ["POLICY_DEFAULTS", "PRIOR_SEED", "FetchWorld", "default_world", "fetch_problem"]

PRIOR_SEED = 20_240_917  # the population of "other people" is the same for every run


@settings_dataclass("FetchWorld", eq=False)
class FetchWorld(WorldBase):
    """The fetch game (see the module docstring for the map and the conventions).

    robot_speed: m/s along a route. dt: seconds per step. horizon: H, a multiple of 8, long
    enough for the longest robot route. reach_radius: metres within which an object or home
    counts as reached. variant: only "default". gamma, lam: the objective's proximity and
    diversity weights (the paper's fetch ablation: 1.75 and 15). prior_people, prior_samples,
    prior_seed: the population of other people (how many, cycles each, seed) that both the
    duration priors of :meth:`problem` and the spatial prior come from (:meth:`prior`).
    """

    variant: Literal["default"] = "default"
    robot_speed: Positive = 4.0
    dt: Positive = 0.2
    horizon: Horizon = 64
    reach_radius: Positive = 0.5
    gamma: NonNegative = 1.75
    lam: NonNegative = 15.0
    prior_people: Annotated[Int, Field(ge=2)] = 24
    prior_samples: Annotated[Int, Field(ge=1)] = 2
    prior_seed: Int = PRIOR_SEED
    # how its people react and how its robot stops (its ``reactions`` capability)
    reaction_population: ClassVar[ReactionPopulation] = REACTIONS
    safety_limits: ClassVar[SafetyLimits] = SAFETY
    _routes: dict[tuple[str, str, str], Route] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        routes = {}
        for agent in AGENTS:
            for task in TASK_IDS:
                for mode in MODES[task]:
                    routes[agent, task, mode] = self._build_route(agent, task, mode)
        object.__setattr__(self, "_routes", routes)
        longest = max(r.length for (a, _, _), r in routes.items() if a == "robot")
        need = longest / self.robot_speed * 1.1 + self.dt
        if need > (self.horizon - 1) * self.dt:
            raise ValueError(
                f"horizon * dt = {self.horizon * self.dt:g} s is too short: the "
                f"longest robot route takes {longest / self.robot_speed:.1f} s at "
                f"{self.robot_speed} m/s and demonstrations need 10 % slack"
            )

    # -- the World protocol -----------------------------------------------------------------
    @cached_property
    def spec(self) -> WorldSpec:
        """The robot's planar coordinates (m) named as a mobile base's driver names its axes;
        the person one point, their body (ROS4HRI's ``body`` frame, on the floor)."""
        return WorldSpec(
            name="fetch", task_ids=TASK_IDS, state_dim=2, workspace_dim=2,
            workspace_bounds=((0.0, 0.0), (SIZE, SIZE)), spatial_beta=1.0, spatial_grid=32,
            teammate_names=tuple(ARCHETYPES), views={"top": (0, 1)},
            policy_defaults=dict(POLICY_DEFAULTS), joint_names=("x", "y"),
            body_point_names=("body",), resources="rapidds.worlds.fetch",
            capabilities=("browser_play", "priming", "reactions", "robot_limits",
                          "tracking_mapping", "tensor_values"))

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.workspace_bounds

    @property
    def priming_factors(self) -> dict[str, tuple[str, ...]]:
        """A user study's priming factors: their factorial names :attr:`teammate_names`."""
        return {"speed": ("fast", "slow"), "route": ("middle", "outside")}

    def prior(self) -> PopulationPrior:
        return self._prior

    @cached_property
    def _prior(self) -> PopulationPrior:
        """``prior_people`` people, each doing every task ``prior_samples`` times."""
        rng = np.random.default_rng(self.prior_seed)
        people = population(self.prior_people, rng, world=self)
        durations: dict[str, list[float]] = {t: [] for t in TASK_IDS}
        paths: dict[str, list[np.ndarray]] = {t: [] for t in TASK_IDS}
        for person in people:
            for task in TASK_IDS:
                for _ in range(self.prior_samples):
                    d, path = person.perform(task, rng)
                    durations[task].append(d)
                    paths[task].append(path)
        return PopulationPrior(durations, paths)

    def teammate(self, name: str) -> FetchTeammate:
        return archetype(name, self)

    def robot_points(self, traj: np.ndarray) -> np.ndarray:
        return np.asarray(traj, dtype=float)[..., None, :]

    def robot_rest(self) -> np.ndarray:
        return self.home("robot")

    def human_rest(self) -> np.ndarray:
        return self.home("human")[None, :]

    @property
    def robot_limits(self) -> JointLimits:
        """The point robot's limits per axis (m, m/s, m/s^2, m/s^3): the map's bounds, 1.2 times
        its route speed (demonstrations reach 1.09 times it), and acceleration and jerk that
        reach that speed within about a row (``robot_speed / dt`` times 2, and that over
        ``dt`` times 5): a toy robot's, stated so its trajectories are parameterized like the
        arm's when they leave rapidds (its planner keeps its own row timing)."""
        from rapidds.motion.timing import JointLimits

        lo, hi = self.bounds
        accel = 2.0 * self.robot_speed / self.dt
        return JointLimits(lo, hi, np.full(2, 1.2 * self.robot_speed), np.full(2, accel),
                           np.full(2, 5.0 * accel / self.dt))

    def motion_label(self, task: str, traj: np.ndarray) -> str:
        return self.route_mode(task, traj)

    def draw(self, ax: Axes, view: str = "top") -> None:
        from rapidds.plots.maps import plot_obstacles, plot_points

        plot_obstacles(ax, self.obstacles())
        plot_points(ax, self.points_of_interest())

    def problem(self) -> Problem:
        return self._problem

    @cached_property
    def _problem(self) -> Problem:
        durations = self.prior().durations
        tasks = []
        for task in TASK_IDS:
            d = np.asarray(durations[task])
            robot = self.completion_time(task, self.robot_trajectory(task)[None])[0]
            tasks.append(
                Task(
                    id=task,
                    allowed=frozenset(AGENTS),
                    human_mean=round(float(d.mean()), 2),
                    human_std=round(float(d.std(ddof=1)), 2),
                    robot_duration=float(robot),
                    description=DESCRIPTIONS[task],
                )
            )
        return Problem("fetch", tuple(tasks), PRECEDENCE, Objective(self.gamma, self.lam))

    def robot_start(self, task: str) -> np.ndarray:
        self._check_task(task)
        return np.array(HOMES["robot"], dtype=float)

    def completion_time(self, task: str, traj: np.ndarray) -> np.ndarray:
        """(N,) seconds for (N, H, 2) robot trajectories (any leading shape works); the penalty
        for a path that never gets the object home or that touches a wall."""
        self._check_task(task)
        t = reach_then_return_time(
            traj, np.array(OBJECTS[task]), np.array(HOMES["robot"]), self.reach_radius,
            self.dt, self.penalty,
        )
        # A path through a wall cannot be executed: it never completes. Without this, steering
        # would pick the model's rare wall-cutting shortcuts for being fast.
        p = np.asarray(traj, dtype=float)
        hit = self.collides(p.reshape(-1, *p.shape[-2:])).reshape(np.shape(t))
        return np.where(hit, self.penalty, t)

    def tensor_terms(self, device: torch.device | str) -> FetchTensorValues:
        """The steering value's terms as tensor operations on ``device``
        (:mod:`rapidds.worlds.fetch.tensor_value`), built once per device."""
        from rapidds.worlds.fetch.tensor_value import FetchTensorValues, tensor_terms

        def build(dev: torch.device) -> FetchTensorValues:
            goals = {task: np.array(pos, dtype=float) for task, pos in OBJECTS.items()}
            walls = np.array([w.as_array() for w in WALLS]).reshape(-1, 4)
            return FetchTensorValues(goals, np.array(HOMES["robot"], dtype=float),
                                     self.reach_radius, self.dt, self.penalty, self.bounds,
                                     walls, dev)

        return tensor_terms(self._tensor_cache, device, build)

    @cached_property
    def _tensor_cache(self) -> dict[torch.device, FetchTensorValues]:
        return {}

    def robot_demonstrations(self, n_per_mode: int, rng: np.random.Generator) -> RobotDemos:
        """Every robot task in every mode, ``n_per_mode`` each, in (task, mode) order.

        Noise: via points jittered by 0.12 m, a smooth wobble (two harmonics, 0.08 m) that
        vanishes at home and object, and a speed factor N(1, 0.03). A draw that touches a wall,
        leaves the map or misses its task is redrawn, so every row is collision-free and
        completes its task.
        """
        if n_per_mode < 1:
            raise ValueError(f"n_per_mode must be >= 1, got {n_per_mode}")
        trajs, index, modes = [], [], []
        for i, task in enumerate(TASK_IDS):
            for mode in MODES[task]:
                route = self.route("robot", task, mode)
                for _ in range(n_per_mode):
                    trajs.append(self._noisy_robot_walk(task, route, rng))
                    index.append(i)
                    modes.append(mode)
        return RobotDemos(np.stack(trajs), np.array(index, dtype=np.int64), TASK_IDS,
                          np.array(modes))

    def obstacles(self) -> tuple[Rect, ...]:
        return WALLS

    def points_of_interest(self) -> dict[str, np.ndarray]:
        pts = {f"{a} home": np.array(p, dtype=float) for a, p in HOMES.items()}
        pts.update({t: np.array(p, dtype=float) for t, p in OBJECTS.items()})
        return pts

    # -- geometry -----------------------------------------------------------------------------
    def modes(self, task: str) -> tuple[str, ...]:
        """Motion modes of ``task``, the default (shortest) first; the same for both agents."""
        self._check_task(task)
        return MODES[task]

    def home(self, agent: Agent) -> np.ndarray:
        return np.array(HOMES[agent], dtype=float)

    def object_position(self, task: str) -> np.ndarray:
        self._check_task(task)
        return np.array(OBJECTS[task], dtype=float)

    def route(self, agent: Agent, task: str, mode: str) -> Route:
        """The nominal round trip of ``agent`` for ``task`` in ``mode``."""
        try:
            return self._routes[agent, task, mode]
        except KeyError:
            raise ValueError(
                f"no route for agent {agent!r}, task {task!r}, mode {mode!r}; tasks "
                f"{', '.join(TASK_IDS)}, modes {MODES.get(task, ())}"
            ) from None

    def walk(self, route: Route, speed: float, n_steps: int,
             wobble: np.ndarray | None = None) -> np.ndarray:
        """(n_steps, 2): ``route`` walked at ``speed`` m/s from time 0, row k at time k * dt,
        standing at home once back."""
        return route.at(np.arange(n_steps) * self.dt * speed, wobble)

    def trajectory(self, agent: Agent, task: str, mode: str, speed: float | None = None,
                   n_steps: int | None = None) -> np.ndarray:
        """(n_steps, 2) noise-free walk of a route; speed defaults to the robot's, n_steps to H."""
        route = self.route(agent, task, mode)
        return self.walk(route, self.robot_speed if speed is None else speed,
                         self.horizon if n_steps is None else n_steps)

    def robot_trajectory(self, task: str, mode: str | None = None) -> np.ndarray:
        """(H, 2) the robot's noise-free trajectory; mode defaults to the shortest one."""
        return self.trajectory("robot", task, mode or self.modes(task)[0])

    def route_mode(self, task: str, traj: np.ndarray) -> str:
        """The route a path (T, 2) took: "middle" if it passes the central corridor between the
        two blocks, else "outside"; the single mode of t0/t1. For reports, not for planning."""
        self._check_task(task)
        if len(MODES[task]) == 1:
            return MODES[task][0]
        left, right = WALLS[0], WALLS[1]
        p = np.asarray(traj, dtype=float).reshape(-1, 2)
        inside = ((p[:, 0] > left.xmax) & (p[:, 0] < right.xmin)
                  & (p[:, 1] > left.ymin) & (p[:, 1] < left.ymax))
        return "middle" if bool(inside.any()) else "outside"

    def collides(self, traj: np.ndarray) -> np.ndarray:
        """(N,) bool for (N, T, 2) trajectories (or 0-d for (T, 2)): a segment touches a wall
        or a point leaves the map."""
        p = np.asarray(traj, dtype=float)
        lo, hi = self.bounds
        outside = ((p < lo) | (p > hi)).any(axis=(-1, -2))
        return outside | segments_hit_rects(p, WALLS)

    # -- internals ----------------------------------------------------------------------------
    def _check_task(self, task: str) -> None:
        if task not in OBJECTS:
            raise ValueError(f"unknown fetch task {task!r}; tasks are {', '.join(TASK_IDS)}")

    def _build_route(self, agent: Agent, task: str, mode: str) -> Route:
        src = task if agent == "human" else MIRROR_TASK[task]
        via = np.array(HUMAN_VIA[src, mode], dtype=float).reshape(-1, 2)
        home = np.array(HOMES["human"], dtype=float)
        goal = np.array(OBJECTS[src], dtype=float)
        one_way = np.vstack([home, via, goal])
        if agent == "robot":
            one_way = mirror(one_way)
        points = np.vstack([one_way, one_way[-2::-1]])
        return Route(points, goal=len(one_way) - 1)

    def _noisy_robot_walk(self, task: str, route: Route, rng: np.random.Generator,
                          tries: int = 100) -> np.ndarray:
        for _ in range(tries):
            noisy = route.jittered(rng, 0.12)
            wobble = rng.normal(0.0, 0.08, size=(2, 2, 2)) / np.array([1.0, 2.0])[None, :, None]
            speed = self.robot_speed * float(np.clip(rng.normal(1.0, 0.03), 0.91, 1.09))
            traj = self.walk(noisy, speed, self.horizon, wobble)
            ok = not self.collides(traj)
            if ok and self.completion_time(task, traj[None])[0] < self.penalty:
                return traj
        return self.walk(route, self.robot_speed, self.horizon)  # nominal: tested to be valid


# Network and sampler for the fetch policy: small enough that steering a whole GA generation of
# motion requests stays well under a second on one CPU core (docs/benchmarks.md, "Motion").
# 6 reverse steps: over every request type the scheduler makes, beside a person of the prior and
# of two archetypes, the kept V was 0.02-0.05 s LOWER than with 10 steps (8 seeds, s.e. 0.02-0.03)
# and 0.06-0.08 s higher with 4; the painting policy keeps its 10 (6 cost it 0.35 s of V).
POLICY_DEFAULTS: dict[str, object] = {
    "down_dims": [16, 32, 64],
    "num_inference_steps": 6,
    "steps": 4000,
    "batch_size": 64,
    "lr": 2e-3,
}


def fetch_problem() -> Problem:
    """The default fetch world's problem (equal to ``FetchWorld().problem()``)."""
    return default_world().problem()


@cache
def default_world() -> FetchWorld:
    """One shared default FetchWorld, so its population priors are computed once."""
    return FetchWorld()
