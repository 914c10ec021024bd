"""A cycle recorded in a real cell, read from a rosbag2 bag under the default contract.

- Task events on ``/rapidds/events`` (String JSON ``{"task", "agent", "event"}``), timed by the
  bag's receive time.
- Tracked points (PointStamped, PoseStamped, PoseArray, TFMessage) mapped to the world's body
  points by a :class:`TrackingMapping` (YAML), with a rigid transform into the world frame;
  timed by receive time too, so events and tracking share one clock (the recorder's). TF
  frames (``/tf``, ``/tf_static``) are composed up to the mapping's ``root_frame`` as tf2 does
  (:mod:`rapidds.bridge.tf`) before that transform; a ROS4HRI skeleton's frames are named with
  ``{body}`` for the body id (the mapping's ``body_id``, else the first ``body_<id>`` seen).
- Or task boundaries from the cell's own signals, by the mapping's ``boundaries`` rules
  (:mod:`rapidds.bridge.boundaries`).
- The robot's ``sensor_msgs/JointState`` on ``/rapidds/robot/joint_states`` (demonstrations).
- "Too close" signals of the person on ``/rapidds/human/too_close`` (``std_msgs/Empty`` or
  ``String``), timed by receive time and taken relative to the cycle's first task start (the
  realised cycle's time 0); one outside the cycle's span is dropped.

Bad input never stops the reading: a malformed message, an unknown task id, an event out of
order (an end before its start, a second start), a tracked point whose header stamp goes back
in time, or a frame the mapping does not name is logged in one line and dropped. A human task
whose body points were not tracked through it is dropped the same way. What remains is
resampled at the world's dt: a task's path has a row at start + min(k * dt, duration) for
k = 0 .. ceil(duration / dt), the teammates' convention.
"""

from __future__ import annotations

import logging
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rapidds.bridge import ros2
from rapidds.bridge.bag import BagMessage, read_bag
from rapidds.bridge.boundaries import SignalReader
from rapidds.bridge.mapping import (
    RigidTransform,
    TrackingMapping,
    default_mapping,
    load_mapping,
)
from rapidds.bridge.tf import TfBuffer, tracked_frames
from rapidds.errors import ConfigError, RapiddsError
from rapidds.loop.observation import Observation, Said, resample, sample_times
from rapidds.worlds.base import HumanExecution, World, body_point_names
from rapidds.worlds.bounds import mostly_implausible, plausible_mask, world_task_bound

if TYPE_CHECKING:
    from rapidds.loop.cycle import Cycle

__all__ = [
    "BagSource",
    "RecordedCycle",
    "RecordedTeammate",
    "RigidTransform",
    "TrackingMapping",
    "bag_paths",
    "bind_plan",
    "default_mapping",
    "human_executions",
    "load_mapping",
    "observed_for",
    "read_cycle",
    "robot_demonstrations",
]

log = logging.getLogger("rapidds.bridge")
_NS = 1e9
_SIGNALS = frozenset({"std_msgs/msg/Empty", "std_msgs/msg/String"})
_TRACKING = frozenset({"geometry_msgs/msg/PointStamped", "geometry_msgs/msg/PoseStamped",
                       "geometry_msgs/msg/PoseArray", "tf2_msgs/msg/TFMessage"})


@dataclass
class RecordedCycle:
    """What a bag holds of one cycle: each task's (agent, start ns, end ns) and each body
    point's samples (receive times ns, positions (N, d_ws)), plus the robot's joint states."""

    tasks: dict[str, tuple[str, int, int]] = field(default_factory=dict)
    points: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    joints: tuple[np.ndarray, np.ndarray] | None = None
    signals: list[BagMessage] = field(default_factory=list)  # for rules awaiting the plan
    too_close: list[int] = field(default_factory=list)  # receive times, ns
    dropped: int = 0
    implausible: dict[str, np.ndarray] = field(default_factory=dict)  # dropped samples' ns

    def too_close_times(self) -> list[float]:
        """The "too close" signals in seconds from the cycle's first task start, those within
        the cycle's span (first start to last end); others are dropped, one line each."""
        if not self.tasks:
            return []
        t0 = min(s for _, s, _ in self.tasks.values())
        t1 = max(e for _, _, e in self.tasks.values())
        out = []
        for t in self.too_close:
            if t0 <= t <= t1:
                out.append((t - t0) / _NS)
            else:
                log.warning("a 'too close' signal at %d ns, outside the cycle (%d..%d ns); "
                            "dropped", t, t0, t1)
        return out


class _Reader:
    """Accumulates a bag's messages into a :class:`RecordedCycle`, dropping bad ones."""

    def __init__(self, world: World, mapping: TrackingMapping, where: str):
        self.world, self.mapping, self.where = world, mapping, where
        self.started: dict[str, tuple[str, int]] = {}
        self.out = RecordedCycle()
        self.samples: dict[str, list[tuple[int, np.ndarray]]] = defaultdict(list)
        self.stamps: dict[str, int] = {}
        self.joint_rows: list[tuple[int, np.ndarray]] = []
        self.unmapped: set[str] = set()
        self.tf = TfBuffer()
        self.tf_samples: list[tuple[int, str, int]] = []  # receive ns, child frame, stamp ns
        self.framed: list[tuple[int, ros2.TrackedPoint]] = []  # points in another frame
        self.signals = None if mapping.boundaries is None else SignalReader(mapping.boundaries)
        self.bad_joints = 0
        self.offsets: np.ndarray | None = None  # the driver's joint offsets (robot profile)

    def drop(self, what: str) -> None:
        log.warning("%s: %s; dropped", self.where, what)
        self.out.dropped += 1

    def event(self, m: BagMessage) -> None:
        try:
            ev = ros2.parse_event(m.msg.data)
        except ros2.MessageError as exc:
            return self.drop(f"event at {m.time_ns} ns: {exc}")
        if ev.task not in self.world.task_ids:
            return self.drop(f"event of unknown task {ev.task!r}")
        return self.task_event(ev, m.time_ns)

    def signal(self, m: BagMessage) -> None:
        """A message a boundary rule may fire on (module docstring)."""
        assert self.signals is not None
        for got in self.signals.feed(m.topic, m.msg, m.time_ns):
            if isinstance(got, str):
                self.drop(got)
            else:
                self.task_event(ros2.Event(*got), m.time_ns)  # type: ignore[arg-type]

    def task_event(self, ev: ros2.Event, time_ns: int) -> None:
        if ev.event == "start":
            if ev.task in self.started or ev.task in self.out.tasks:
                return self.drop(f"second start of task {ev.task!r}")
            self.started[ev.task] = (ev.agent, time_ns)
            return None
        agent, start = self.started.get(ev.task, (None, None))
        if start is None or agent != ev.agent:
            return self.drop(f"end of task {ev.task!r} ({ev.agent}) before its start")
        del self.started[ev.task]
        self.out.tasks[ev.task] = (ev.agent, start, time_ns)
        return None

    def transforms(self, m: BagMessage) -> None:
        """A TFMessage: every transform into the buffer; a dynamic one is also a sample of
        its child frame, composed at its stamp when the bag has been read (tf2's rule)."""
        static = m.topic.rstrip("/").endswith("tf_static")
        try:
            kept = self.tf.add_message(m.msg, static, unstamped=m.time_ns)
        except AttributeError as exc:
            return self.drop(f"{m.topic}: {exc}")
        if len(kept) < len(m.msg.transforms):
            self.drop(f"{m.topic} at {m.time_ns} ns: {len(m.msg.transforms) - len(kept)} "
                      "transform(s) not finite or with a zero quaternion")
        if not static:
            self.tf_samples += [(m.time_ns, child, stamp) for child, stamp in kept]
        return None

    def composed(self) -> None:
        """The mapped TF frames' samples, composed to the root frame (rapidds.bridge.tf), and
        the points stamped in another frame than the root: through TF where that frame's chain
        reaches the root, as they are (the tracker's frame, the mapping's transform) where the
        bag has no transform of it."""
        got, lines = tracked_frames(self.tf, self.tf_samples, self.mapping.points,
                                    self.mapping.root_frame, self.mapping.body_id,
                                    {tp.parent for _, tp in self.framed})
        for line in lines:  # each says what became of what it names
            log.warning("%s: %s", self.where, line)
            self.out.dropped += 1
        got += self.framed_points()
        got.sort(key=lambda g: g[0])
        for recv, source, stamp, p in got:
            name = self.mapping.points[source]
            if not np.isfinite(p).all():
                self.drop(f"{source!r} at {recv} ns is not finite")
            elif stamp and stamp < self.stamps.get(name, 0):
                self.drop(f"{source!r} stamped {stamp} ns, before its previous sample")
            else:
                self.stamps[name] = max(stamp, self.stamps.get(name, 0))
                self.samples[name].append(
                    (recv, self.mapping.to_world(source, p, self.world.workspace_dim)))
        for rows in self.samples.values():  # TF and other sources of one point, in time order
            rows.sort(key=lambda r: r[0])

    def framed_points(self) -> list[tuple[int, str, int, np.ndarray]]:
        """(receive ns, source, stamp ns, position) of the points in another frame."""
        by_frame: dict[str, list[tuple[int, ros2.TrackedPoint]]] = defaultdict(list)
        for recv, tp in self.framed:
            by_frame[tp.parent.lstrip("/")].append((recv, tp))
        out = []
        for frame, rows in by_frame.items():
            local = np.stack([tp.position for _, tp in rows])
            ok = np.ones(len(rows), bool)
            if frame in self.tf.links:
                if (gap := self.tf.chain(frame, self.mapping.root_frame)[1]) is not None:
                    self.drop(f"points in frame {frame!r} (its TF chain stops at {gap!r}, not "
                              f"the root frame {self.mapping.root_frame!r}), not learned")
                    continue
                stamps = np.array([tp.stamp_ns or r for r, tp in rows], np.int64)
                local, ok = self.tf.positions(frame, self.mapping.root_frame, stamps, local)
                if not ok.all():
                    self.drop(f"{int((~ok).sum())} points in frame {frame!r} stamped outside "
                              "the transforms of its chain (tf2 does not extrapolate)")
            out += [(r, tp.name, tp.stamp_ns, p)
                    for (r, tp), p, good in zip(rows, local, ok, strict=True) if good]
        return out

    def tracking(self, m: BagMessage) -> None:
        if m.msgtype == "tf2_msgs/msg/TFMessage":
            return self.transforms(m)
        try:
            points = list(ros2.tracked_points(m.msg, m.topic))
        except (ros2.MessageError, AttributeError) as exc:
            return self.drop(f"{m.topic}: {exc}")
        for tp in points:
            name = self.mapping.points.get(tp.name)
            if name is None:
                if tp.name not in self.unmapped:  # one line per source, not per message
                    self.unmapped.add(tp.name)
                    self.drop(f"{tp.name!r} is not in the mapping")
                continue
            if not np.isfinite(tp.position).all():
                self.drop(f"{tp.name!r} at {m.time_ns} ns is not finite")
                continue
            if tp.parent.lstrip("/") not in ("", self.mapping.root_frame.lstrip("/")):
                self.framed.append((m.time_ns, tp))  # through TF, once the bag is read
                continue
            if tp.stamp_ns and tp.stamp_ns < self.stamps.get(name, 0):
                self.drop(f"{tp.name!r} stamped {tp.stamp_ns} ns, before its previous sample")
                continue
            self.stamps[name] = max(tp.stamp_ns, self.stamps.get(name, 0))
            self.samples[name].append(
                (m.time_ns, self.mapping.to_world(tp.name, tp.position,
                                                  self.world.workspace_dim)))
        return None

    def _plausible(self, name: str, times: np.ndarray, pos: np.ndarray,
                   ) -> tuple[np.ndarray, np.ndarray]:
        """A body point's plausible samples (:mod:`rapidds.worlds.bounds`); the others are
        dropped in one line and kept by time, to say which tasks they made unlearnable."""
        keep, why = plausible_mask(self.world, times / _NS, pos)
        if keep.all():
            return times, pos
        self.out.implausible[name] = times[~keep]
        self.drop(f"{int((~keep).sum())} implausible sample(s) of body point {name!r} (the "
                  f"first: {why})")
        return times[keep], pos[keep]

    def joint_state(self, m: BagMessage, names: Sequence[str]) -> None:
        """A robot joint state, in the world's order and convention (world = driver -
        ``self.offsets``, the robot profile's); one line for the first that lacks the joints,
        a count after."""
        got = list(m.msg.name)
        pos = np.asarray(m.msg.position, float)
        if set(names) - set(got) or len(pos) != len(got) or not np.isfinite(pos).all():
            self.bad_joints += 1
            if self.bad_joints == 1:
                self.drop(f"joint state at {m.time_ns} ns names {', '.join(got) or 'nothing'}"
                          f" ({len(pos)} positions): not the robot's joints "
                          f"{', '.join(names)}, or not finite")
            return None
        row = pos[[got.index(n) for n in names]]
        self.joint_rows.append((m.time_ns, row if self.offsets is None else row - self.offsets))
        return None

    def finish(self) -> RecordedCycle:
        self.composed()
        for task in self.started:
            self.drop(f"task {task!r} started but never ended")
        for name, rows in self.samples.items():
            self.out.points[name] = self._plausible(
                name, np.array([t for t, _ in rows], dtype=np.int64),
                np.stack([p for _, p in rows]))
        if self.joint_rows:
            self.out.joints = (np.array([t for t, _ in self.joint_rows], dtype=np.int64),
                               np.stack([r for _, r in self.joint_rows]))
        if self.bad_joints > 1:
            self.drop(f"{self.bad_joints - 1} more joint states like it")
        return self.out


def read_cycle(path: str | Path, world: World, mapping: TrackingMapping | None = None,
               joints: Sequence[str] | None = None,
               offsets: Sequence[float] | None = None) -> RecordedCycle:
    """Events, tracked body points and (given the robot's ``joints``, as its driver names
    them, and the driver's ``offsets`` from the world's positions) joint states of the bag at
    ``path`` (module docstring)."""
    mapping = (mapping or default_mapping(world)).check(world)
    reader = _Reader(world, mapping, str(path))
    reader.offsets = None if offsets is None else np.asarray(offsets, float)
    rules = mapping.boundaries
    signals = set() if rules is None else rules.topics()
    waiting = set() if rules is None else {"/" + r.topic.lstrip("/") for r in rules.rules
                                           if r.agent in rules.unordered()}
    # one clock: the bag's receive times, in order (a bag of several files may interleave)
    for m in sorted(read_bag(path), key=lambda m: m.time_ns):
        if "/" + m.topic.lstrip("/") in signals:
            reader.signal(m)
            if "/" + m.topic.lstrip("/") in waiting:
                reader.out.signals.append(m)
        if m.topic == ros2.EVENTS_TOPIC and m.msgtype == "std_msgs/msg/String":
            reader.event(m)
        elif m.topic == ros2.TOO_CLOSE_TOPIC and m.msgtype in _SIGNALS:
            reader.out.too_close.append(m.time_ns)
        elif m.msgtype in _TRACKING:
            reader.tracking(m)
        elif joints is not None and m.msgtype == "sensor_msgs/msg/JointState":
            reader.joint_state(m, joints)
    return reader.finish()


def bind_plan(cycle: RecordedCycle, world: World, mapping: TrackingMapping,
              order: Mapping[str, Sequence[str]]) -> RecordedCycle:
    """``cycle`` with the task events of the mapping's boundary rules that waited for an order
    (an agent without ``boundaries.order``), bound to ``order`` (agent -> its tasks in the
    cycle's plan); the cycle itself when none waited."""
    rules = mapping.boundaries
    if rules is None or not rules.unordered():
        return cycle
    bound = rules.ordered({a: tuple(ts) for a, ts in order.items()})
    reader = _Reader(world, mapping, "the plan's order")
    reader.signals = SignalReader(bound, rules.unordered())
    reader.out = RecordedCycle(tasks=dict(cycle.tasks), points=cycle.points,
                               joints=cycle.joints, too_close=cycle.too_close,
                               dropped=cycle.dropped)
    for m in cycle.signals:
        reader.signal(m)
    for task in reader.started:
        reader.drop(f"task {task!r} started but never ended")
    return reader.out


def _at_ns(times_ns: np.ndarray, values: np.ndarray, at_ns: np.ndarray) -> np.ndarray:
    """The one resampler (:func:`~rapidds.loop.observation.resample`) on a bag's clock: samples
    (N, ...) at ``times_ns`` read at ``at_ns``, both taken in seconds from the first sample."""
    return resample((times_ns - times_ns[0]) / _NS, values, (at_ns - times_ns[0]) / _NS)


def _covers(times: np.ndarray, start: int, end: int, dt: float) -> bool:
    slack = dt * _NS
    return len(times) > 0 and times[0] <= start + slack and times[-1] >= end - slack


def human_executions(cycle: RecordedCycle, world: World,
                     tasks: Iterable[str] | None = None) -> dict[str, HumanExecution]:
    """task -> what the person did, for the human tasks the bag holds whole (of ``tasks`` only,
    if given): the duration between the task's events and each body point's path resampled at
    the world's dt over it (module docstring). Tasks without their body points are dropped."""
    dt, names = world.dt, body_point_names(world)
    out: dict[str, HumanExecution] = {}
    wanted = None if tasks is None else set(tasks)
    for task, (agent, start, end) in cycle.tasks.items():
        if agent != "human" or (wanted is not None and task not in wanted):
            continue
        duration = (end - start) / _NS
        if (why := _unlearnable(cycle, world, names, start, end)) is not None:
            log.warning("human task %r %s; task dropped", task, why)
            continue
        at = start + np.round(sample_times(duration, dt) * _NS).astype(np.int64)
        missing = [n for n in names if n not in cycle.points
                   or not _covers(cycle.points[n][0], start, end, dt)]
        if missing:
            log.warning("body point %r was not tracked through human task %r; task dropped",
                        missing[0], task)
            continue
        path = np.stack([_at_ns(*cycle.points[n], at) for n in names], axis=1)
        out[task] = HumanExecution(task, duration, path)
    return out


def _unlearnable(cycle: RecordedCycle, world: World, names: Sequence[str], start: int,
                 end: int) -> str | None:
    """Why a human task from ``start`` to ``end`` (ns) cannot be learned: longer than any task
    of the world, or a body point mostly implausible through it; None if it can."""
    if (end - start) / _NS > (bound := world_task_bound(world)):
        return f"took {(end - start) / _NS:.3g} s, longer than any task of this world ({bound:g} s)"
    for n in names:
        bad = cycle.implausible.get(n)
        if bad is None:
            continue
        dropped = int(((bad >= start) & (bad <= end)).sum())
        kept = int(((cycle.points[n][0] >= start) & (cycle.points[n][0] <= end)).sum())
        if dropped and mostly_implausible(kept, dropped):
            return (f"had body point {n!r} mostly implausible ({dropped} of {dropped + kept} "
                    "samples)")
    return None


def observed_for(cycle: RecordedCycle, world: World,
                 tasks: Sequence[str]) -> dict[str, HumanExecution]:
    """The observations of the plan's human ``tasks``; RapiddsError naming the first one the
    bag does not hold whole (a cycle cannot be realised without every one of them)."""
    got = human_executions(cycle, world, tasks)
    if missing := [t for t in tasks if t not in got]:
        held = ", ".join(sorted(t for t, v in cycle.tasks.items() if v[0] == "human")) or "none"
        raise RapiddsError(f"the bag holds no usable observation of human task {missing[0]!r} "
                           f"of this cycle's plan (human tasks in the bag: {held})")
    return got


@dataclass(frozen=True)
class RecordedTeammate:
    """The person of a bag, as a :class:`~rapidds.worlds.base.Teammate`: a live person whose
    truth is unknown (no plan cost against it), who did what the bag holds
    (:class:`BagSource` hands it to the loop)."""

    observed: Mapping[str, HumanExecution] = field(default_factory=dict)
    name: str = "recorded"

    def execute(self, cycle: int, tasks: Sequence[str],
                rng: np.random.Generator) -> dict[str, HumanExecution]:
        return {t: self.observed[t] for t in tasks}


@dataclass(frozen=True)
class BagSource:
    """A recorded cycle as the loop's :class:`~rapidds.loop.observation.Source`: the bag's
    human tasks, with the events of boundary rules that waited for an order bound to the
    cycle's plan, and what the person said: the operator's comfort ``answer`` (1-7; None: not
    asked) and the bag's "too close" signals."""

    recorded: RecordedCycle
    world: World
    mapping: TrackingMapping
    answer: int | None = None

    def observe(self, cycle: Cycle) -> Observation:
        schedule = cycle.best.schedule
        rules = self.mapping.boundaries
        waiting = set() if rules is None else rules.unordered()
        bound = bind_plan(self.recorded, self.world, self.mapping,
                          {a: schedule.tasks(a) for a in waiting})
        human = observed_for(bound, self.world, schedule.tasks("human"))
        too_close = tuple(self.recorded.too_close_times())
        said = None if self.answer is None and not too_close else Said(self.answer, too_close)
        events = {t: (s / _NS, e / _NS) for t, (a, s, e) in bound.tasks.items() if a == "human"}
        return Observation(human=human, events=events, said=said)


def bag_paths(path: str | Path) -> list[Path]:
    """The bags at ``path``: itself (an .mcap, .db3 or ROS 1 .bag file, or a bag folder with
    ``metadata.yaml``), or the bags directly inside a folder of them, by name."""
    path = Path(path)
    if path.is_file() or (path / "metadata.yaml").is_file():
        return [path]
    if not path.is_dir():
        raise RapiddsError(f"{path}: no such bag or folder of bags")
    found = sorted(p for p in path.iterdir()
                   if (p.is_file() and p.suffix in (".mcap", ".db3", ".bag"))
                   or (p / "metadata.yaml").is_file())
    if not found:
        raise RapiddsError(f"{path}: no bag in it (.mcap, .db3, bag folders, or ROS 1 .bag)")
    return found


def _driver_joints(bags: Sequence[Path], world: World,
                   robot: str | None) -> tuple[tuple[str, ...], np.ndarray]:
    """The driver's joint names and offsets: robot profile ``robot``'s, else those of the first
    profile (``reference`` first) whose names the bags' first joint state carries; one line
    naming what came and what was expected when it does not carry them."""
    from rapidds.bridge.profiles import PROFILES, ProfileError, robot_profile

    first = next(((b, list(m.msg.name)) for b in bags for m in read_bag(b)
                  if m.msgtype == "sensor_msgs/msg/JointState"), None)
    fitting = []
    for profile in [robot_profile(robot)] if robot is not None else PROFILES.values():
        try:
            names = profile.joint_names(world)
        except ProfileError:  # a profile of another robot
            if robot is not None:
                raise
            continue
        fitting.append((profile.name, names, profile.offset(world)))
        if first is None or set(names) <= set(first[1]):
            return names, profile.offset(world)
    assert first is not None and fitting  # "reference" fits every world
    expected = "; ".join(f"{n}: {', '.join(names)}" for n, names, _ in fitting)
    raise ProfileError(f"{first[0]}: its joint states name {', '.join(first[1]) or 'nothing'}; "
                       f"no robot profile{' ' + repr(robot) if robot else ''} of world "
                       f"{world.name} fits ({expected})")


def robot_demonstrations(path: str | Path, world: World, mapping: TrackingMapping | None = None,
                         robot: str | None = None) -> Any:
    """:class:`~rapidds.motion.demos.Demonstrations` of the robot from recorded bags: its
    ``sensor_msgs/JointState`` (named as robot profile ``robot`` names them, else as the first
    profile that fits the bag; any order, extra joints such as fingers ignored; shifted into
    the world's convention by the profile's offsets) cut into tasks by the robot's task events
    (or the ``mapping``'s boundary rules) and sampled at the world's dt from each task's start,
    held at the last pose to the world's horizon (the demonstrations' convention: a motion
    that finishes early stops moving). A task longer than the horizon is dropped."""
    from rapidds.motion.demos import Demonstrations

    if mapping is not None and mapping.boundaries is not None \
            and "robot" in mapping.boundaries.unordered():
        raise ConfigError("mapping: boundaries.order.robot is needed to cut demonstrations "
                          "(there is no plan to take the robot's order from)")
    bags = bag_paths(path)
    names, offsets = _driver_joints(bags, world, robot)
    tasks = [t.id for t in world.problem().tasks if "robot" in t.allowed]
    dt, horizon = world.dt, world.horizon
    rows, index = [], []
    for bag in bags:
        cycle = read_cycle(bag, world, mapping, joints=names, offsets=offsets)
        for task, (agent, start, end) in cycle.tasks.items():
            if agent != "robot":
                continue
            if task not in tasks:
                log.warning("%s: %r is not a robot task of %s; dropped", bag, task, world.name)
                continue
            if (end - start) / _NS > (horizon - 1) * dt + 1e-9:
                log.warning("%s: robot task %r took %.2f s, longer than the horizon (%.2f s); "
                            "dropped", bag, task, (end - start) / _NS, (horizon - 1) * dt)
                continue
            if cycle.joints is None or not _covers(cycle.joints[0], start, end, dt):
                log.warning("%s: no joint states through robot task %r; dropped", bag, task)
                continue
            at = start + np.round(np.minimum(np.arange(horizon) * dt, (end - start) / _NS)
                                  * _NS).astype(np.int64)
            rows.append(_at_ns(*cycle.joints, at))
            index.append(tasks.index(task))
    if not rows:
        raise RapiddsError(f"{path}: no robot task with joint states through it (robot start "
                           "and end events on /rapidds/events or by the mapping's boundaries, "
                           f"sensor_msgs/JointState naming {', '.join(names)})")
    if missing := [t for k, t in enumerate(tasks) if k not in index]:
        log.warning("no demonstration of robot task(s) %s: the policy will not know them",
                    ", ".join(missing))
    return Demonstrations(np.stack(rows), np.array(index), tuple(tasks))
