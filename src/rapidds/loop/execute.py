"""The loop's execute step on the clock-driven executor (:mod:`rapidds.execution`).

Which sources and policies a run's settings ask for: the teammate's executions (drawn from the
cycle's stream as the paper's replay draws them), a person who reacts (``reacts``: their own
reaction drawn once per run around the cell's population) and deviates (``deviate``: drawn per
cycle from its own stream, so the plan's numbers never move), and the robot's policy and
re-planner, which the run's registered execution entry builds (:mod:`rapidds.execution.registry`:
``planned`` follows the plan, ``reactive`` monitors speed and separation and re-plans).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rapidds.errors import RapiddsError
from rapidds.execution import (
    CycleExecutor,
    CycleRules,
    Deployment,
    HumanSource,
    PlannedRobot,
    Replanning,
    SimulatedHuman,
)
from rapidds.human.spatial import SpatialModel
from rapidds.loop.config import RunConfig
from rapidds.loop.deploy import deploy
from rapidds.loop.model import value_terms, workspace_cost
from rapidds.motion.diffusion_motion import DiffusionMotion, SteeringConfig
from rapidds.motion.interface import MotionKey, MotionModel, MotionPlan
from rapidds.motion.policy import DiffusionPolicy
from rapidds.problem import Problem
from rapidds.schedule import Schedule, compile_schedule
from rapidds.worlds.base import HumanExecution, SimulatedTeammate, Teammate, World
from rapidds.worlds.reactions import (
    Deviation,
    Reaction,
    cell_reactions,
    deviation_kinds,
    draw_deviation,
)

__all__ = ["CycleMotions", "CycleSetup", "check_cell", "contingency_motions", "cycle_executor",
           "cycle_record", "execute_cycle", "person_reaction", "replan_steering"]

_REACTION_STREAM = 24_023  # the person's reaction: drawn once per run
_DEVIATION_STREAM = 24_024  # this cycle's deviation and any task the person takes on
_CONTINGENCY_STREAM = 24_025  # the robot's motions for tasks it was not planned to do
_RESTEER_STREAM = 24_026  # motions a re-plan steers inside the cycle


def person_reaction(world: World, config: RunConfig) -> Reaction | None:
    """The simulated person's reaction to the robot (None unless ``reacts``)."""
    if not config.reacts:
        return None
    population, _ = cell_reactions(world)
    return population.draw(np.random.default_rng([config.seed, _REACTION_STREAM]))


def check_cell(config: RunConfig, teammate: Teammate) -> None:
    """Reactions and deviations are the simulated person's; a live one brings their own."""
    if (config.reacts or config.deviate) and not isinstance(teammate, SimulatedTeammate):
        raise RapiddsError("--reacts and --deviate simulate a person; a live teammate does "
                           "what they do")


def _cycle_motion(world: World, config: RunConfig, cycle: int, gamma: float,
                  policy: DiffusionPolicy, spatial: SpatialModel, stream: int) -> DiffusionMotion:
    """A steering model with the run's settings and the cycle's ``gamma``, seeded by (seed,
    cycle, stream), so a resumed run steers the same."""
    seed = int(np.random.default_rng([config.seed, cycle, stream]).integers(2**31))
    return DiffusionMotion(policy, world.completion_time, workspace_cost(world, spatial),
                           gamma,
                           SteeringConfig(particles=config.particles,
                                          candidates=config.candidates, seed=seed,
                                          steps=config.steps),
                           terms=value_terms(world, spatial))


def contingency_motions(world: World, problem: Problem, config: RunConfig, cycle: int,
                        gamma: float, policy: DiffusionPolicy, spatial: SpatialModel,
                        planned: Mapping[str, MotionPlan]) -> dict[str, MotionPlan]:
    """For an execution that re-plans: a steered motion (beside nothing) for every task the
    robot may do but was not planned to, steered before the cycle starts, so that re-planning
    inside it may hand the robot one of the person's tasks without steering (which costs far
    more than its latency budget)."""
    if not config.execution.replan:
        return {}
    todo = [t for t in problem.ids if problem.task(t).can("robot") and t not in planned]
    if not todo:
        return {}
    motion = _cycle_motion(world, config, cycle, gamma, policy, spatial, _CONTINGENCY_STREAM)
    return {m.task: m for m in motion.plan([(t, frozenset()) for t in todo])}


class CycleMotions:
    """What re-plans inside one cycle draw robot motions from (a
    :class:`~rapidds.execution.MotionSupply`): the motions the cycle starts with (the plan's and
    the spares), the motions already steered for (task, concurrent set) pairs against the
    spatial models as they stand (the plan's search and earlier cycles: ``memory``), and a
    steering model for the rest, whose motions join the memory."""

    def __init__(self, planned: Mapping[str, MotionPlan], memory: Mapping[MotionKey, MotionPlan],
                 steering: MotionModel, cost: Callable[[Iterable[str], np.ndarray], np.ndarray]):
        self._planned = dict(planned)
        self._memory = {**dict(memory), **{(m.task, m.concurrent): m for m in planned.values()}}
        self._steering, self._cost = steering, cost

    def planned(self, task: str) -> MotionPlan | None:
        return self._planned.get(task)

    def recall(self, key: MotionKey) -> MotionPlan | None:
        return self._memory.get(key)

    def steer(self, keys: Sequence[MotionKey]) -> list[MotionPlan]:
        plans = self._steering.plan(keys)
        self._memory.update(zip(keys, plans, strict=True))
        return plans

    def cost(self, concurrent: frozenset[str], trajectory: np.ndarray) -> float:
        return float(self._cost(concurrent, np.asarray(trajectory)[None])[0]) if concurrent \
            else 0.0


def replan_steering(world: World, config: RunConfig, cycle: int, gamma: float,
                    policy: DiffusionPolicy, spatial: SpatialModel) -> DiffusionMotion | None:
    """For an execution that re-plans: the steering model re-plans inside the cycle steer new
    motions with (seeded by (seed, cycle, 24026)); None otherwise."""
    if not config.execution.replan:
        return None
    return _cycle_motion(world, config, cycle, gamma, policy, spatial, _RESTEER_STREAM)


@dataclass(frozen=True)
class CycleSetup:
    """What one cycle's executor is built from: the run's ``world``, ``problem`` and
    ``config``, the ``cycle`` and the ``gamma`` it was planned with, the ``schedule`` it runs
    and the robot's ``motions`` (planned and spare: :func:`contingency_motions`), the person's
    learned ``beliefs`` ((mean, std) duration per problem task) and ``spatial`` model as they
    stand, for re-planning, and the closeness scale ``beta``. steering
    (:func:`replan_steering`), memory (motions steered for (task, concurrent set) pairs against
    the spatial models as they stand): what re-plans give the robot new motions from where they
    change what runs beside it (None: they keep the plan's); monitor, replan: whether speed and
    separation monitoring and re-planning act under reactive execution (both, unless a
    decomposition of what each does turns one off)."""

    world: World
    problem: Problem
    config: RunConfig
    cycle: int
    gamma: float
    schedule: Schedule
    motions: Mapping[str, MotionPlan]
    beliefs: tuple[np.ndarray, np.ndarray]
    spatial: SpatialModel
    beta: float
    steering: MotionModel | None = None
    memory: Mapping[MotionKey, MotionPlan] | None = None


def execute_cycle(setup: CycleSetup, human: Mapping[str, HumanExecution], teammate: Teammate,
                  reaction: Reaction | None, order: Sequence[str] | None = None,
                  ) -> tuple[Deployment, Deviation | None]:
    """One cycle of ``setup`` with what the person was going to do (``human``), under the
    run's execution entry; the deviation it had, if any. Where the entry replays (the paper's)
    and the person neither reacts nor deviates, the cycle is the open-loop replay
    (:func:`~rapidds.loop.deploy.deploy`), else (and for an order the replay cannot compile, a
    live cell's re-planned one) it runs on the executor (:func:`cycle_executor`). reaction: the
    simulated person's (None: they do not react); order: the order a live person took their
    tasks in (None: the plan's, or the simulated deviation's)."""
    config, cycle = setup.config, setup.cycle
    rng = np.random.default_rng([config.seed, cycle, _DEVIATION_STREAM])
    population, _ = cell_reactions(setup.world)
    deviation = (draw_deviation(config.deviate, rng, population,
                                deviation_kinds(setup.problem, setup.schedule))
                 if config.deviate else None)

    def perform(task: str) -> tuple[float, np.ndarray]:
        assert isinstance(teammate, SimulatedTeammate)
        return teammate.at(cycle).perform(task, rng)

    s = setup
    undisturbed = reaction is None and deviation is None and order is None
    if (config.execution.replays and undisturbed
            and compile_schedule(s.problem, s.schedule) is not None):
        return deploy(s.world, s.problem.with_objective(gamma=s.gamma), s.schedule, s.motions,
                      human, beta=s.beta), None
    person = SimulatedHuman(s.world, human, perform, reaction, deviation, order)
    return cycle_executor(setup, person).run(), deviation


def cycle_executor(setup: CycleSetup, person: HumanSource,
                   max_time: float = 600.0) -> CycleExecutor:
    """The executor of the cycle ``setup`` describes with the person ``person`` (a simulated
    one, or the browser game's avatar): the robot follows its motions (planned and spare) under
    the policy and the re-planner the run's execution entry builds (the re-planner from the
    learned models as they stand). Costs are weighed with the cycle's gamma."""
    s = setup
    _, limits = cell_reactions(s.world)
    replanning = s.config.execution.replanner(lambda: cycle_replanning(
        s.world, s.problem, s.motions, s.beliefs, s.spatial, s.gamma, steering=s.steering,
        memory=s.memory))
    return CycleExecutor(
        s.world, s.problem.with_objective(gamma=s.gamma), s.schedule, person,
        PlannedRobot(s.world, s.motions), s.config.execution.policy(limits),
        beta=s.beta, rules=CycleRules(replanning=replanning, limits=limits, max_time=max_time))


def cycle_replanning(world: World, problem: Problem, motions: Mapping[str, MotionPlan],
                     beliefs: tuple[np.ndarray, np.ndarray], spatial: SpatialModel,
                     gamma: float, *, steering: MotionModel | None = None,
                     memory: Mapping[MotionKey, MotionPlan] | None = None) -> Replanning:
    """What a cycle's re-plans use (the simulated, browser and live cells alike): the learned
    ``beliefs`` (mean, std per task) and ``spatial`` model as they stand, the robot's
    ``motions``, the cycle's ``gamma``; with ``steering``, motions steered where a re-plan
    changes what runs beside them (``memory``: those the plan's search steered)."""
    cost = workspace_cost(world, spatial)
    mean, std = beliefs
    ids = problem.ids

    def spatial_cost(j: str, near: frozenset[str]) -> float:
        traj = motions[j].trajectory
        return 0.0 if traj is None else float(cost(near, np.asarray(traj)[None])[0])

    return Replanning(
        mean={t: float(m) for t, m in zip(ids, mean, strict=True) if np.isfinite(m)},
        std={t: float(s) for t, s in zip(ids, std, strict=True) if np.isfinite(s)},
        robot={j: m.duration + m.hold for j, m in motions.items()  # hold: 0 open loop
               if m.trajectory is not None},
        spatial=spatial_cost, gamma=gamma,
        motions=None if steering is None else CycleMotions(motions, memory or {}, steering,
                                                            cost))


def cycle_record(config: RunConfig, dep: Deployment,
                 deviation: Deviation | None) -> dict[str, Any]:
    """What a cycle's record says of execution inside it: nothing for the paper's execution
    (its records stay as they were), else who did what, the pauses and the re-plans, and where
    a monitor may hold the robot its yields."""
    if not config.in_cycle:
        return {}
    sched = dep.timeline.schedule
    return {"executed": {"human": list(sched.tasks("human")), "robot": list(sched.tasks("robot"))},
            "deviation": None if deviation is None else deviation.to_json(),
            "pauses": [dict(p) for p in dep.pauses], "replans": [dict(r) for r in dep.replans],
            "protective": dep.protective,
            # only where a policy can hold the robot (and so yield): other records unchanged
            **({"yields": [dict(y) for y in dep.yields]} if config.execution.monitor else {})}
