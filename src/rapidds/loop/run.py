"""The RAPIDDS multi-cycle loop (paper Algorithm 1), one cycle in four steps.

A run builds its :class:`~rapidds.loop.context.RunContext` once (world, config, problem,
policy, teammate, beliefs). Each cycle then: :meth:`AdaptiveRun.plan` searches the schedule
with the genetic scheduler, whose robot motions come from the steered diffusion policy, and
returns a :class:`~rapidds.loop.cycle.Cycle` carrying the plan, the gamma it was planned with
and its own random stream; a :class:`~rapidds.loop.observation.Source` observes what the person
did in it; :meth:`~AdaptiveRun.execute` realises the cycle from that observation;
:meth:`~AdaptiveRun.learn` updates the models the adaptation level names;
:meth:`~AdaptiveRun.record` stores the cycle in one transaction. :meth:`~AdaptiveRun.step` is
the four together, and every driver (the simulated run, a bag, the live cell, the study page)
calls it with its own source; each step can still be called on its own.

A run resumes from its last stored cycle with the models exactly as they were, because every
cycle draws its random numbers from (seed, cycle) and the stored state holds everything learned.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from rapidds.errors import RapiddsError, StateError
from rapidds.execution import CycleExecutor, HumanSource, Replanning
from rapidds.execution.registry import Planned
from rapidds.execution.slowdowns import HoldModel
from rapidds.human.spatial import SpatialModel
from rapidds.loop.carry import CarriedMotions, spatial_stamps, valid_plans
from rapidds.loop.changes import detect_changes
from rapidds.loop.comfort import (
    cycle_evidence,
    reaction_anchor,
    reaction_evidence,
    said_and_signalled,
)
from rapidds.loop.config import RunConfig
from rapidds.loop.context import RunContext, load_policy
from rapidds.loop.cycle import (
    Cycle,
    CyclePlan,
    CycleResult,
    FreeOrderTeammate,
    LiveTeammate,
    ReactiveTeammate,
    TeammateSource,
)
from rapidds.loop.deploy import Deployment
from rapidds.loop.execute import (
    CycleSetup,
    contingency_motions,
    cycle_executor,
    cycle_record,
    execute_cycle,
    replan_steering,
)
from rapidds.loop.model import HumanModel, oracle_spatial, value_terms, workspace_cost
from rapidds.loop.observation import Observation, Source
from rapidds.motion.diffusion_motion import DiffusionMotion, SteeringConfig
from rapidds.motion.interface import MotionKey, MotionModel, MotionPlan, TrajectoryCache
from rapidds.motion.policy import DiffusionPolicy
from rapidds.problem import Problem
from rapidds.record import CycleRecord, Execution, InCycle, PlanCost, PlanPart, Predicted, Realised
from rapidds.schedule import Schedule, Timeline
from rapidds.scheduler import (
    Evaluation,
    EvaluationContext,
    GAConfig,
    GeneticScheduler,
    evaluate_population,
    solve_exact,
)
from rapidds.store import RunStore, path_arrays
from rapidds.worlds.base import SimulatedTeammate, Teammate, World

__all__ = ["AdaptiveRun", "Cycle", "CyclePlan", "CycleResult", "FreeOrderTeammate",
           "LiveTeammate", "ReactiveTeammate", "RunContext", "load_policy", "timeline_of"]

PLAN_COST_SAMPLES = 256  # true-duration samples behind a cycle's plan cost (s.e. ~0.01 s)

LEARNS: dict[str, tuple[bool, bool]] = {  # adapt level -> (temporal, spatial) models updated
    "full": (True, True),
    "spatial": (False, True),
    "temporal": (True, False),
    "none": (False, False),
    "oracle": (False, False),
    "exact": (False, False),
}


def timeline_of(problem: Problem, record: CycleRecord) -> Timeline:
    """The realised timeline of a stored cycle record (for charts drawn after the fact)."""
    schedule = record.done  # who did what, where the person deviated
    times = record.realised.timeline
    start = np.array([[times[t][0] for t in problem.ids]])
    finish = np.array([[times[t][1] for t in problem.ids]])
    return Timeline(problem, schedule, start, finish)


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
        self.context = RunContext.build(config, policy, world, teammate, prior)
        self.store = store
        self._oracle_spatial: dict[str, SpatialModel] = {}
        self.next_cycle = 0
        if store is not None:
            self._attach(store)
        if self.policy.device.type != "cpu" and not self.finished:
            self.warm_up()

    # the context's parts, by the names drivers read them
    @property
    def world(self) -> World:
        return self.context.world

    @property
    def config(self) -> RunConfig:
        return self.context.config

    @property
    def problem(self) -> Problem:
        return self.context.problem

    @property
    def policy(self) -> DiffusionPolicy:
        return self.context.policy

    @property
    def teammate(self) -> Teammate:
        return self.context.teammate

    @property
    def model(self) -> HumanModel:
        return self.context.model

    @model.setter
    def model(self, model: HumanModel) -> None:
        self.context.model = model

    def _attach(self, store: RunStore) -> None:
        rid = self.config.run_id
        raw = store.run_config(rid)
        # a setting added since the run was stored ran with its default (which is the old
        # behaviour: every new setting's default is)
        stored = None if raw is None else {
            **{k: f.default for k, f in RunConfig.flat_fields().items()
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
        store.claim_policy(rid, self.policy.fingerprint())
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

    def _gamma(self, cycle: Cycle | None = None) -> float:
        """The gamma ``cycle`` was planned with (None: the next one's, the person's as believed
        now, or the run's fixed one when it does not learn gamma)."""
        if cycle is not None and cycle.gamma is not None:
            return cycle.gamma
        if cycle is None and self.model.gamma is not None:
            return self.model.gamma.planning(self.config.gamma_plan)
        return self.problem.objective.gamma

    def plan_cost(self, plan: Cycle) -> dict[str, float] | None:
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
        gamma = self._gamma(plan)
        ev = evaluate_population(
            EvaluationContext(self.problem, samples, mean, TrajectoryCache(motion),
                              motion.nominal_durations(self.problem), gamma, 0.0),
            [best.schedule])[0]
        return {"cost": ev.makespan_mean + gamma * ev.spatial, "makespan": ev.makespan_mean,
                "spatial": ev.spatial}

    def _plan_exact(self, motion: MotionModel, samples: np.ndarray, mean: np.ndarray,
                    gamma: float) -> tuple[Evaluation, dict[str, Any]]:
        """CP-SAT on the prior mean durations, scored like every other plan."""
        exact = solve_exact(self.problem, time_limit_s=5.0, human_mean=mean)
        cache = TrajectoryCache(motion)
        ev = evaluate_population(
            EvaluationContext(self.problem, samples, mean, cache,
                              motion.nominal_durations(self.problem), gamma, 0.0,
                              self.model.history),
            [exact.schedule])[0]
        return ev, {"solver": "cp-sat", "optimal": exact.optimal,
                    "motion_requests": cache.misses}

    def _motion(self, spatial: SpatialModel, gamma: float, steering: SteeringConfig,
                holds: HoldModel | None) -> DiffusionMotion:
        """The steered motions of a plan: the run's policy, V against ``spatial`` with the
        world's terms and, when the plan expects the monitor, its predicted ``holds``."""
        return DiffusionMotion(
            self.policy, self.world.completion_time, workspace_cost(self.world, spatial), gamma,
            steering, terms=value_terms(self.world, spatial,
                                        None if holds is None else holds.hold,
                                        None if holds is None else holds.tensor_hold))

    def warm_up(self) -> None:
        """One tiny steering batch with the run's value (the network, the world's terms, the
        monitor's hold when the run plans for it), its result dropped. On a GPU the first
        cycle would otherwise load all those kernels while the person waits; the run warms up
        when it is made there. It draws from no random stream the run uses and changes no
        belief, so the records are those of a run without it (tests check it)."""
        spatial = self._spatial()
        holds = self.context.slowdowns.model(spatial, self.model.slowdowns)
        robot = next(t.id for t in self.problem.tasks if t.can("robot"))
        near = frozenset(spatial.tasks[:1])
        self._motion(spatial, self.problem.objective.gamma,
                     SteeringConfig(particles=1, candidates=2, steps=2, seed=0),
                     holds).plan([(robot, near)])

    def plan(self) -> Cycle:
        """Plan the next cycle from the current belief (nothing changes until it is recorded)."""
        if self.finished:
            raise RapiddsError(f"run '{self.config.run_id}' is finished "
                               f"({self.config.cycles} cycles)")
        cfg, c = self.config, self.next_cycle
        t0 = time.perf_counter()
        gamma = self._gamma()  # this person's gamma, as believed now
        rng = np.random.default_rng([cfg.seed, c])
        samples, mean = self._durations(rng)
        exact = cfg.adapt == "exact"
        spatial = self._spatial()
        slowdowns = self.context.slowdowns
        holds = slowdowns.model(spatial, self.model.slowdowns)  # None: open-loop robot
        motion: MotionModel = self._motion(
            spatial, 0.0 if exact else gamma,  # the CP-SAT user ignores proximity
            SteeringConfig(particles=cfg.particles, candidates=cfg.candidates,
                           seed=int(rng.integers(2**31)), steps=cfg.steps), holds)
        carried = CarriedMotions(motion, dict(self.model.motions) if cfg.reuse_motions else {},
                                 spatial_stamps(spatial))
        held = slowdowns.wrap(carried, holds)
        ga_seed = int(rng.integers(2**31))
        lam = 0.0 if exact else cfg.lam_at(c, self.model.changes.last_change)
        if exact:
            best, search = self._plan_exact(held, samples, mean, gamma)
        else:
            # The GA's runner-up polishes off: every new (j, C_j) they reach is a steering
            # call, and they made a fetch trial ~50 % dearer (5.5 s against 3.6 s in the full
            # study) for a 4-task job the GA already solves. The order search off too: on this
            # job it changed no plan and no motion request in 32 cycles, and off keeps the
            # plans of the committed study (docs/reproduction.md).
            ga = GeneticScheduler(self.problem, held, GAConfig(
                population=cfg.population, generations=cfg.generations, samples=cfg.samples,
                patience=cfg.patience, polish_allocations=1, order_search_nodes=0,
                seed=ga_seed))
            result = ga.solve(samples, mean, gamma=gamma, lam=lam, history=self.model.history)
            best = result.best
            search = {"generations": result.generations_run, "evaluations": result.evaluations,
                      "motion_requests": result.cache_misses}
        search["motions_reused"] = carried.reused
        cycle = Cycle(c, best, lam, search, rng, time.perf_counter() - t0,
                      carried.carried if cfg.reuse_motions else {}, gamma)
        cycle.live_executor = lambda: self.live_executor(cycle)
        return cycle

    # -- observe and execute ------------------------------------------------------------------
    def source(self) -> Source:
        """The run's own teammate as a source (what :meth:`step` observes without one)."""
        reactive = self.config.execution.in_cycle
        return TeammateSource(self.teammate, self.live_executor if reactive else None,
                              ask=self.context.comfort is None)

    def execute(self, plan: Cycle, observation: Observation | None = None, *,
                source: Source | None = None) -> Deployment:
        """Realise ``plan`` from what the person did: ``observation``, else what ``source``
        (default: the run's teammate, :meth:`source`) observes of it. The cycle is realised
        with the robot's planned motions by the clock-driven executor, under the run's
        execution settings (:mod:`.execute`), replaying the person's executions and order. An
        observation that holds a cycle already ``played`` live on :meth:`live_executor` (the
        browser game under reactive execution) is that cycle; one with ``reacted`` (a live
        cell's own reactive layer: pauses, re-plans, protective check) and the robot's own
        durations is realised open loop from what happened, with those as its in-cycle
        record."""
        self._check_current(plan)
        t0 = time.perf_counter()
        obs = observation if observation is not None else (source or self.source()).observe(plan)
        plan.observation = obs
        if obs.played is not None:
            if not self.config.execution.in_cycle:
                raise ValueError("a cycle played live on the executor needs an execution that "
                                 "acts inside the cycle (e.g. reactive)")
            plan.deviation = None  # what a live person did is in the record
            plan.timing["deploy"] = time.perf_counter() - t0
            return obs.played
        if obs.robot_durations is not None:
            plan.as_executed(dict(obs.robot_durations))
        human = dict(obs.human)
        missing = set(plan.best.schedule.tasks("human")) - set(human)
        if missing:
            raise ValueError(f"no observation of human task(s) {sorted(missing)}")
        reacted = obs.reacted
        cfg = (self.config if reacted is None
               else self.config.model_copy(update={"execution": Planned()}))
        ran = plan.best.schedule if reacted is None else reacted.schedule or plan.best.schedule
        dep, plan.deviation = execute_cycle(self._setup(plan, cfg, ran), human, self.teammate,
                                            self.context.reaction, obs.order)
        if reacted is not None:
            dep = dataclasses.replace(dep, pauses=reacted.pauses, replans=reacted.replans,
                                      protective=reacted.protective)
        plan.timing["deploy"] = time.perf_counter() - t0
        return dep

    def _setup(self, plan: Cycle, config: RunConfig, schedule: Schedule) -> CycleSetup:
        """What the executor of ``plan`` is built from (:class:`~.execute.CycleSetup`): the
        robot's spare motions steered now, before the cycle starts; its re-plans steer where
        the concurrency changed, from the motions the plan's search steered."""
        spatial, gamma = self._spatial(), self._gamma(plan)
        steering = replan_steering(self.world, config, plan.cycle, gamma, self.policy, spatial)
        spare = contingency_motions(self.world, self.problem, config, plan.cycle, gamma,
                                    self.policy, spatial, plan.best.motions)
        return CycleSetup(
            self.world, self.problem, config, plan.cycle, gamma, schedule,
            {**spare, **plan.best.motions}, (self.model.temporal.mean(), self.model.temporal.std()),
            spatial, self.model.spatial.config.beta, steering=steering,
            memory=None if steering is None else valid_plans(plan.motions,
                                                             spatial_stamps(spatial)))

    def live_executor(self, plan: Cycle) -> Callable[[HumanSource], CycleExecutor]:
        """What builds the executor of ``plan`` around a live person (every restart of the
        cycle builds a fresh one): the robot's spare motions are steered once, here, before
        the cycle is shown; its re-plans steer where the concurrency changed as a simulated
        cycle's do; a live cycle has no time limit but the person's patience."""
        setup = self._setup(plan, self.config, plan.best.schedule)
        return lambda person: cycle_executor(setup, person, max_time=math.inf)

    def replanning(self, plan: Cycle) -> Replanning:
        """What a live cell's re-plans inside ``plan`` use: the learned models as they stand
        and the cycle's gamma (as a simulated reactive cycle's re-plans have them)."""
        from rapidds.loop.execute import cycle_replanning

        return cycle_replanning(self.world, self.problem, plan.best.motions,
                                (self.model.temporal.mean(), self.model.temporal.std()),
                                self.model.spatial, self._gamma(plan))

    # -- learn --------------------------------------------------------------------------------
    def learn(self, plan: Cycle, deployment: Deployment) -> None:
        """Update the models the adaptation level names with what the person did, and the
        allocation history (every level: it is what happened, not a model)."""
        self._check_current(plan)
        t0 = time.perf_counter()
        learn_time, learn_space = LEARNS[self.config.adapt]
        # on a GPU the belief's update finds its distances there too (numpy's operations in
        # numpy's order), since the host is what a cycle there waits for
        device = None if self.policy.device.type == "cpu" else self.policy.device
        plan.slowed = self.context.slowdowns.observe(  # before the path belief moves
            self._spatial(), plan.best.motions, deployment, self.model.slowdowns)
        for task, ex in deployment.human.items():
            if learn_time:
                self.model.temporal.observe(task, ex.duration)
                self.model.changes.cycles.setdefault(task, []).append(plan.cycle)
            if learn_space:
                self.model.spatial.observe(task, ex.trajectory, device)
        if self.config.detect and learn_time:
            plan.changes = detect_changes(
                self.config, self.model, self.teammate, plan.cycle, deployment, learn_space)
        if learn_space:
            self.model.spatial.refit(deployment.human)
        self.model.history.record(plan.best.schedule)
        self.model.motions = plan.motions
        self._learn_gamma(plan, deployment)
        plan.timing["update"] = time.perf_counter() - t0

    def _learn_gamma(self, plan: Cycle, deployment: Deployment) -> None:
        """What the person said and signalled about the robot's closeness this cycle, and how
        they reacted to it (kept for the record), and the gamma belief updated with it when the
        run learns gamma. A person who says nothing still shows their reactions."""
        beta, comfort = self.model.spatial.config.beta, self.context.comfort
        said = None if plan.observation is None else plan.observation.said
        ev = said_and_signalled(self.world, deployment, beta, comfort, said, self.config.seed,
                                plan.cycle)
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
        plan.evidence = {**ev.to_dict(), **(comfort.to_dict() if comfort else {})}

    # -- record -------------------------------------------------------------------------------
    def record(self, plan: Cycle, deployment: Deployment,
               live: dict[str, Any] | None = None) -> CycleRecord:
        """The cycle's record; stored (with the model after learning) in one transaction when a
        store is attached. Advances the run to the next cycle. ``live``: what a live cell saw
        beyond the deployment (the robot's realised durations, touches), kept under ``live``
        (absent from every other record); default: the observation's."""
        self._check_current(plan)
        cfg, best, dep = self.config, plan.best, deployment
        if live is None and plan.observation is not None:
            live = plan.observation.live
        idx = self.problem.index
        deploy_s, update_s = plan.timing.get("deploy", 0.0), plan.timing.get("update", 0.0)
        in_cycle = cycle_record(cfg, dep, plan.deviation)
        comfort = cfg.simulates_comfort or plan.evidence is not None
        pc = self.plan_cost(plan)
        typed = CycleRecord(
            cycle=plan.cycle,
            plan=PlanPart(
                human=tuple(best.schedule.human), robot=tuple(best.schedule.robot),
                routes={j: self.world.motion_label(j, p.trajectory)
                        for j, p in best.motions.items() if p.trajectory is not None},
                gamma=self._gamma(plan), lam=plan.lam,
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
            changes=plan.changes if cfg.detect else None,
            has_comfort=comfort, comfort=plan.evidence if comfort else None,
            gamma_belief=self.model.gamma.summary() if self.model.gamma else None,
            live=live, slowdowns=plan.slowed,
            seconds={"plan": plan.seconds, "deploy": deploy_s, "update": update_s,
                     "total": plan.seconds + deploy_s + update_s},
        )
        if self.store is not None:
            arrays = path_arrays(dep.robot, {t: ex.trajectory for t, ex in dep.human.items()})
            self.store.record_cycle(cfg.run_id, plan.cycle, typed.to_json(), arrays,
                                    self.model.to_bytes())
        self.next_cycle += 1
        return typed

    def _check_current(self, plan: Cycle) -> None:
        if plan.cycle != self.next_cycle:
            raise RapiddsError(f"plan is for cycle {plan.cycle}, the run is at cycle "
                               f"{self.next_cycle}")

    # -- all together: Algorithm 1's loop body ------------------------------------------------
    def step(self, source: Source | None = None, plan: Cycle | None = None) -> CycleResult:
        """One cycle: plan (unless ``plan``, already shown to the person), observe what the
        person did through ``source`` (default: the run's teammate), execute, learn, record."""
        cycle = plan if plan is not None else self.plan()
        dep = self.execute(cycle, source=source)
        self.learn(cycle, dep)
        return CycleResult(self.record(cycle, dep), cycle, dep)

    def run(self, on_cycle: Callable[[CycleResult], None] | None = None) -> list[CycleRecord]:
        """Run the remaining cycles; returns their records."""
        out = []
        while not self.finished:
            res = self.step()
            out.append(res.record)
            if on_cycle is not None:
                on_cycle(res)
        return out
