"""The planner as the hub of a live cell: each cycle it plans, publishes the plan and dispatches
the robot's trajectories over the link, runs the cycle from the events and tracking it receives,
then learns and records it like a simulated cycle (:class:`~rapidds.loop.run.AdaptiveRun`).

Dispatch: a robot task's ``JointTrajectory`` goes out when every task the plan puts before it
has ended (its header stamp is then "start now"), cut at the task's completion,
time-parameterized within the robot profile's limits and in its driver's joint names
(:meth:`~rapidds.bridge.profiles.RobotProfile.timed`). The person acts on the plan on their
own. The cycle is realised from what was observed: the person's durations and paths, and the
robot's durations from its start and end events (its trajectories stay the planned paths: the
loop scores and stores those).

Execution inside the cycle is the run's registered execution entry
(:mod:`rapidds.execution.registry`), the same one the simulated executor runs. Where it monitors
(``reactive``, ``monitored``): while the cycle runs, a
:class:`~rapidds.bridge.reactive.SpeedMonitor` with the entry's policy ticks at ``scaling_rate``
Hz of the cell clock and publishes the robot's speed scaling on ``/rapidds/robot/speed_scaling``;
the robot driver obeys it. Where it re-plans (``reactive``, ``replanning``): the robot's rest is
re-planned with the entry's re-planner on each deviation of the person. The monitor takes the
robot's expected speeds from the very trajectories dispatched (:meth:`LiveCell.timed`, once per
plan). Its pauses, protective check and re-plans go into the cycle's record, as a simulated
reactive cycle's.

Faults: the robot falls silent (no ``JointState`` for ``robot_timeout`` wall seconds), a node
leaves the link (its liveliness token goes: its process ended, its connection dropped) or the
cycle overruns (``cycle_timeout`` cell seconds): a stop goes out on ``/rapidds/stop``, nothing
is recorded, :class:`CellFault` is raised; ``--resume`` continues from the last recorded cycle.
A stop the hub did not send ends the cycle the same way at once, with the stop's stated reason
and sender. Input is bounded before it is kept (:mod:`rapidds.bridge.faults`,
:class:`~rapidds.bridge.live.CycleObservation`); what was dropped is summed up per cycle.
So is a safety function that cannot do its job (:mod:`rapidds.bridge.failsafe`): joint states
under other names than the profile's, a body point never tracked (before the first cycle: the
cycle is not started), a reactive monitor blind for long, a robot that does not hold at scaling
0, a robot task that ran unwatched.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import PurePosixPath
from typing import TYPE_CHECKING, Any

import numpy as np

from rapidds.bridge.failsafe import (
    MonitorGuard,
    ReadyCheck,
    joint_state_fault,
    planned_joint_speeds,
)
from rapidds.bridge.link import ALIVE_PREFIX, Link, Received, StampGate, log
from rapidds.bridge.live import (
    CONTACTS_TOPIC,
    SPEED_SCALING_TOPIC,
    STOP_TOPIC,
    CycleObservation,
    LivePlan,
    joint_rows,
    live_plan_payload,
    stop_payload,
    stop_words,
    tracking_topic,
)
from rapidds.bridge.profiles import DEFAULT_PROFILE, RobotProfile, robot_profile
from rapidds.bridge.reactive import SpeedMonitor, planned_speeds
from rapidds.bridge.replan import LiveReplanner
from rapidds.bridge.ros2 import (
    EVENTS_TOPIC,
    JOINT_STATE_TOPIC,
    PLAN_TOPIC,
    TRAJECTORY_TOPIC,
    MessageError,
    float64_message,
    stamp_ns,
    string_message,
)
from rapidds.errors import RapiddsError
from rapidds.execution.deployment import Reactions
from rapidds.schedule import Schedule
from rapidds.worlds.base import body_point_names
from rapidds.worlds.bounds import Plausibility, world_task_bound

if TYPE_CHECKING:
    from rapidds.execution.executor import Replanning
    from rapidds.loop.observation import Observation
    from rapidds.loop.run import AdaptiveRun, CyclePlan, CycleResult
    from rapidds.motion.timing import TimedTrajectory

__all__ = ["CellFault", "CellOptions", "LinkTeammate", "LiveCell"]


class CellFault(RapiddsError):
    """The cell stopped mid-cycle (a silent robot, a node gone, an overrun, a stop from
    elsewhere); the cycle was not recorded."""


MAX_CONTACTS = 1000
"""Contacts a cycle keeps (a robot that touches the person stops; a flood is counted only)."""
HUB = "hub"
"""The sender the hub names in its own stops."""


@dataclass(frozen=True)
class CellOptions:
    """time_scale: cell seconds per wall second. robot_timeout: wall s without a JointState
    before the robot counts as silent. startup_timeout: wall s to wait for the nodes.
    cycle_timeout: cell s a cycle may take. lead: wall s between publishing a plan and its
    start (the nodes' time to read it). scaling_rate: the monitor's ticks per cell second
    (where the run's execution monitors)."""

    time_scale: float = 1.0
    robot_timeout: float = 2.0
    startup_timeout: float = 60.0
    cycle_timeout: float = 120.0
    lead: float = 0.3
    scaling_rate: float = 20.0


@dataclass(frozen=True)
class _LinkSource:
    """A live cell as a :class:`~rapidds.loop.observation.Source`."""

    cell: LiveCell

    def observe(self, cycle: CyclePlan) -> Observation:
        return self.cell.observe_cycle(cycle)


class LinkTeammate:
    """The person at the far end of the link: the loop never asks them directly (the cell
    passes what it observed), and their truth is unknown, so no plan cost is computed."""

    name = "live"

    def execute(self, cycle: int, tasks: Any, rng: np.random.Generator) -> dict[str, Any]:
        raise RapiddsError("a live person's cycle comes from the link, not from execute()")


def _ran(plan: CyclePlan, obs: CycleObservation) -> Schedule | None:
    """The schedule the cell ran where a re-plan changed the robot's order or the person took
    a robot task (each agent's tasks in the order they started; the person's waits kept unless
    they took one, a re-planned rest has none); None: the plan's."""
    sched = plan.best.schedule
    robot = sorted((t for t in sched.tasks("robot") if t not in obs.taken),
                   key=lambda t: obs.start.get(t, math.inf))
    if not obs.taken:
        if robot == list(sched.tasks("robot")):
            return None
        return Schedule(sched.sequence("human"), tuple(robot))
    human = sorted((*sched.tasks("human"), *obs.taken), key=lambda t: obs.start.get(t, math.inf))
    return Schedule(tuple(human), tuple(robot))


def hub_topics(points: tuple[str, ...]) -> dict[str, str]:
    string = "std_msgs/msg/String"
    return {EVENTS_TOPIC: string, CONTACTS_TOPIC: string, STOP_TOPIC: string,
            JOINT_STATE_TOPIC: "sensor_msgs/msg/JointState",
            **{tracking_topic(p): "geometry_msgs/msg/PointStamped" for p in points}}


@dataclass
class LiveCell:
    """Runs an :class:`AdaptiveRun`'s cycles over ``link`` (opened with :func:`hub_topics`
    and ``watch=True``: the nodes' liveliness)."""

    run: AdaptiveRun
    link: Link
    options: CellOptions = field(default_factory=CellOptions)
    profile: RobotProfile = field(default_factory=lambda: robot_profile(DEFAULT_PROFILE))
    _robot_seen: float = 0.0
    _gate: StampGate = field(default_factory=StampGate)  # tracking stamps across cycles
    _guard: MonitorGuard = field(init=False)  # the reactive cycle's (bridge.failsafe)
    # the plan whose robot trajectories were last parameterized, and those (``timed``)
    _timings: tuple[CyclePlan, dict[str, TimedTrajectory]] | None = None

    def __post_init__(self) -> None:
        self.joints = self.profile.joint_names(self.run.world)  # the driver's names
        self.points = body_point_names(self.run.world)
        self.task_bound = world_task_bound(self.run.world)
        self._plausible = Plausibility(self.run.world)  # the run's: last plausible samples
        self._gate.faults = self.link.faults
        self._nodes: set[str] = set()  # liveliness tokens (node/session) the hub has seen
        # joints a joint state may carry beyond ``joints`` (a profile's fingers; bridge.failsafe)
        self.fingers = self.profile.fingers
        self._named = f"robot profile '{self.profile.name}' (--robot)"

    def wait_ready(self) -> None:
        """Until the robot streams joint states under the names the profile expects and the
        tracker every body point (:class:`~rapidds.bridge.failsafe.ReadyCheck`); a robot under
        other names or a body point left untracked is a fault, not a wait."""
        deadline = time.monotonic() + self.options.startup_timeout
        check = ReadyCheck(self.joints, self.points, self.fingers, self._named)
        while not check.ready:
            left = deadline - time.monotonic()
            why = check.result()
            if why is not None:
                raise self._stop(self.run.next_cycle, why, before=True)
            if left <= 0:
                missing = [n for n, ok in (("robot (joint states)", check.robot),
                                           ("tracker (body points)", bool(check.tracked)))
                           if not ok]
                raise CellFault(f"no {' or '.join(missing)} on the link after "
                                f"{self.options.startup_timeout:g} s; start the nodes with "
                                "--connect to this hub's endpoint")
            rec = self.link.receive(min(left, 0.2))
            if rec is not None:
                self._liveness(rec, None)
                check.see(rec)
        self._robot_seen = time.monotonic()
        time.sleep(0.2)  # the nodes' subscriptions reach the hub before the first plan
        for rec in self.link.drain():  # the backlog goes, the nodes' arrivals are kept
            self._liveness(rec, None)

    def _stop(self, cycle: int, reason: str, before: bool = False) -> CellFault:
        self.link.publish(STOP_TOPIC, string_message(stop_payload(cycle, reason, HUB)))
        if before:
            return CellFault(f"cycle {cycle} not started, nothing recorded: {reason}")
        return CellFault(f"cycle {cycle} stopped, not recorded: {reason}; continue with "
                         "--resume once the cell is back")

    def _liveness(self, rec: Received, cycle: int | None) -> None:
        """A node joined (kept) or left the link: during a cycle (``cycle``) a node it had
        seen leaving stops the cycle at once."""
        if not rec.topic.startswith(ALIVE_PREFIX):
            return
        token = rec.topic[len(ALIVE_PREFIX):]
        node = PurePosixPath(token).parts[0]  # node/session id
        if rec.msg:
            self._nodes.add(token)
            log.info("node %s is on the link", node)
        elif token in self._nodes:
            self._nodes.discard(token)
            if cycle is not None:
                raise self._stop(cycle, f"the {node} node left the link")
            log.warning("node %s left the link", node)

    def _publish_plan(self, plan: CyclePlan) -> LivePlan:
        run, best = self.run, plan.best
        idx = run.problem.index
        expected = {t: (float(best.expected_start[idx[t]]), float(best.expected_finish[idx[t]]))
                    for t in run.problem.ids if t in idx and len(best.expected_start)}
        payload = live_plan_payload(
            run.problem, plan.cycle, best.schedule.human, best.schedule.robot, expected,
            start_ns=time.time_ns() + round(self.options.lead * 1e9),
            time_scale=self.options.time_scale, dt=run.world.dt)
        self.link.publish(PLAN_TOPIC, string_message(payload))
        return LivePlan.parse(string_message(payload).data)

    def _dispatch(self, plan: CyclePlan, live: LivePlan, obs: CycleObservation,
                  sent: set[str], replanner: LiveReplanner | None = None) -> None:
        """Send each robot trajectory whose prerequisites have all ended (and are past t0), in
        the robot's order as last re-planned (the plan's without re-plans); the trajectory's
        frame_id names its task."""
        if time.time_ns() < live.stamp_ns:
            return
        order, after = ((live.order, live.after) if replanner is None
                        else (replanner.order, replanner.after))
        for task in order["robot"]:
            if task in sent or task in obs.start or not all(x in obs.end for x in after[task]):
                continue
            timed = self.timed(plan)[task]
            self.link.publish(TRAJECTORY_TOPIC, self.profile.trajectory(
                self.run.world, timed, stamp_ns=time.time_ns(), frame_id=task))
            sent.add(task)
            log.info("cycle %d: dispatched %s (%.2f s)", plan.cycle, task, timed.duration)

    def timed(self, plan: CyclePlan) -> dict[str, TimedTrajectory]:
        """Each robot task's trajectory as the hub sends it: cut to the task, parameterized
        within the robot profile's limits (world convention). Computed once per plan: the
        dispatch sends these and the reactive monitor and its guard take the robot's expected
        speeds from these, so what is watched is what runs. A path the arm would refuse
        stops the cycle, nothing recorded."""
        if self._timings is None or self._timings[0] is not plan:
            try:
                timed = {t: self.profile.timed(self.run.world, t, m.trajectory)
                         for t, m in plan.best.motions.items() if m.trajectory is not None}
            except RapiddsError as exc:
                raise self._stop(plan.cycle, str(exc)) from None
            self._timings = (plan, timed)
        return self._timings[1]

    def _take(self, live: LivePlan, obs: CycleObservation, wait: float = 0.02,
              monitor: SpeedMonitor | None = None) -> None:
        """Wait up to ``wait`` s for a message and file it; with a ``monitor``, every other
        one queued too: it acts on the latest state, never on a backlog (joint states come
        hundreds a second)."""
        rec = self.link.receive(wait)
        if rec is None:
            return
        for r in (rec, *(self.link.drain() if monitor is not None else ())):
            self._file(live, obs, r, monitor)

    def _file(self, live: LivePlan, obs: CycleObservation, rec: Received,
              monitor: SpeedMonitor | None) -> None:
        if rec.topic == STOP_TOPIC:  # not the hub's own: it raises as it sends one
            reason, sender = stop_words(rec.msg.data)
            raise CellFault(f"cycle {live.cycle} stopped, not recorded: a stop from {sender}: "
                            f"{reason}; continue with --resume once the cell is back")
        self._liveness(rec, live.cycle)
        if rec.topic == JOINT_STATE_TOPIC:
            why = joint_state_fault(rec.msg.name, rec.msg.position, self.joints, self.fingers,
                                    self._named)
            if why is not None:  # not the robot the profile describes: not a live robot
                raise self._stop(live.cycle, why)
            self._robot_seen = time.monotonic()
            rows = joint_rows(rec.msg.name, self.joints)
            if monitor is not None and rows is not None:
                monitor.joint_state(np.asarray(rec.msg.position, float)[rows]
                                    - self.profile.offset(self.run.world),
                                    live.cell_seconds(stamp_ns(rec.msg.header)))
        elif rec.topic == CONTACTS_TOPIC:
            if len(obs.contacts) >= MAX_CONTACTS:
                obs.faults.warn("contact flood", "dropped a contact: over %d this cycle",
                                MAX_CONTACTS)
                return
            obs.contacts.append({"at": live.cell_seconds(rec.received_ns),
                                 "touch": rec.msg.data[:1000]})
            log.warning("contact: %s", rec.msg.data[:200])
        else:
            obs.handle(rec)

    def _monitor(self, plan: CyclePlan) -> SpeedMonitor | None:
        """The cycle's monitor, where the run's execution monitors (None: the robot runs at
        full speed)."""
        execution = self.run.config.execution
        if not execution.monitor:
            return None
        timed = self.timed(plan)
        monitor = SpeedMonitor(self.run.world, planned_speeds(self.run.world, timed),
                               period=1.0 / self.options.scaling_rate, execution=execution)
        self._guard = MonitorGuard(planned_joint_speeds(timed), monitor.limits.stopping_time)
        return monitor

    def _scale(self, live: LivePlan, obs: CycleObservation, sent: set[str],
               monitor: SpeedMonitor, tick: float) -> float:
        """Run the monitor's ticks that are due (the latest one, if several are: a slow pass
        does not replay the past); the next tick's cell time."""
        now = live.cell_seconds(time.time_ns())
        if now < tick:
            return tick
        running = next((t for t in live.order["robot"] if t in sent and t not in obs.end), None)
        rate = monitor.tick(now, obs.latest(), running, obs.velocities())
        self.link.publish(SPEED_SCALING_TOPIC, float64_message(rate))
        fault = self._guard.check(now, monitor, running)
        if fault is not None:
            raise self._stop(live.cycle, fault)
        period = 1.0 / self.options.scaling_rate
        return (np.floor(now / period + 1e-9) + 1) * period

    def observe(self, plan: CyclePlan, monitor: SpeedMonitor | None = None,
                replans: list[dict[str, Any]] | None = None) -> CycleObservation:
        """Run one cycle on the link and return what was observed; CellFault on a fault.
        ``monitor``: reactive execution's, ticked while the cycle runs; ``replans``: where
        the re-plans of the rest go when the person deviates (None: the plan is followed)."""
        rp = None if replans is None else self._replanning(plan)  # before t0 is set: it takes
        self.timed(plan)  # the trajectories to send, before t0 too (a refused path: no plan)
        live = self._publish_plan(plan)
        sent: set[str] = set()
        problem = self.run.problem
        obs = CycleObservation(live, self.points, gate=self._gate,
                               window=self.options.cycle_timeout, task_bound=self.task_bound,
                               plausible=self._plausible, faults=self.link.faults,
                               may_take=None if rp is None else (
                                   lambda t: t not in sent and problem.task(t).can("human")))
        replanner = None if rp is None else LiveReplanner(
            self.run.problem, {a: list(o) for a, o in live.order.items()},
            {t: list(v) for t, v in live.after.items()}, rp)
        self._robot_seen = time.monotonic()
        tick = 0.0
        while not obs.done:
            if replanner is not None:
                self._deviations(live, obs, sent, replanner)
            self._dispatch(plan, live, obs, sent, replanner)
            wait = 0.02
            if monitor is not None:
                tick = self._scale(live, obs, sent, monitor, tick)
                left = (live.wall_ns(tick) - time.time_ns()) / 1e9
                wait = min(wait, max(left, 0.0))
            self._take(live, obs, wait, monitor)
            if time.monotonic() - self._robot_seen > self.options.robot_timeout:
                raise self._stop(plan.cycle, f"the robot has been silent for "
                                             f"{self.options.robot_timeout:g} s")
            if live.cell_seconds(time.time_ns()) > self.options.cycle_timeout:
                raise self._stop(plan.cycle, f"the cycle took over "
                                             f"{self.options.cycle_timeout:g} s")
        if replanner is not None and replans is not None:
            replans.extend(replanner.replans)
        # Zenoh keeps the order of messages per key only: the person's last tracked rows may
        # come after their last end event. A tracker streams at rest too, so read on until
        # every body point is tracked past that end (robot_timeout wall s at most).
        human = [obs.end[t] for t in live.agent if obs.doer(t) == "human"]
        deadline = time.monotonic() + self.options.robot_timeout
        while human and not obs.tracked_past(max(human)):
            if time.monotonic() > deadline:
                log.warning("cycle %d: tracking did not reach the person's last end", plan.cycle)
                break
            self._take(live, obs)
        return obs

    def _replanning(self, plan: CyclePlan) -> Replanning | None:
        """What the cycle's re-plans use, built by the run's execution entry from the learned
        models as they stand and the cycle's gamma (as a simulated cycle's re-plans have them);
        None: no re-plans."""
        return self.run.config.execution.replanner(lambda: self.run.replanning(plan))

    def _deviations(self, live: LivePlan, obs: CycleObservation, sent: set[str],
                    replanner: LiveReplanner) -> None:
        """Re-plan the robot's rest on each deviation of the person seen so far."""
        now = live.cell_seconds(time.time_ns())
        started = sorted((t for t in obs.start if obs.doer(t) == "human"),
                         key=lambda t: obs.start[t])
        for reason, task in replanner.deviations(now, obs.start, obs.end, started):
            entry = replanner.replan(now, reason, task, obs.start, obs.end, sorted(sent))
            log.info("cycle %d: re-planned at %.2f s (%s %s): robot %s%s", live.cycle, now,
                     reason, task, replanner.order["robot"],
                     "" if entry["changed"] else " (unchanged)")

    def observe_cycle(self, plan: CyclePlan) -> Observation:
        """The cell as the loop's :class:`~rapidds.loop.observation.Source`: run ``plan`` over
        the link (:meth:`observe`) and hand back what the person did, what the cell's reactive
        layer did (pauses, re-plans, protective check), the durations the robot took (the
        cycle is realised with them) and what the record keeps beyond the deployment (the
        robot's realised and planned durations, contacts). CellFault on a fault."""
        from rapidds.loop.observation import Observation

        monitor = self._monitor(plan)
        replans: list[dict[str, Any]] | None = [] if self.run.config.execution.replan else None
        try:
            obs = self.observe(plan, monitor, replans)
        finally:
            self.link.faults.summary(f"cycle {plan.cycle}")
        reacted = None
        if monitor is not None:
            monitor.close(max(obs.end.values(), default=0.0))
            fault = self._guard.unwatched(monitor)
            if fault is not None:
                raise self._stop(plan.cycle, fault)
            self.link.publish(SPEED_SCALING_TOPIC, float64_message(1.0))  # between cycles
        if monitor is not None or replans is not None:
            reacted = Reactions(() if monitor is None else tuple(monitor.pauses),
                                tuple(replans or ()),
                                None if monitor is None else monitor.protective(),
                                _ran(plan, obs))
        try:
            human = obs.human_executions(self.run.world.dt)
        except MessageError as exc:
            raise self._stop(plan.cycle, str(exc)) from None
        planned = {t: float(m.duration) for t, m in plan.best.motions.items()}
        robot = obs.durations("robot")
        live = {"robot_durations": robot, "planned_robot_durations": planned,
                "contacts": obs.contacts}
        return Observation(human=human, events={t: (obs.start[t], obs.end[t]) for t in human},
                           reacted=reacted, robot_durations=robot, live=live)

    def cycle(self) -> tuple[CycleResult, dict[str, Any]]:
        """Plan, run over the link, learn, record (:meth:`AdaptiveRun.step` with the cell as
        its source). Returns the result and what the link saw beyond the deployment (the
        robot's realised durations, contacts; also the record's ``live``)."""
        res = self.run.step(_LinkSource(self))
        assert res.plan.observation is not None and res.plan.observation.live is not None
        return res, res.plan.observation.live

    def run_all(self, on_cycle: Callable[[CycleResult, dict[str, Any]], None] | None = None,
                ) -> None:
        """Every remaining cycle of the run."""
        if self.run.finished:
            return
        self.wait_ready()
        while not self.run.finished:
            res, live = self.cycle()
            if on_cycle is not None:
                on_cycle(res, live)
