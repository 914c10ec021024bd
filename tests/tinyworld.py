"""A world from outside the package (docs/architecture.md, "Where a new world goes"): a spec
and the behaviour every world has. A 6 x 4 m room, homes left (person) and right (robot); ``a``
(top) and ``b`` (bottom) either agent's, ``c`` the person's, ``b`` before ``a``. Registered by
``register("tiny", TinyWorld)`` or ``RAPIDDS_WORLDS="tiny=tinyworld:TinyWorld"``."""

from dataclasses import dataclass
from typing import Any

import numpy as np

from rapidds.problem import AGENTS, Objective, Problem, Task
from rapidds.worlds.base import PopulationPrior, RobotDemos, SteadyPerson, WorldBase, WorldSpec
from rapidds.worlds.geometry import reach_then_return_time

HOME = {"human": np.array([1.0, 2.0]), "robot": np.array([5.0, 2.0])}
GOALS = {"a": np.array([3.0, 3.5]), "b": np.array([3.0, 0.5]), "c": np.array([1.0, 0.5])}
ROBOT_TASKS, DT, H, SPEEDS = ("a", "b"), 0.25, 32, {"steady": 1.2, "quick": 2.5}


def _walk(agent: str, task: str, speed: float, n: int | None, wide: bool = False) -> np.ndarray:
    """(n, 2): the round trip walked at ``speed`` m/s from time 0 (n None: until back home)."""
    via = [np.array([5.6, GOALS[task][1]])] if wide else []
    pts = np.array([HOME[agent], *via, GOALS[task], *via[::-1], HOME[agent]])
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    n = int(np.ceil(cum[-1] / speed / DT)) + 1 if n is None else n
    s = np.clip(np.arange(n) * DT * speed, 0.0, cum[-1])
    return np.stack([np.interp(s, cum, pts[:, k]) for k in range(2)], axis=-1)


@dataclass(frozen=True)
class Walker(SteadyPerson):  # a scripted person: to each task and back, 5 % noise a time
    name: str
    speed: float

    def perform(self, task: str, rng: np.random.Generator) -> tuple[float, np.ndarray]:
        speed = self.speed * float(np.clip(rng.normal(1, 0.05), 0.8, 1.2))
        return (len(path := _walk("human", task, speed, None)) - 1) * DT, path

    def true_mean_durations(self) -> dict[str, float]:
        return {t: (len(_walk("human", t, self.speed, None)) - 1) * DT for t in GOALS}

    def true_std_durations(self) -> dict[str, float]:
        return {t: 0.05 * d for t, d in self.true_mean_durations().items()}


@dataclass(frozen=True)
class TinyWorld(WorldBase):
    variant: str = "default"
    dt: float = DT
    horizon: int = H
    spec = WorldSpec(name="tiny", task_ids=tuple(GOALS), state_dim=2, workspace_dim=2,
                     workspace_bounds=((0.0, 0.0), (6.0, 4.0)), spatial_beta=2.0,
                     spatial_grid=16, teammate_names=tuple(SPEEDS),
                     policy_defaults={"down_dims": [8, 16], "steps": 300, "batch_size": 32,
                                      "lr": 3e-3, "num_inference_steps": 8})

    def teammate(self, name: str) -> Walker:
        if name not in SPEEDS:
            raise ValueError(f"unknown tiny teammate {name!r}; one of {', '.join(SPEEDS)}")
        return Walker(name, SPEEDS[name])

    def prior(self) -> PopulationPrior:
        rng, people = np.random.default_rng(5), [Walker("other", s) for s in np.linspace(1, 3, 6)]
        done = {t: [p.perform(t, rng) for p in people] for t in GOALS}
        return PopulationPrior(*({t: [x[i] for x in v] for t, v in done.items()} for i in (0, 1)))

    def problem(self) -> Problem:
        tasks = [Task(t, frozenset(AGENTS if t in ROBOT_TASKS else ("human",)),
                      round(float(np.mean(d := self.prior().durations[t])), 2),
                      round(float(np.std(d, ddof=1)), 2),
                      float(self.completion_time(t, _walk("robot", t, 2.0, H)[None])[0])
                      if t in ROBOT_TASKS else None) for t in GOALS]
        return Problem("tiny", tuple(tasks), (("b", "a"),), Objective(gamma=2.0, lam=2.0))

    def robot_points(self, traj: np.ndarray) -> np.ndarray:  # the robot is one point
        return np.asarray(traj, dtype=float)[..., None, :]

    def robot_rest(self) -> np.ndarray:
        return HOME["robot"].copy()

    def human_rest(self) -> np.ndarray:  # the person is one point
        return HOME["human"][None, :].copy()

    def completion_time(self, task: str, traj: np.ndarray) -> np.ndarray:
        return reach_then_return_time(traj, GOALS[task], HOME["robot"], 0.3, DT, self.penalty)

    def robot_demonstrations(self, n_per_mode: int, rng: np.random.Generator) -> RobotDemos:
        rows = [(t, w) for t in ROBOT_TASKS for w in (False, True) for _ in range(n_per_mode)]
        trajs = [_walk("robot", t, 2 * float(np.clip(rng.normal(1, 0.03), 0.92, 1.08)), H, w)
                 for t, w in rows]
        return RobotDemos(np.stack(trajs), np.array([ROBOT_TASKS.index(t) for t, _ in rows]),
                          ROBOT_TASKS, np.array(["wide" if w else "direct" for _, w in rows]))

    def motion_label(self, task: str, traj: np.ndarray) -> str:
        return "wide" if float(np.max(np.asarray(traj)[:, 0])) > 5.3 else "direct"

    def draw(self, ax: Any, view: str = "top") -> None:  # homes and tasks as red diamonds
        ax.scatter(*np.array([*HOME.values(), *GOALS.values()]).T, marker="D", color="tab:red")
