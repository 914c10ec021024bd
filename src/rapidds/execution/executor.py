"""The clock-driven executor of one cycle.

Time advances from one instant to the next: the next tick of the world's clock (every dt, when
anything watches distances: a reacting person or speed and separation monitoring) or the next
event a source announces (a task's end, a pause's start), whichever comes first. At each
instant the executor starts what may start (an agent free, the task's precedence predecessors
finished, its wait tokens passed; the person chooses among what they may start), asks the
policy for the robot's rate, lets both sources move on, and records what ended. With an
undisturbed person and the open-loop policy every time is computed as the open-loop replay
computes it (start = the latest gating finish, finish = start + duration), so ``--execution
planned`` gives the paper's records to the last bit.

The result is a :class:`~rapidds.loop.deploy.Deployment`, what the loop already learns from
and records, with the robot's pauses, the person's and the re-plans added.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from rapidds.errors import RapiddsError, RuntimeFault
from rapidds.execution.deployment import Deployment, realise
from rapidds.execution.policies import (
    OpenLoop,
    RobotPolicy,
    Scene,
    directed_speeds,
    protective_check,
)
from rapidds.execution.replan import (
    MotionSupply,
    Progress,
    Remainder,
    replan_remainder,
    robot_concurrency,
)
from rapidds.execution.sources import (
    HumanSource,
    PlannedRobot,
    RobotSource,
    RobotView,
    SimulatedHuman,
    SteerableRobot,
)
from rapidds.execution.yielding import YieldGuard, YieldRule
from rapidds.motion.interface import MotionPlan
from rapidds.problem import Problem
from rapidds.schedule import Item, Schedule, Timeline, Wait
from rapidds.worlds.base import World
from rapidds.worlds.reactions import SafetyLimits

__all__ = ["CycleExecutor", "Replanning"]

AGENTS = ("human", "robot")


@dataclass(frozen=True)
class Replanning:
    """What re-planning inside a cycle uses: the learned models as they stand.

    mean, std: the person's expected duration and its spread per task (the belief); robot: the
    robot's motion duration per task it has a trajectory for; spatial(j, C): robot task j's
    spatial cost beside the person's tasks C; gamma: the proximity weight; z: a running task
    overruns past mean + z std (1.2816: the 90 % quantile of a normal); motions: where a re-plan
    gets a motion for a robot task whose concurrent person's tasks it changed (None: the robot
    keeps its motions); steer_max: how many such pairs one re-plan may steer anew (the rest keep
    their motion), which bounds its latency."""

    mean: Mapping[str, float]
    std: Mapping[str, float]
    robot: Mapping[str, float]
    spatial: Callable[[str, frozenset[str]], float]
    gamma: float
    z: float = 1.2816
    motions: MotionSupply | None = None
    steer_max: int = 1


@dataclass(frozen=True)
class CycleRules:
    """What watches and adjusts a cycle while it runs, beside the robot's policy.

    replanning: re-plans the rest when the person deviates (None: never); limits: the robot's
    safety numbers, against which every watched instant is checked (the result's
    ``protective``), whichever policy runs; max_time: the cycle's simulated time limit;
    yielding: when a held robot gives way to a person who waits for it (:mod:`.yielding`; only
    a policy that holds the robot needs it; None: :class:`YieldRule`'s defaults).
    """

    replanning: Replanning | None = None
    limits: SafetyLimits | None = None
    max_time: float = 600.0
    yielding: YieldRule | None = None


class CycleExecutor:
    """One cycle of ``schedule`` fed by a human and a robot source under a robot policy and
    the :class:`CycleRules` ``rules``."""

    def __init__(self, world: World, problem: Problem, schedule: Schedule, human: HumanSource,
                 robot: RobotSource, policy: RobotPolicy | None = None, *, beta: float,
                 rules: CycleRules = CycleRules()):
        self.world, self.problem, self.human, self.robot = world, problem, human, robot
        self.policy = policy or OpenLoop()
        self.beta, self.replanning, self.max_time = beta, rules.replanning, rules.max_time
        self.limits = rules.limits  # the protective distance measured against, whatever the policy
        self.queue: dict[str, list[Item]] = {a: list(schedule.sequence(a)) for a in AGENTS}
        self.start: dict[str, float] = {}
        self.finish: dict[str, float] = {}
        self.doer: dict[str, str] = {}
        self.running: dict[str, str | None] = {a: None for a in AGENTS}
        self.replans: list[dict[str, Any]] = []
        # every instant watched while the robot had a task: (t, separation, person's speed
        # towards the robot, robot's towards the person at full rate in the direction it went,
        # rate), for checks of the protective distance
        self.trace: list[tuple[float, float, float, float, float]] = []
        self._robot_held: tuple[float, str] | None = None  # since when, "stop" or "slow"
        self._held_task: str | None = None
        self._robot_pauses: list[dict[str, Any]] = []
        self._overran: set[str] = set()
        self._claimed: frozenset[str] = frozenset()  # robot tasks the person took
        self._steered: dict[str, MotionPlan] = {}  # motions re-plans gave the robot
        self._last: tuple[float, np.ndarray] | None = None
        self._vel_h: np.ndarray | None = None  # the person's body points' velocities
        self.now = 0.0  # the executor's clock: every instant before it has been run
        self.rate = 1.0  # the robot's rate from the last instant run (what a live page shows)
        self._stalled = 0  # instants in a row at which time did not move: a bug, not a cycle
        reacts = getattr(human, "reaction", None) is not None
        self.watching = reacts or not isinstance(self.policy, OpenLoop)
        self.guard = YieldGuard(rules.yielding or YieldRule(), world.dt)

    # -- starting what may start ----------------------------------------------------------------
    def _gated(self, task: str) -> bool:
        return all(p in self.finish for p in self.problem.preceding[task])

    def _head(self, agent: str) -> str | None:
        """Drop passed waits and tasks someone else took; the next task if it may start."""
        q = self.queue[agent]
        while q and ((isinstance(q[0], Wait) and q[0].task in self.finish)
                     or (isinstance(q[0], str) and q[0] in self.start)):
            q.pop(0)
        if not q or isinstance(q[0], Wait):
            return None
        return q[0] if self._gated(q[0]) else None

    def _begin(self, agent: str, task: str, now: float) -> None:
        self.start[task], self.doer[task], self.running[agent] = now, agent, task
        (self.human if agent == "human" else self.robot).start(task, now)

    def _dispatch(self, now: float) -> list[tuple[str, str]]:
        """Start what may start at ``now``; the person's deviations: (reason, task)."""
        deviations = []
        if self.running["robot"] is None:
            task = self._head("robot")
            if task is not None:
                self.queue["robot"].pop(0)
                self._begin("robot", task, now)
        if self.running["human"] is None:
            planned = self._head("human")
            mine = [t for t in self.queue["human"] if isinstance(t, str)]
            ready = [t for t in mine if self._gated(t)]
            takeable = [t for t in self.queue["robot"] if isinstance(t, str)
                        and t not in self.start and self.problem.task(t).can("human")]
            choice = self.human.choose(now, planned, ready, takeable)
            if choice in takeable:  # the person claims a robot task: now, or once it may start
                self.queue["robot"].remove(choice)
                self._claim(choice)
                deviations.append(("took", choice))
                if self._gated(choice):
                    self.queue["human"].remove(choice)
                    self._begin("human", choice, now)
            elif choice is not None:
                if choice not in ready:
                    raise RapiddsError(f"the person started '{choice}', which they may not "
                                       f"start now (ready: {ready}, takeable: {takeable})")
                self.queue["human"].remove(choice)
                self._begin("human", choice, now)
                if choice != planned:
                    deviations.append(("order", choice))
        return deviations

    def _claim(self, task: str) -> None:
        """Put a claimed task into the person's queue right after the last of their tasks it
        must follow (precedence, transitively), so their order stays feasible."""
        before, stack = set(), list(self.problem.preceding[task])
        while stack:
            t = stack.pop()
            if t not in before:
                before.add(t)
                stack.extend(self.problem.preceding[t])
        self._claimed |= {task}
        q = self.queue["human"]
        at = max((k + 1 for k, t in enumerate(q) if isinstance(t, str) and t in before),
                 default=0)
        q.insert(at, task)

    def _unstick(self, now: float) -> bool:
        """Nothing runs and nothing may start (a deviation left an order that cannot go on):
        the robot skips a wait it cannot pass, the person does a task they may start. False
        when neither helps."""
        q = self.queue["robot"]
        if q and isinstance(q[0], Wait) and q[0].task not in self.finish:
            q.pop(0)
            return True
        mine = [t for t in self.queue["human"] if isinstance(t, str) and self._gated(t)]
        if mine:
            self.queue["human"].remove(mine[0])
            self.queue["human"].insert(0, mine[0])
            self.queue["human"] = [x for x in self.queue["human"] if not (
                isinstance(x, Wait) and x.task not in self.finish)]
            return True
        return False

    # -- the robot's rate -------------------------------------------------------------------------
    def _rate(self, now: float) -> tuple[float, RobotView]:
        r_pts = self.robot.points()
        if not self.watching:
            return 1.0, RobotView(r_pts, self.running["robot"] is not None)
        h_pts = self.human.points()
        if self._last is not None and now - self._last[0] > 1e-6:
            self._vel_h = (h_pts - self._last[1]) / (now - self._last[0])
        self._last = (now, h_pts)
        if self.running["robot"] is None:
            return 1.0, RobotView(r_pts, False)
        speed = self.robot.speed()
        scene = Scene(h_pts, np.zeros_like(h_pts) if self._vel_h is None else self._vel_h,
                      r_pts, self.robot.velocity(), speed)
        forward = self.policy.rate(scene)
        back = (self.policy.rate(scene.backwards()) if forward < 1.0 or self.guard.phase
                else 0.0)
        rate = self._yield(now, h_pts, (forward, back))
        self.trace.append((now, *directed_speeds(scene if rate >= 0 else scene.backwards()),
                           rate))
        return rate, RobotView(r_pts, rate != 0.0 and speed > 0.0)

    def _yield(self, now: float, h_pts: np.ndarray, rates: tuple[float, float]) -> float:
        """The rate after the yield rule: the policy's, or backing/standing while the robot
        gives way (only where it can say how far along its task it is)."""
        at = self.robot.progress() if isinstance(self.robot, PlannedRobot) else None
        if at is None:
            return rates[0]
        before = len(self.guard.yields)
        rate = self.guard.rate(now, at, self.running["human"], h_pts, rates, len(self.finish))
        if len(self.guard.yields) > before:
            self._replan(now, "yield", at[0])
        return rate

    def _log_robot(self, now: float, rate: float) -> None:
        kind = "" if rate >= 1.0 or self.running["robot"] is None else (
            f"yield: {self.guard.phase}" if self.guard.phase else
            "stop" if rate <= 0.0 else "slow")
        if self._robot_held is not None and self._robot_held[1] != kind:
            since, was = self._robot_held
            why = (f"yielded to the person ({was[7:]})" if was.startswith("yield")
                   else f"protective distance ({was})")
            self._robot_pauses.append({"agent": "robot", "task": self._held_task, "start": since,
                                       "end": now, "reason": why})
            self._robot_held = None
        if kind and self._robot_held is None:
            self._robot_held, self._held_task = (now, kind), self.running["robot"]

    # -- re-planning ------------------------------------------------------------------------------
    def _replan(self, now: float, reason: str, task: str) -> None:
        rp = self.replanning
        if rp is None:
            return
        t0 = time.perf_counter()
        fixed = {t: (self.doer[t], self.start[t], f) for t, f in self.finish.items()}
        free = {a: now for a in AGENTS}
        for a, t in self.running.items():
            if t is None:
                continue
            end = (max(now, self.start[t] + rp.mean[t]) if a == "human"
                   else self.robot.next_event(now, 1.0))
            fixed[t], free[a] = (a, self.start[t], end), end
        current = {a: [t for t in self.queue[a] if isinstance(t, str) and t not in self.start]
                   for a in AGENTS}
        mean = {f"human:{t}": m for t, m in rp.mean.items()}
        mean.update({f"robot:{t}": d for t, d in rp.robot.items()})
        mean.update({f"robot:{t}": m.duration for t, m in self._steered.items()})
        rem = replan_remainder(self.problem, Progress(now, current, fixed, free, mean),
                               frozenset(rp.robot), self._spatial, rp.gamma, self._claimed)
        changed = (list(rem.human), list(rem.robot)) != (current["human"], current["robot"])
        if changed:
            self.queue = {"human": list(rem.human), "robot": list(rem.robot)}
        t1 = time.perf_counter()
        motions = self._resteer(now, rem, fixed, free, mean)
        self.replans.append({
            "time": now, "reason": reason, "task": task, "changed": changed,
            "before": current, "after": {"human": list(rem.human), "robot": list(rem.robot)},
            "expected_makespan_cost": rem.objective,
            "expected_cost_before": rem.current if math.isfinite(rem.current) else None,
            "evaluated": rem.evaluated,
            **({"motions": motions, "steer_s": time.perf_counter() - t1}
               if rp.motions is not None else {}),
            "latency_s": time.perf_counter() - t0})

    def _spatial(self, task: str, near: frozenset[str]) -> float:
        """Robot task's spatial cost beside the person's tasks ``near``, with the motion it has
        now (one a re-plan gave it, else the plan's)."""
        rp = self.replanning
        assert rp is not None
        plan = self._steered.get(task)
        if plan is None or rp.motions is None:
            return rp.spatial(task, near)
        return 0.0 if plan.trajectory is None else rp.motions.cost(near, plan.trajectory)

    def _resteer(self, now: float, rem: Remainder,
                 fixed: Mapping[str, tuple[str, float, float]], free: Mapping[str, float],
                 mean: Mapping[str, float]) -> list[dict[str, Any]]:
        """Where the re-planned rest runs a robot task beside other person's tasks than its
        motion was steered for, a motion for the new (task, set): recalled (steered already,
        free), else steered now (at most ``steer_max`` a re-plan, one batch; the rest keep
        theirs). It replaces the robot's when its value d + gamma S against the new set is
        lower. Pairs whose set did not change keep their motion and are not listed."""
        rp = self.replanning
        assert rp is not None
        supply = rp.motions
        if supply is None or not isinstance(self.robot, SteerableRobot):
            return []
        todo: list[tuple[str, MotionPlan, frozenset[str]]] = []
        for j, near in robot_concurrency(self.problem, now, rem.human, rem.robot, fixed, free,
                                         mean).items():
            have = self._steered.get(j) or supply.planned(j)
            if have is not None and have.concurrent != near:
                todo.append((j, have, near))
        found = {j: supply.recall((j, near)) for j, _, near in todo}
        fresh = [(j, near) for j, _, near in todo if found[j] is None][:rp.steer_max]
        steered = dict(zip([j for j, _ in fresh], supply.steer(fresh) if fresh else [],
                           strict=True))

        def value(plan: MotionPlan, near: frozenset[str]) -> float:
            far = not near or plan.trajectory is None or rp.gamma == 0
            return plan.duration + (0.0 if far else rp.gamma * supply.cost(near,
                                                                           plan.trajectory))

        out = []
        for j, have, near in todo:
            new = found[j] or steered.get(j)
            entry: dict[str, Any] = {
                "task": j, "was": sorted(have.concurrent), "now": sorted(near),
                "by": "recalled" if found[j] else "steered" if new else "kept (steering budget)"}
            if new is not None:
                entry["value"] = [value(have, near), value(new, near)]
                entry["used"] = entry["value"][1] < entry["value"][0] - 1e-9
                if entry["used"]:
                    self._steered[j] = new
                    self.robot.follow(new)
            out.append(entry)
        return out

    def _check_overrun(self, now: float) -> None:
        rp, task = self.replanning, self.running["human"]
        if rp is None or task is None or task in self._overran or task not in rp.mean:
            return
        if now - self.start[task] > rp.mean[task] + rp.z * rp.std.get(task, 0.0):
            self._overran.add(task)
            self._replan(now, "overran", task)

    # -- the cycle --------------------------------------------------------------------------------
    @property
    def over(self) -> bool:
        """Whether every task has finished."""
        return len(self.finish) == len(self.problem.ids)

    def advance_to(self, limit: float) -> bool:
        """Run the cycle up to time ``limit`` (s), or to its end if that comes first; True when
        it is over. :meth:`run` is this with no limit; a live source (the browser game) calls
        it once per tick with the tick's time, its sources holding what happened until then.
        An instant at ``limit`` itself is left to the next call, whose sources know more."""
        dt = self.world.dt
        while not self.over and self.now < limit:
            now = self.now
            for reason, task in self._dispatch(now):
                self._replan(now, reason, task)
                self._dispatch(now)
            rate, view = self._rate(now)
            self._log_robot(now, rate)
            self.rate = rate
            until = min(self.human.next_event(now, view), self.robot.next_event(now, rate), limit)
            if self.watching:
                until = min(until, (math.floor(now / dt + 1e-9) + 1) * dt)
            if rate < 0.0:  # backing while it yields: no further than the rule says
                at = self.robot.progress() if isinstance(self.robot, PlannedRobot) else None
                until = min(until, now + self.guard.retreat_left(at[1] if at else 0.0) / -rate)
            if not math.isfinite(until) and self._unstick(now):
                continue
            self._stalled = self._stalled + 1 if until <= now else 0
            if not math.isfinite(until) or until > self.max_time or self._stalled > 1000:
                raise RuntimeFault(f"the cycle is stuck at t = {now:.2f} s (running "
                                   f"{self.running}, waiting {self.queue})")
            for agent, ended in (("human", self.human.advance(now, until, view)),
                                 ("robot", self.robot.advance(now, until, rate))):
                if ended is not None:
                    self.finish[ended] = until
                    self.running[agent] = None
            self.now = until
            self._check_overrun(until)
        return self.over

    def run(self) -> Deployment:
        """Run the cycle to its end; what happened."""
        self.advance_to(math.inf)
        return self.result()

    def result(self) -> Deployment:
        """What happened, once the cycle is over."""
        if not self.over:
            raise RapiddsError(f"the cycle is not over at t = {self.now:.2f} s")
        self._log_robot(self.now, 1.0)
        return self._result()

    def _result(self) -> Deployment:
        ids, idx = self.problem.ids, self.problem.index
        order = sorted(ids, key=lambda t: (self.start[t], idx[t]))
        sched = Schedule(*(tuple(t for t in order if self.doer[t] == a) for a in AGENTS))
        start = np.array([[self.start[t] for t in ids]])
        finish = np.array([[self.finish[t] for t in ids]])
        seen = self.human.observed()
        human = {t: seen[t] for t in sched.tasks("human")}
        dep = realise(self.world, self.problem, Timeline(self.problem, sched, start, finish),
                      human, self.robot.realised(), beta=self.beta)
        pauses = list(self._robot_pauses)
        if isinstance(self.human, SimulatedHuman):
            pauses += [{"agent": "person", "task": t, "start": s, "end": e, "reason": r}
                       for s, e, t, r in self.human.pauses]
        pauses.sort(key=lambda p: (p["start"], p["agent"]))
        return dataclasses.replace(dep, pauses=tuple(pauses), replans=tuple(self.replans),
                                   protective=self._protective(),
                                   yields=tuple(self.guard.finish(self.now)))

    def _protective(self) -> dict[str, Any] | None:
        if self.limits is None or not self.watching:
            return None
        return protective_check(self.limits, len(self.trace),
                                ((sep, vh, abs(rate) * vr) for _, sep, vh, vr, rate in self.trace
                                 if rate != 0.0 and vr > 0.0))
