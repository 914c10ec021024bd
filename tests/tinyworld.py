"""A tiny second world, to show that a world is a plug-in: nothing in the loop or the CLI knows it.

A 6 m x 4 m room without walls. The person's home is on the left, the robot's on the right;
task ``a`` (top) and ``b`` (bottom) may be done by either, ``c`` (bottom left) only by the person,
and ``a`` must wait for ``b``. People walk straight there and back; the robot either goes
straight ("direct") or swings wide to the right ("wide", longer but away from the middle).

Registered in a process with ``rapidds.worlds.register("tiny", TinyWorld)`` or, for the CLI,
``RAPIDDS_WORLDS="tiny=tinyworld:TinyWorld"`` with this folder on ``PYTHONPATH``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from rapidds.problem import AGENTS, Objective, Problem, Task
from rapidds.worlds.base import HumanExecution, PopulationPrior, RobotDemos
from rapidds.worlds.geometry import reach_then_return_time

HOME = {"human": np.array([1.0, 2.0]), "robot": np.array([5.0, 2.0])}
GOALS = {"a": np.array([3.0, 3.5]), "b": np.array([3.0, 0.5]), "c": np.array([1.0, 0.5])}
ROBOT_TASKS = ("a", "b")
DT, H = 0.25, 32


def _walk(points: np.ndarray, speed: float, n: int | None, dt: float = DT) -> np.ndarray:
    """(n, 2) positions walking the polyline at ``speed`` from time 0 (n: until back)."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if n is None:
        n = math.ceil(cum[-1] / speed / dt) + 1
    s = np.clip(np.arange(n) * dt * speed, 0.0, cum[-1])
    return np.stack([np.interp(s, cum, points[:, k]) for k in range(2)], axis=-1)


def _round_trip(agent: str, task: str, wide: bool = False) -> np.ndarray:
    home, goal = HOME[agent], GOALS[task]
    via = [np.array([5.6, goal[1]])] if wide else []
    return np.array([home, *via, goal, *via[::-1], home])


@dataclass(frozen=True)
class Walker:
    """A scripted person: walks straight to each task at ``speed`` m/s, with per-cycle noise."""

    name: str
    speed: float
    noise: float = 0.05

    def at(self, cycle: int) -> Walker:
        return self

    def perform(self, task: str, rng: np.random.Generator) -> tuple[float, np.ndarray]:
        speed = self.speed * float(np.clip(rng.normal(1.0, self.noise), 0.8, 1.2))
        path = _walk(_round_trip("human", task), speed, None)
        return (len(path) - 1) * DT, path

    def execute(self, cycle: int, tasks: Sequence[str],
                rng: np.random.Generator) -> dict[str, HumanExecution]:
        out = {}
        for t in tasks:
            d, path = self.perform(t, rng)
            out[t] = HumanExecution(t, d, path)
        return out

    def true_mean_durations(self) -> dict[str, float]:
        return {t: float(np.linalg.norm(np.diff(_round_trip("human", t), axis=0), axis=1).sum()
                         / self.speed) for t in GOALS}

    def true_std_durations(self) -> dict[str, float]:
        return {t: self.noise * d for t, d in self.true_mean_durations().items()}


@dataclass(frozen=True)
class TinyWorld:
    variant: str = "default"
    name: str = "tiny"
    dt: float = DT
    horizon: int = H
    state_dim: int = 2
    workspace_dim: int = 2
    spatial_beta: float = 2.0
    spatial_grid: int = 16

    @property
    def variants(self) -> tuple[str, ...]:
        return ("default",)

    @property
    def task_ids(self) -> tuple[str, ...]:
        return tuple(GOALS)

    @property
    def workspace_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros(2), np.array([6.0, 4.0])

    @property
    def teammate_names(self) -> tuple[str, ...]:
        return ("steady", "quick")

    @property
    def policy_defaults(self) -> dict[str, Any]:
        return {"down_dims": [8, 16], "steps": 300, "batch_size": 32, "lr": 3e-3,
                "num_inference_steps": 8}

    @property
    def views(self) -> dict[str, tuple[int, int]]:
        return {"top": (0, 1)}

    def teammate(self, name: str) -> Walker:
        speeds = {"steady": 1.2, "quick": 2.5}
        if name not in speeds:
            raise ValueError(f"unknown tiny teammate {name!r}; one of {', '.join(speeds)}")
        return Walker(name, speeds[name])

    @cached_property
    def _prior(self) -> PopulationPrior:
        rng = np.random.default_rng(5)
        durations: dict[str, list[float]] = {t: [] for t in GOALS}
        paths: dict[str, list[np.ndarray]] = {t: [] for t in GOALS}
        for speed in np.linspace(1.0, 3.0, 6):
            for t in GOALS:
                d, p = Walker("other", float(speed)).perform(t, rng)
                durations[t].append(d)
                paths[t].append(p)
        return PopulationPrior(durations, paths)

    def prior(self) -> PopulationPrior:
        return self._prior

    @cached_property
    def _problem(self) -> Problem:
        tasks = []
        for t in GOALS:
            d = np.asarray(self._prior.durations[t])
            robot = (float(self.completion_time(t, _walk(_round_trip("robot", t), 2.0, H)[None])[0])
                     if t in ROBOT_TASKS else None)
            tasks.append(Task(t, frozenset(AGENTS) if t in ROBOT_TASKS else frozenset({"human"}),
                              round(float(d.mean()), 2), round(float(d.std(ddof=1)), 2), robot))
        return Problem("tiny", tuple(tasks), (("b", "a"),), Objective(gamma=2.0, lam=2.0))

    def problem(self) -> Problem:
        return self._problem

    def robot_points(self, traj: np.ndarray) -> np.ndarray:
        return np.asarray(traj, dtype=float)[..., None, :]

    def robot_rest(self) -> np.ndarray:
        return HOME["robot"].copy()

    def human_rest(self) -> np.ndarray:
        return HOME["human"][None, :].copy()

    def completion_time(self, task: str, traj: np.ndarray) -> np.ndarray:
        if task not in ROBOT_TASKS:
            raise ValueError(f"the robot cannot do tiny task {task!r}")
        return reach_then_return_time(traj, GOALS[task], HOME["robot"], 0.3, DT, 2 * H * DT)

    def robot_demonstrations(self, n_per_mode: int, rng: np.random.Generator) -> RobotDemos:
        trajs, index, modes = [], [], []
        for k, t in enumerate(ROBOT_TASKS):
            for mode in ("direct", "wide"):
                for _ in range(n_per_mode):
                    speed = 2.0 * float(np.clip(rng.normal(1.0, 0.03), 0.92, 1.08))
                    trajs.append(_walk(_round_trip("robot", t, mode == "wide"), speed, H))
                    index.append(k)
                    modes.append(mode)
        return RobotDemos(np.stack(trajs), np.array(index), ROBOT_TASKS, np.array(modes))

    def bundled_policy(self) -> Path | None:
        return None

    def motion_label(self, task: str, traj: np.ndarray) -> str:
        return "wide" if float(np.max(np.asarray(traj)[:, 0])) > 5.3 else "direct"

    def draw(self, ax: Any, view: str = "top") -> None:
        for name, p in {**{f"{a} home": h for a, h in HOME.items()}, **GOALS}.items():
            ax.plot(*p, "D", color="tab:red")
            ax.annotate(name, p, xytext=(3, 3), textcoords="offset points", fontsize=7)
