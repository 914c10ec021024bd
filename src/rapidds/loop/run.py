"""The RAPIDDS multi-cycle loop (paper Algorithm 1), one cycle in four steps.

:meth:`AdaptiveRun.plan` searches the schedule with the genetic scheduler, whose robot motions
come from the steered diffusion policy; :meth:`~AdaptiveRun.execute` has the teammate do their
part and realises the cycle; :meth:`~AdaptiveRun.learn` updates the models the adaptation level
names; :meth:`~AdaptiveRun.record` stores the cycle in one transaction. Each step can be called
on its own, so a caller can show the plan to a person, wait for what they did, then learn.

A run resumes from its last stored cycle with the models exactly as they were, because every
cycle draws its random numbers from (seed, cycle) and the stored state holds everything learned.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from rapidds.errors import CheckpointError, RapiddsError, StateError
from rapidds.execution import CycleExecutor, HumanSource
from rapidds.execution.deployment import Reactions
from rapidds.human.spatial import SpatialModel
from rapidds.loop.carry import CarriedMotions, Stamped, spatial_stamps, valid_plans
from rapidds.loop.changes import detect_changes
from rapidds.loop.comfort import (
    SimulatedComfort,
    cycle_evidence,
    reaction_anchor,
    reaction_evidence,
    said_and_signalled,
    simulated_comfort,
)
from rapidds.loop.config import RunConfig
from rapidds.loop.deploy import Deployment
from rapidds.loop.execute import (
    check_cell,
    contingency_motions,
    cycle_executor,
    cycle_record,
    execute_cycle,
    person_reaction,
    replan_steering,
)
from rapidds.loop.model import (
    HumanModel,
    check_teammate,
    gamma_prior,
    oracle_spatial,
    prior_model,
    workspace_cost,
)
from rapidds.loop.slowdowns import Slowdowns
from rapidds.motion.diffusion_motion import DiffusionMotion, SteeringConfig
from rapidds.motion.interface import MotionKey, MotionModel, MotionPlan, TrajectoryCache
from rapidds.motion.policy import DiffusionPolicy
from rapidds.problem import Problem
from rapidds.record import CycleRecord, Execution, InCycle, PlanCost, PlanPart, Predicted, Realised
from rapidds.schedule import Timeline
from rapidds.scheduler import (
    Evaluation,
    GAConfig,
    GeneticScheduler,
    evaluate_population,
    solve_exact,
)
from rapidds.settings import require_memory
from rapidds.store import RunStore, path_arrays
from rapidds.worlds.base import HumanExecution, SimulatedTeammate, Teammate, World
from rapidds.worlds.reactions import Deviation
from rapidds.worlds.registry import make_world

__all__ = ["AdaptiveRun", "CyclePlan", "CycleResult", "FreeOrderTeammate", "LiveTeammate",
           "ReactiveTeammate", "load_policy", "timeline_of"]

PLAN_COST_SAMPLES = 256  # true-duration samples behind a cycle's plan cost (s.e. ~0.01 s)

LEARNS: dict[str, tuple[bool, bool]] = {  # adapt level -> (temporal, spatial) models updated
    "full": (True, True),
    "spatial": (False, True),
    "temporal": (True, False),
    "none": (False, False),
    "oracle": (False, False),
    "exact": (False, False),
}


def load_policy(world: World, path: Path | None = None, device: str = "auto"
                ) -> DiffusionPolicy:
    """The checkpoint at ``path``, or the world's bundled policy, on ``device`` ("auto": a CUDA
    GPU when there is one; "cuda" without one is a ConfigError, one line at the CLI)."""
    directory = path or world.bundled_policy()
    if directory is None:
        raise CheckpointError(
            f"no bundled {world.name} policy in this install; train one with "
            f"'rapidds train-policy --world {world.name} --out DIR' and pass --policy DIR"
        )
    return DiffusionPolicy.load(directory, device=device)


def timeline_of(problem: Problem, record: CycleRecord) -> Timeline:
    """The realised timeline of a stored cycle record (for charts drawn after the fact)."""
    schedule = record.done  # who did what, where the person deviated
    times = record.realised.timeline
    start = np.array([[times[t][0] for t in problem.ids]])
    finish = np.array([[times[t][1] for t in problem.ids]])
    return Timeline(problem, schedule, start, finish)


@dataclass
class CyclePlan:
    """The plan of one cycle: the best evaluated schedule with its robot motions and expected
    costs, the lambda it was planned with, and what the search did.

    ``rng`` is the cycle's random stream after planning; execution continues from it, so a
    simulated cycle draws the same numbers whether it is run in one call or step by step.
    ``motions`` are the steered plans to carry into the next cycle once this one is recorded.
    """

    cycle: int
    best: Evaluation
    lam: float
    search: dict[str, Any]
    rng: np.random.Generator = field(repr=False)
    seconds: float = 0.0
    motions: dict[MotionKey, Stamped] = field(default_factory=dict, repr=False)


@runtime_checkable
class LiveTeammate(Teammate, Protocol):
    """A teammate who has to see the plan before doing their part: a person at a screen (the
    browser game's player), a person told by an experimenter. :meth:`AdaptiveRun.execute` shows
    them the plan right before asking what they did, so ``run.step()`` works with them too."""

    def show(self, plan: CyclePlan) -> None:
        """Present ``plan`` (its schedule, the robot's motions); called once per cycle, in the
        thread that then calls :meth:`~rapidds.worlds.base.Teammate.execute`."""
        ...


@runtime_checkable
class FreeOrderTeammate(Teammate, Protocol):
    """A live teammate who may do their tasks in another order than the plan's (any that
    precedence allows: the browser game's player); the executor replays the order they took."""

    def played_order(self, cycle: int) -> list[str] | None:
        """The person's tasks of cycle ``cycle`` in the order they did them (None: unknown)."""
        ...


@runtime_checkable
class ReactiveTeammate(LiveTeammate, Protocol):
    """A live teammate the robot reacts to while the cycle runs (the browser game's player
    under ``--execution reactive``): the cycle runs live on the loop's executor, built around
    the person's own :class:`~rapidds.execution.HumanSource`."""

    def play(self, plan: CyclePlan,
             executor: Callable[[HumanSource], CycleExecutor]) -> Deployment:
        """Show ``plan`` and run it live with the executor ``executor`` builds around the
        person; block until the cycle is over; what happened."""
        ...


class _PlannedMotions:
    """The motions a plan chose, as a motion model: each robot task keeps its trajectory and
    duration whatever runs beside it; only its spatial cost is re-scored with ``cost``."""

    def __init__(self, motions: Mapping[str, MotionPlan],
                 cost: Callable[[frozenset[str], np.ndarray], np.ndarray]):
        self._motions, self._cost = motions, cost

    def nominal_durations(self, problem: Problem) -> np.ndarray:
        return np.array([self._motions[t].duration if t in self._motions else np.nan
                         for t in problem.ids])

    def plan(self, requests: Sequence[MotionKey]) -> list[MotionPlan]:
        out = []
        for task, concurrent in requests:
            m = self._motions[task]
            s = (float(self._cost(concurrent, m.trajectory[None])[0])
                 if concurrent and m.trajectory is not None else 0.0)
            out.append(MotionPlan(task, concurrent, m.duration, s, m.trajectory))
        return out


@dataclass
class CycleResult:
    """A finished cycle: its record (typed; its ``to_json`` is what was stored), the plan and
    what happened."""

    record: CycleRecord
    plan: CyclePlan
    deployment: Deployment


class AdaptiveRun:
    """One teammate, one adaptation level, ``cycles`` cycles; optionally stored and resumable.

    world: defaults to the registry's ``config.world``; teammate: defaults to the world's
    simulated ``config.human`` (pass a live person's teammate to run with them); policy:
    defaults to the world's bundled one; store: where every cycle is recorded; prior: the
    starting belief (default: the world's population prior for this config, computed anew).
    """

    def __init__(self, config: RunConfig, policy: DiffusionPolicy | None = None,
                 store: RunStore | None = None, world: World | None = None,
                 teammate: Teammate | None = None, prior: HumanModel | None = None):
        self.world = world or make_world(config.world, config.variant)
        self.config = config.resolved(self.world)
        self.teammate = check_teammate(self.world, self.config, teammate)
        if self.config.adapt == "oracle" and not isinstance(self.teammate, SimulatedTeammate):
            raise RapiddsError("--adapt oracle needs a simulated teammate (it plans with their "
                               "true model)")
        c = self.config
        n, h, d = len(self.world.task_ids), self.world.horizon, self.world.state_dim
        # a generation's timelines (C x K x n, a few arrays) and one steering batch of every
        # motion request of a generation (C x n requests x B x M rows, network activations)
        require_memory(8 * 8 * c.population * c.samples * n
                       + 4 * 256 * c.population * n * c.particles * c.candidates * h * d,
                       "this search (--population, --samples, --particles, --candidates)")
        self.policy = (policy or load_policy(self.world, device=c.device)).with_sampler(
            c.sampler)
        self.store = store
        self.problem: Problem = self.world.problem().with_objective(
            gamma=self.config.gamma, lam=self.config.lam)
        # a given prior (e.g. one population prior shared by a study's runs, computed once) is
        # copied: the run learns into its own model
        self.model = (HumanModel.from_bytes(prior.to_bytes()) if prior is not None
                      else prior_model(self.world, self.config))
        if c.gamma_learn and self.model.gamma is None:
            self.model.gamma = gamma_prior(self.world, c)
        # the run's own simulated teammate answers about their comfort; an injected one (a
        # person) may offer ``comfort_report(cycle)``
        self.comfort: SimulatedComfort | None = (
            simulated_comfort(self.world.problem().objective.gamma, c.seed, c.comfort)
            if c.simulates_comfort and teammate is None else None)
        self._evidence: dict[int, dict[str, Any]] = {}
        self._oracle_spatial: dict[str, SpatialModel] = {}
        self._changes: dict[int, list[dict[str, Any]]] = {}
        self.next_cycle = 0
        self._timing: dict[int, dict[str, float]] = {}
        check_cell(self.config, self.teammate)
        # the person's reaction, all run long; a simulated person with a comfort reacts by it
        self._reaction = person_reaction(self.world, self.config)
        if self._reaction is not None and self.comfort is not None:
            self._reaction = self.comfort.reaction(self._reaction, self.model.spatial.config.beta)
        self._deviations: dict[int, Deviation | None] = {}
        self.slowdowns, self._slowed = Slowdowns(self.world, self.config), {}
        self.model.slowdowns = self.model.slowdowns or self.slowdowns.belief()
        if store is not None:
            self._attach(store)

    def _attach(self, store: RunStore) -> None:
        rid = self.config.run_id
        raw = store.run_config(rid)
        # a setting added since the run was stored ran with its default (which is the old
        # behaviour: every new setting's default is)
        stored = None if raw is None else {
            **{k: f.default for k, f in RunConfig.model_fields.items()
               if k not in raw and not f.exclude
               and not (f.exclude_if is not None and f.exclude_if(f.default))}, **raw}
        if stored is not None and stored != self.config.model_dump():
            mine = self.config.model_dump()
            diff = ", ".join(f"{k}={stored.get(k)!r} (asked {mine.get(k)!r})"
                             for k in sorted(set(stored) | set(mine))
                             if stored.get(k) != mine.get(k))
            raise StateError(f"run '{rid}' in {store.path} was stored with other settings: "
                             f"{diff}; use the same settings or another --out")
        store.create_run(rid, raw if raw is not None else self.config.model_dump())
        last = store.last_cycle(rid)
        if last is not None:
            state = store.state(rid, last)
            if state is None:
                raise StateError(f"run '{rid}' cycle {last} has no stored model")
            self.model = HumanModel.from_bytes(state)
            self.next_cycle = last + 1

    @property
    def finished(self) -> bool:
        return self.next_cycle >= self.config.cycles

    # -- plan ---------------------------------------------------------------------------------
    def _durations(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(K, n) planning samples and (n,) means from the belief (or the truth for oracle)."""
        k = self.config.samples
        if self.config.adapt == "oracle":
            return self._true_durations(k, rng)
        return self.model.temporal.sample(k, rng), self.model.temporal.mean()

    def _true_durations(self, k: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(k, n) samples of the teammate's true durations and their (n,) means."""
        person = self._truth()
        ids = self.problem.ids
        mean_d, sd_d = person.true_mean_durations(), person.true_std_durations()
        mean = np.array([mean_d.get(t, np.nan) for t in ids])
        sd = np.array([sd_d.get(t, np.nan) for t in ids])
        return np.maximum(rng.normal(mean, sd, (k, len(ids))), 0.5 * mean), mean

    def _truth(self) -> SimulatedTeammate:
        assert isinstance(self.teammate, SimulatedTeammate)
        return self.teammate.at(self.next_cycle)

    def _spatial(self) -> SpatialModel:
        if self.config.adapt != "oracle":
            return self.model.spatial
        return self._true_spatial()

    def _true_spatial(self) -> SpatialModel:
        """The spatial model of the person the teammate is now (a habit change switches it)."""
        truth = self._truth()
        person = getattr(truth, "base", truth)  # a re-paced person walks the same paths
        if person.name not in self._oracle_spatial:
            self._oracle_spatial[person.name] = oracle_spatial(self.world, self.config, person)
        return self._oracle_spatial[person.name]

    def plan_cost(self, plan: CyclePlan) -> dict[str, float] | None:
        """The paper's plan cost (its Figure 5): the plan's schedule with its robot motions,
        scored under the teammate's TRUE model: expected makespan over their true durations
        plus gamma x the motions' spatial cost against their true paths (the oracle's models),
        with C_j taken on the true expected timeline. No diversity term: it is a cost of the
        allocation history, not of the cycle. None for a teammate whose truth is unknown (a
        live person). Draws from its own random stream, so the cycle's numbers do not change.
        """
        if not isinstance(self.teammate, SimulatedTeammate):
            return None
        self._check_current(plan)
        best = plan.best
        rng = np.random.default_rng([self.config.seed, plan.cycle, 104_729])
        samples, mean = self._true_durations(PLAN_COST_SAMPLES, rng)
        motion = _PlannedMotions(best.motions, workspace_cost(self.world, self._true_spatial()))
        gamma = self.problem.objective.gamma
        ev = evaluate_population(self.problem, [best.schedule], samples, mean,
                                 TrajectoryCache(motion), motion.nominal_durations(self.problem),
                                 gamma, 0.0)[0]
        return {"cost": ev.makespan_mean + gamma * ev.spatial, "makespan": ev.makespan_mean,
                "spatial": ev.spatial}

    def _plan_exact(
        self, motion: MotionModel, samples: np.ndarray, mean: np.ndarray
    ) -> tuple[Evaluation, dict[str, Any]]:
        """CP-SAT on the prior mean durations, scored like every other plan."""
        exact = solve_exact(self.problem, time_limit_s=5.0, human_mean=mean)
        cache = TrajectoryCache(motion)
        ev = evaluate_population(self.problem, [exact.schedule], samples, mean, cache,
                                 motion.nominal_durations(self.problem),
                                 self.problem.objective.gamma, 0.0, self.model.history)[0]
        return ev, {"solver": "cp-sat", "optimal": exact.optimal,
                    "motion_requests": cache.misses}

    def plan(self) -> CyclePlan:
        """Plan the next cycle from the current belief (nothing changes until it is recorded)."""
        if self.finished:
            raise RapiddsError(f"run '{self.config.run_id}' is finished "
                               f"({self.config.cycles} cycles)")
        cfg, c = self.config, self.next_cycle
        t0 = time.perf_counter()
        if self.model.gamma is not None:  # this person's gamma, as believed now
            self.problem = self.problem.with_objective(gamma=self.model.gamma.planning(
                cfg.gamma_plan))
        rng = np.random.default_rng([cfg.seed, c])
        samples, mean = self._durations(rng)
        exact = cfg.adapt == "exact"
        gamma = 0.0 if exact else self.problem.objective.gamma  # the CP-SAT user ignores proximity
        spatial = self._spatial()
        holds = self.slowdowns.model(spatial, self.model.slowdowns)  # None: open-loop robot
        motion: MotionModel = DiffusionMotion(
            self.policy, self.world.completion_time,
            workspace_cost(self.world, spatial), gamma,
            SteeringConfig(particles=cfg.particles, candidates=cfg.candidates,
                           seed=int(rng.integers(2**31)), steps=cfg.steps),
            duration=getattr(self.world, "robot_duration", None),
            hold=None if holds is None else holds.hold)
        carried = CarriedMotions(motion, dict(self.model.motions) if cfg.reuse_motions else {},
                                 spatial_stamps(spatial))
        held = self.slowdowns.wrap(carried, holds)
        ga_seed = int(rng.integers(2**31))
        lam = 0.0 if exact else cfg.lam_at(c, self.model.changes.last_change)
        if exact:
            best, search = self._plan_exact(held, samples, mean)
        else:
            # The GA's runner-up polishes off: every new (j, C_j) they reach is a steering
            # call, and they made a fetch trial ~50 % dearer (5.5 s against 3.6 s in the full
            # study) for a 4-task job the GA already solves. The order search off too: on this
            # job it changed no plan and no motion request in 32 cycles, and off keeps the
            # plans of the committed study (docs/reproduction.md).
            ga = GeneticScheduler(self.problem.with_objective(lam=lam), held, GAConfig(
                population=cfg.population, generations=cfg.generations, samples=cfg.samples,
                patience=cfg.patience, polish_allocations=1, order_search_nodes=0,
                seed=ga_seed))
            result = ga.solve(samples, mean, history=self.model.history)
            best = result.best
            search = {"generations": result.generations_run, "evaluations": result.evaluations,
                      "motion_requests": result.cache_misses}
        search["motions_reused"] = carried.reused
        return CyclePlan(c, best, lam, search, rng, time.perf_counter() - t0,
                         carried.carried if cfg.reuse_motions else {})

    # -- execute ------------------------------------------------------------------------------
    def execute(self, plan: CyclePlan,
                observed: Mapping[str, HumanExecution] | None = None,
                reacted: Reactions | None = None, *,
                played: Deployment | None = None) -> Deployment:
        """Deploy ``plan``: the teammate does the human tasks (or ``observed`` holds what a
        live person did), and the cycle is realised with the robot's planned motions by the
        clock-driven executor, under the run's execution settings (:mod:`.execute`). Under
        reactive execution a :class:`ReactiveTeammate` plays the cycle live on that executor
        (the robot reacts to them as they move) and hands back the whole of it; ``played`` is
        such a cycle already over, played on :meth:`live_executor` by a caller that waited for
        it without blocking (the study's game rounds, on the server's event loop).
        ``reacted``: what a live cell's own reactive layer did (pauses, re-plans, protective
        check): the robot's reactions already are in the durations it took, so the cycle is
        realised open loop from what happened and these are its in-cycle record."""
        self._check_current(plan)
        t0 = time.perf_counter()
        tasks = plan.best.schedule.tasks("human")
        if played is not None and self.config.execution != "reactive":
            raise ValueError("a cycle played live on the executor needs reactive execution")
        if (played is None and observed is None and self.config.execution == "reactive"
                and isinstance(self.teammate, ReactiveTeammate)):
            played = self.teammate.play(plan, self.live_executor(plan))
        if played is not None:
            self._deviations[plan.cycle] = None  # what a live person did is in the record
            self._timing[plan.cycle] = {"deploy": time.perf_counter() - t0}
            return played
        if observed is None and isinstance(self.teammate, LiveTeammate):
            self.teammate.show(plan)
        human = (dict(observed) if observed is not None
                 else self.teammate.execute(plan.cycle, tasks, plan.rng))
        missing = set(tasks) - set(human)
        if missing:
            raise ValueError(f"no observation of human task(s) {sorted(missing)}")
        cfg = (self.config if reacted is None
               else self.config.model_copy(update={"execution": "planned"}))
        steering = replan_steering(self.world, self.problem, cfg, plan.cycle, self.policy,
                                   self._spatial())
        ran = plan.best.schedule if reacted is None else reacted.schedule or plan.best.schedule
        dep, self._deviations[plan.cycle] = execute_cycle(
            self.world, self.problem, cfg, plan.cycle, ran,
            plan.best.motions, human, self.teammate, self._reaction,
            (self.model.temporal.mean(), self.model.temporal.std()), self._spatial(),
            beta=self.model.spatial.config.beta,
            spare=contingency_motions(self.world, self.problem, cfg, plan.cycle,
                                      self.policy, self._spatial(), plan.best.motions),
            order=(self.teammate.played_order(plan.cycle)
                   if isinstance(self.teammate, FreeOrderTeammate) else None),
            steering=steering, memory=None if steering is None else valid_plans(
                plan.motions, spatial_stamps(self._spatial())))
        if reacted is not None:
            dep = dataclasses.replace(dep, pauses=reacted.pauses, replans=reacted.replans,
                                      protective=reacted.protective)
        self._timing[plan.cycle] = {"deploy": time.perf_counter() - t0}
        return dep

    def live_executor(self, plan: CyclePlan) -> Callable[[HumanSource], CycleExecutor]:
        """What builds the executor of ``plan`` around a live person (every restart of the
        cycle builds a fresh one): the robot's spare motions are steered once, here, before
        the cycle is shown; its re-plans steer where the concurrency changed as a simulated
        cycle's do; a live cycle has no time limit but the person's patience."""
        motions = {**contingency_motions(self.world, self.problem, self.config, plan.cycle,
                                         self.policy, self._spatial(), plan.best.motions),
                   **plan.best.motions}
        beliefs = (self.model.temporal.mean(), self.model.temporal.std())
        spatial, beta = self._spatial(), self.model.spatial.config.beta
        steering = replan_steering(self.world, self.problem, self.config, plan.cycle,
                                   self.policy, spatial)
        memory = None if steering is None else valid_plans(plan.motions, spatial_stamps(spatial))

        def build(person: HumanSource) -> CycleExecutor:
            return cycle_executor(self.world, self.problem, self.config, plan.best.schedule,
                                  motions, person, beliefs, spatial, beta, max_time=math.inf,
                                  steering=steering, memory=memory)

        return build

    # -- learn --------------------------------------------------------------------------------
    def learn(self, plan: CyclePlan, deployment: Deployment) -> None:
        """Update the models the adaptation level names with what the person did, and the
        allocation history (every level: it is what happened, not a model)."""
        self._check_current(plan)
        t0 = time.perf_counter()
        learn_time, learn_space = LEARNS[self.config.adapt]
        self._slowed[plan.cycle] = self.slowdowns.observe(  # before the path belief moves
            self._spatial(), plan.best.motions, deployment, self.model.slowdowns)
        for task, ex in deployment.human.items():
            if learn_time:
                self.model.temporal.observe(task, ex.duration)
                self.model.changes.cycles.setdefault(task, []).append(plan.cycle)
            if learn_space:
                self.model.spatial.observe(task, ex.trajectory)
        if self.config.detect and learn_time:
            self._changes[plan.cycle] = detect_changes(
                self.config, self.model, self.teammate, plan.cycle, deployment, learn_space)
        if learn_space:
            self.model.spatial.refit(deployment.human)
        self.model.history.record(plan.best.schedule)
        self.model.motions = plan.motions
        self._learn_gamma(plan.cycle, deployment)
        self._timing.setdefault(plan.cycle, {})["update"] = time.perf_counter() - t0

    def _learn_gamma(self, cycle: int, deployment: Deployment) -> None:
        """What the person said and signalled about the robot's closeness this cycle, and how
        they reacted to it (kept for the record), and the gamma belief updated with it when the
        run learns gamma. A person who says nothing still shows their reactions."""
        beta = self.model.spatial.config.beta
        ev = said_and_signalled(self.world, deployment, beta, self.comfort, self.teammate,
                                self.config.seed, cycle)
        if self.config.reacts and self.config.gamma_reactions and (
                ev is not None or self.model.gamma is not None):
            onsets, calm = reaction_evidence(self.world, deployment, beta)
            watched = dict(reactions=onsets, calm_peak=calm,
                           anchor=reaction_anchor(self.world, beta))
            ev = dataclasses.replace(ev or cycle_evidence(self.world, deployment, beta, None, ()),
                                     **watched, asked=ev is not None)
        if ev is None:
            return
        if self.model.gamma is not None:
            self.model.gamma.observe(ev)
        self._evidence[cycle] = {**ev.to_dict(), **(self.comfort.to_dict() if self.comfort
                                                     else {})}

    # -- record -------------------------------------------------------------------------------
    def record(self, plan: CyclePlan, deployment: Deployment,
               live: dict[str, Any] | None = None) -> CycleRecord:
        """The cycle's record; stored (with the model after learning) in one transaction when a
        store is attached. Advances the run to the next cycle. ``live``: what a live cell saw
        beyond the deployment (the robot's realised durations, touches), kept under ``live``
        (absent from every other record)."""
        self._check_current(plan)
        cfg, best, dep = self.config, plan.best, deployment
        idx = self.problem.index
        timing = self._timing.pop(plan.cycle, {})
        deploy_s, update_s = timing.get("deploy", 0.0), timing.get("update", 0.0)
        in_cycle = cycle_record(cfg, dep, self._deviations.pop(plan.cycle, None))
        comfort = cfg.simulates_comfort or plan.cycle in self._evidence
        pc = self.plan_cost(plan)
        typed = CycleRecord(
            cycle=plan.cycle,
            plan=PlanPart(
                human=tuple(best.schedule.human), robot=tuple(best.schedule.robot),
                routes={j: self.world.motion_label(j, p.trajectory)
                        for j, p in best.motions.items() if p.trajectory is not None},
                gamma=self.problem.objective.gamma, lam=plan.lam,
                expected=Predicted(
                    best.makespan_mean, best.makespan_std, best.spatial, best.diversity,
                    best.objective, best.converged,
                    {j: tuple(sorted(v)) for j, v in best.overlaps.items()})),
            execution=Execution(
                Realised(dep.makespan, dep.spatial, dep.cost, dep.min_separation,
                         {j: tuple(sorted(v)) for j, v in dep.overlaps.items()},
                         {t: (float(dep.timeline.start[0, idx[t]]),
                              float(dep.timeline.finish[0, idx[t]])) for t in self.problem.ids}),
                InCycle.from_json(in_cycle) if in_cycle else None),
            observed={t: ex.duration for t, ex in dep.human.items()},
            belief={"mean_durations": {  # of the tasks the person may do
                t: m for t, m in zip(self.problem.ids, self.model.temporal.mean().tolist(),
                                     strict=True) if math.isfinite(m)}},
            plan_cost=None if pc is None else PlanCost(**pc),
            search=plan.search,
            changes=self._changes.pop(plan.cycle, []) if cfg.detect else None,
            has_comfort=comfort, comfort=self._evidence.pop(plan.cycle, None) if comfort else None,
            gamma_belief=self.model.gamma.summary() if self.model.gamma else None,
            live=live, slowdowns=self._slowed.pop(plan.cycle, None),
            seconds={"plan": plan.seconds, "deploy": deploy_s, "update": update_s,
                     "total": plan.seconds + deploy_s + update_s},
        )
        if self.store is not None:
            arrays = path_arrays(dep.robot, {t: ex.trajectory for t, ex in dep.human.items()})
            self.store.record_cycle(cfg.run_id, plan.cycle, typed.to_json(), arrays,
                                    self.model.to_bytes())
        self.next_cycle += 1
        return typed

    def _check_current(self, plan: CyclePlan) -> None:
        if plan.cycle != self.next_cycle:
            raise RapiddsError(f"plan is for cycle {plan.cycle}, the run is at cycle "
                               f"{self.next_cycle}")

    # -- all together -------------------------------------------------------------------------
    def step(self) -> CycleResult:
        """Plan, execute, learn and record one cycle with the run's teammate."""
        plan = self.plan()
        dep = self.execute(plan)
        self.learn(plan, dep)
        return CycleResult(self.record(plan, dep), plan, dep)

    def run(self, on_cycle: Callable[[CycleResult], None] | None = None) -> list[CycleRecord]:
        """Run the remaining cycles; returns their records."""
        out = []
        while not self.finished:
            res = self.step()
            out.append(res.record)
            if on_cycle is not None:
                on_cycle(res)
        return out
