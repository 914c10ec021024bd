"""The loop's execute step on the clock-driven executor (:mod:`rapidds.execution`).

Which sources and policies a run's settings ask for: the teammate's executions (drawn from the
cycle's stream as the paper's replay draws them), a person who reacts (``reacts``: their own
reaction drawn once per run around the cell's population) and deviates (``deviate``: drawn per
cycle from its own stream, so the plan's numbers never move), and a robot that follows its plan
(``planned``) or monitors speed and separation and re-plans (``reactive``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from rapidds.errors import RapiddsError
from rapidds.execution import (
    CycleExecutor,
    Deployment,
    HumanSource,
    PlannedRobot,
    Replanning,
    SimulatedHuman,
    SpeedSeparation,
)
from rapidds.human.spatial import SpatialModel
from rapidds.loop.config import RunConfig
from rapidds.loop.model import device_terms, workspace_cost
from rapidds.motion.diffusion_motion import DiffusionMotion, SteeringConfig
from rapidds.motion.interface import MotionKey, MotionModel, MotionPlan
from rapidds.motion.policy import DiffusionPolicy
from rapidds.problem import Problem
from rapidds.schedule import Schedule
from rapidds.worlds.base import HumanExecution, SimulatedTeammate, Teammate, World
from rapidds.worlds.reactions import (
    Deviation,
    Reaction,
    cell_reactions,
    deviation_kinds,
    draw_deviation,
)

__all__ = ["CycleMotions", "check_cell", "contingency_motions", "cycle_executor", "cycle_record",
           "execute_cycle", "person_reaction", "replan_steering"]

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


def _cycle_motion(world: World, problem: Problem, config: RunConfig, cycle: int,
                  policy: DiffusionPolicy, spatial: SpatialModel, stream: int) -> DiffusionMotion:
    """A steering model with the run's settings, seeded by (seed, cycle, stream), so a resumed
    run steers the same."""
    seed = int(np.random.default_rng([config.seed, cycle, stream]).integers(2**31))
    return DiffusionMotion(policy, world.completion_time, workspace_cost(world, spatial),
                           problem.objective.gamma,
                           SteeringConfig(particles=config.particles,
                                          candidates=config.candidates, seed=seed,
                                          steps=config.steps),
                           duration=getattr(world, "robot_duration", None),
                           device_terms=device_terms(world, spatial))


def contingency_motions(world: World, problem: Problem, config: RunConfig, cycle: int,
                        policy: DiffusionPolicy, spatial: SpatialModel,
                        planned: Mapping[str, MotionPlan]) -> dict[str, MotionPlan]:
    """For reactive execution: a steered motion (beside nothing) for every task the robot may
    do but was not planned to, steered before the cycle starts, so that re-planning inside it
    may hand the robot one of the person's tasks without steering (which costs far more than
    its latency budget)."""
    if config.execution != "reactive":
        return {}
    todo = [t for t in problem.ids if problem.task(t).can("robot") and t not in planned]
    if not todo:
        return {}
    motion = _cycle_motion(world, problem, config, cycle, policy, spatial, _CONTINGENCY_STREAM)
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


def replan_steering(world: World, problem: Problem, config: RunConfig, cycle: int,
                    policy: DiffusionPolicy, spatial: SpatialModel) -> DiffusionMotion | None:
    """For reactive execution: the steering model re-plans inside the cycle steer new motions
    with (seeded by (seed, cycle, 24026)); None otherwise."""
    if config.execution != "reactive":
        return None
    return _cycle_motion(world, problem, config, cycle, policy, spatial, _RESTEER_STREAM)


def execute_cycle(
    world: World, problem: Problem, config: RunConfig, cycle: int, schedule: Schedule,
    motions: Mapping[str, MotionPlan], human: Mapping[str, HumanExecution],
    teammate: Teammate, reaction: Reaction | None, beliefs: tuple[np.ndarray, np.ndarray],
    spatial: SpatialModel, beta: float, spare: Mapping[str, MotionPlan] | None = None,
    order: Sequence[str] | None = None, steering: MotionModel | None = None,
    memory: Mapping[MotionKey, MotionPlan] | None = None, monitor: bool = True,
    replan: bool = True,
) -> tuple[Deployment, Deviation | None]:
    """One cycle of ``schedule`` with the robot's ``motions`` and what the person was going to
    do (``human``), under the run's execution settings; the deviation it had, if any.
    beliefs: the person's (mean, std) duration per problem task, for re-planning; spare: the
    robot's motions for tasks it was not planned to do (:func:`contingency_motions`); order: the
    order a live person took their tasks in (None: the plan's, or the simulated deviation's);
    steering (:func:`replan_steering`), memory (motions steered for (task, concurrent set)
    pairs against the spatial models as they stand): what re-plans give the robot new motions
    from where they change what runs beside it (None: they keep the plan's); monitor, replan:
    whether speed and separation monitoring and re-planning act under reactive execution
    (both, unless a decomposition of what each does turns one off)."""
    motions = {**(spare or {}), **motions}
    rng = np.random.default_rng([config.seed, cycle, _DEVIATION_STREAM])
    population, _ = cell_reactions(world)
    deviation = (draw_deviation(config.deviate, rng, population,
                                deviation_kinds(problem, schedule))
                 if config.deviate else None)

    def perform(task: str) -> tuple[float, np.ndarray]:
        assert isinstance(teammate, SimulatedTeammate)
        return teammate.at(cycle).perform(task, rng)

    person = SimulatedHuman(world, human, perform, reaction, deviation, order)
    executor = cycle_executor(world, problem, config, schedule, motions, person, beliefs,
                              spatial, beta, steering=steering, memory=memory, monitor=monitor,
                              replan=replan)
    return executor.run(), deviation


def cycle_executor(
    world: World, problem: Problem, config: RunConfig, schedule: Schedule,
    motions: Mapping[str, MotionPlan], person: HumanSource,
    beliefs: tuple[np.ndarray, np.ndarray], spatial: SpatialModel, beta: float,
    max_time: float = 600.0, *, steering: MotionModel | None = None,
    memory: Mapping[MotionKey, MotionPlan] | None = None, monitor: bool = True,
    replan: bool = True,
) -> CycleExecutor:
    """The executor of one cycle of ``schedule`` with the person ``person`` (a simulated one,
    or the browser game's avatar), under the run's execution settings: the robot follows its
    ``motions`` (planned and spare) open loop, or monitors speed and separation and re-plans
    with the learned models as they stand (``beliefs``, ``spatial``); steering, memory,
    monitor, replan as in :func:`execute_cycle`."""
    _, limits = cell_reactions(world)
    replanning = (cycle_replanning(world, problem, motions, beliefs, spatial,
                                   steering=steering, memory=memory)
                  if config.execution == "reactive" and replan else None)
    return CycleExecutor(
        world, problem, schedule, person, PlannedRobot(world, motions),
        SpeedSeparation(limits) if config.execution == "reactive" and monitor else None,
        beta=beta, replanning=replanning, limits=limits, max_time=max_time)


def cycle_replanning(world: World, problem: Problem, motions: Mapping[str, MotionPlan],
                     beliefs: tuple[np.ndarray, np.ndarray], spatial: SpatialModel, *,
                     steering: MotionModel | None = None,
                     memory: Mapping[MotionKey, MotionPlan] | None = None) -> Replanning:
    """What a cycle's re-plans use (the simulated, browser and live cells alike): the learned
    ``beliefs`` (mean, std per task) and ``spatial`` model as they stand, the robot's
    ``motions``; with ``steering``, motions steered where a re-plan changes what runs beside
    them (``memory``: those the plan's search steered)."""
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
        spatial=spatial_cost, gamma=problem.objective.gamma,
        motions=None if steering is None else CycleMotions(motions, memory or {}, steering,
                                                            cost))


def cycle_record(config: RunConfig, dep: Deployment,
                 deviation: Deviation | None) -> dict[str, Any]:
    """What a cycle's record says of execution inside it: nothing for the paper's execution
    (its records stay as they were), else who did what, the pauses and the re-plans, and under
    reactive execution the robot's yields."""
    if not config.in_cycle:
        return {}
    sched = dep.timeline.schedule
    return {"executed": {"human": list(sched.tasks("human")), "robot": list(sched.tasks("robot"))},
            "deviation": None if deviation is None else deviation.to_json(),
            "pauses": [dict(p) for p in dep.pauses], "replans": [dict(r) for r in dep.replans],
            "protective": dep.protective,
            # only where a policy can hold the robot (and so yield): other records unchanged
            **({"yields": [dict(y) for y in dep.yields]} if config.execution == "reactive"
               else {})}
