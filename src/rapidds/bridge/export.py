"""A stored run as ROS 2 messages: each cycle's plan, robot motions, the person's paths and the
learned spatial cost, for an MCAP bag (``rapidds export``) that Foxglove and ``ros2 bag`` open,
and that ``ros2 bag play`` replays into a joint trajectory controller.

Clock: the run's recorded wall clock (the store's time the run was started) or ``--epoch``;
cycle after cycle, each cycle's realised timeline, with :data:`CYCLE_GAP_S` between cycles.
Robot joints: as the robot profile (``--robot``, :mod:`rapidds.bridge.profiles`) names and
zeroes them; every trajectory is cut to its task and time-parameterized within the profile's
limits (:mod:`rapidds.motion.timing`), velocities and accelerations in every point.
Frames: ``world``, REP-103 units.

Topics:

- ``/rapidds/plan`` (String JSON, :func:`~rapidds.bridge.ros2.plan_payload`) at the cycle's start;
- ``/rapidds/robot/trajectory`` (JointTrajectory) per robot task, sent with the plan, its
  header stamp the time the motion starts;
- ``/<controller>/joint_trajectory`` (the profile's controller topic): the same trajectory at
  its task's start, header stamp 0 ("start now"), so ``ros2 bag play`` drives a joint
  trajectory controller through the plan;
- ``/rapidds/robot/joint_states`` (JointState): one stream, the robot at every dt of each robot
  task, from its start to its realised end, stamps strictly increasing: along the
  parameterized trajectory where the planner timed the robot by it (the painting arm), else
  along the path at its own row timing (fetch, whose planner keeps it);
- ``/rapidds/events`` (String JSON) each task's start and end, as a real cell reports them;
- ``/tf`` (TFMessage): the person's realised body points at every dt of their tasks, child
  frames the world's body-point names: the tracking contract of ``rapidds observe``, so an
  exported cycle can be observed again;
- ``/rapidds/human/realised/<body point>`` and ``/rapidds/human/expected/<body point>``
  (nav_msgs/Path) per human task: the path done, and the one expected (what the person did
  on that task the latest earlier cycle they did it; none before);
- ``/rapidds/human/cost/<task>`` (PointCloud2, fields x, y, z, cost) at the cycle's end: the
  learned spatial cost of each human task on the model's grid after learning.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from rapidds.bridge import ros2
from rapidds.bridge.bag import BagMessage
from rapidds.bridge.profiles import DEFAULT_PROFILE, RobotProfile, robot_profile, task_rows
from rapidds.store import cycle_paths
from rapidds.worlds.base import World, body_point_names, body_points
from rapidds.worlds.capabilities import capability

if TYPE_CHECKING:
    from rapidds.motion.timing import TimedTrajectory
    from rapidds.record import CycleRecord

__all__ = ["CYCLE_GAP_S", "cost_topic", "cycle_messages", "export_run", "human_task_messages",
           "parse_epoch", "path_topic", "robot_messages", "run_messages", "tf_message"]

CYCLE_GAP_S = 1.0
"""Seconds between one exported cycle's end and the next one's start on the bag's clock."""
_NS = 1_000_000_000


def cost_topic(task: str) -> str:
    """The spatial-cost topic of a task (a task id made a valid ROS 2 name token)."""
    token = re.sub(r"[^A-Za-z0-9_]", "_", task)
    return f"/rapidds/human/cost/{token if token[:1].isalpha() else 't' + token}"


def path_topic(kind: str, point: str) -> str:
    """``/rapidds/human/{realised|expected}/<body point>``."""
    return f"/rapidds/human/{kind}/{re.sub(r'[^A-Za-z0-9_]', '_', point)}"


def _ns(seconds: float) -> int:
    return round(seconds * _NS)


def _iso_seconds(text: str) -> float:
    from datetime import datetime

    from rapidds.errors import RapiddsError

    try:
        when = datetime.fromisoformat(text)
    except ValueError:
        raise RapiddsError(f"--epoch {text!r} is neither Unix seconds nor an ISO 8601 time "
                           "(2026-11-27T06:00:00Z)") from None
    if when.tzinfo is None:
        raise RapiddsError(f"--epoch {text!r} has no time zone; add Z or +HH:MM")
    return when.timestamp()


def parse_epoch(text: str) -> int:
    """``--epoch``: Unix seconds (``1764223200.5``) or an ISO 8601 time with its zone
    (``2026-11-27T06:00:00Z``) -> nanoseconds since 1970 UTC; a :class:`RapiddsError` line
    otherwise."""
    from rapidds.errors import RapiddsError

    try:
        seconds = float(text)
    except ValueError:
        seconds = _iso_seconds(text)
    if not (np.isfinite(seconds) and seconds >= 0):
        raise RapiddsError(f"--epoch {text!r} must be a time after 1970")
    return _ns(seconds)


def _xyz(p: np.ndarray) -> np.ndarray:
    """A workspace point as (x, y, z); a 2-D workspace lies at z = 0."""
    p = np.asarray(p, dtype=float)
    return np.concatenate([p, np.zeros(3 - p.shape[-1])]) if p.shape[-1] < 3 else p


def _row_times(duration: float, rows: int, dt: float) -> np.ndarray:
    """Seconds after a task's start of its path's rows: k * dt, none after its end (the
    teammates' convention, :meth:`~rapidds.worlds.base.SimulatedTeammate.perform`)."""
    return np.minimum(np.arange(rows) * dt, duration)


def _path_msg(points: np.ndarray, start_ns: int, times: np.ndarray) -> Any:
    t = ros2.typestore().types
    poses = [t["geometry_msgs/msg/PoseStamped"](
        header=ros2.header(start_ns + _ns(s)),
        pose=t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z)),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
        for s, (x, y, z) in zip(times, (_xyz(p) for p in points), strict=True)]
    return t["nav_msgs/msg/Path"](header=ros2.header(start_ns), poses=poses)


def tf_message(names: tuple[str, ...], points: np.ndarray, stamp: int,
               parent: str = "world") -> Any:
    """``tf2_msgs/msg/TFMessage``: frame ``names[k]`` at ``points[k]`` in ``parent``."""
    t = ros2.typestore().types
    return t["tf2_msgs/msg/TFMessage"](transforms=[t["geometry_msgs/msg/TransformStamped"](
        header=ros2.header(stamp, parent), child_frame_id=name,
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z)),
            rotation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
        for name, (x, y, z) in zip(names, (_xyz(p) for p in points), strict=True)])


def _event(task: str, agent: str, kind: str, at: int) -> BagMessage:
    ev = ros2.Event(task, agent, kind)  # type: ignore[arg-type]
    return BagMessage(ros2.EVENTS_TOPIC, "std_msgs/msg/String", at, ros2.event_message(ev))


def human_task_messages(world: World, task: str, path: np.ndarray, duration: float,
                        start_ns: int) -> list[BagMessage]:
    """One human task as a real cell reports it (the contract of ``rapidds observe``): its
    start and end on ``/rapidds/events`` and the body points of ``path`` (T, K, d_ws), rows at
    start + min(k * dt, duration), on ``/tf`` under the world's body-point names."""
    names, path = body_point_names(world), body_points(path)
    end = start_ns + _ns(duration)
    out = [_event(task, "human", "start", start_ns), _event(task, "human", "end", end)]
    for s, row in zip(_row_times(duration, len(path), world.dt), path, strict=True):
        at = start_ns + _ns(s)
        out.append(BagMessage("/tf", "tf2_msgs/msg/TFMessage", at, tf_message(names, row, at)))
    return sorted(out, key=lambda m: m.time_ns)


def _states(world: World, task: str, path: np.ndarray, timed: TimedTrajectory,
            length: float) -> Iterator[tuple[float, np.ndarray, np.ndarray | None]]:
    """(seconds after the task's start, positions, velocities or None) every dt for ``length``
    s: the robot as it was timed in the record. A world whose planner times its robot by the
    parameterized trajectory (its ``robot_duration``, the arm) moves along it, its last row
    held after (a slower realised task waited under the monitor's scaling); a world that keeps
    its own row timing (fetch) is at row k at k * dt."""
    dt = world.dt
    if capability(world, "robot_timing") is None:
        rows = task_rows(world, task, path)
        for s in np.arange(0.0, length - 1e-9, dt):
            yield float(s), rows[min(round(s / dt), len(rows) - 1)], None
        return
    for s in np.arange(0.0, length - 1e-9, dt):
        at = min(s, timed.duration)
        q = np.array([np.interp(at, timed.times, c) for c in timed.positions.T])
        v = np.array([np.interp(at, timed.times, c) for c in timed.velocities.T])
        yield float(s), q, (v if s < timed.duration else np.zeros_like(v))


def robot_messages(world: World, profile: RobotProfile, robot: Mapping[str, np.ndarray],
                   times: Mapping[str, tuple[float, float]], epoch_ns: int,
                   sent_ns: int) -> list[BagMessage]:
    """The robot's part of a cycle: per task (in its realised order) its parameterized
    trajectory (with the plan at ``sent_ns``, and on the controller's topic at its start) and
    its joint states up to its realised end, one stream with strictly increasing stamps."""
    out: list[BagMessage] = []
    last = -1
    traj_type = "trajectory_msgs/msg/JointTrajectory"
    for task in sorted(robot, key=lambda t: times[t][0]):
        start, end = times[task]
        begin = epoch_ns + _ns(start)
        timed = profile.timed(world, task, robot[task])
        out.append(BagMessage(ros2.TRAJECTORY_TOPIC, traj_type, sent_ns,
                              profile.trajectory(world, timed, stamp_ns=begin)))
        out.append(BagMessage(profile.trajectory_topic, traj_type, begin,
                              profile.trajectory(world, timed)))
        for s, q, v in _states(world, task, robot[task], timed, end - start):
            at = begin + _ns(s)
            if at <= last:
                continue  # a task that started before the last one's states ended
            names, driver = profile.to_driver(world, q)
            out.append(BagMessage(ros2.JOINT_STATE_TOPIC, "sensor_msgs/msg/JointState", at,
                                  ros2.joint_state(names, driver, v, stamp_ns=at)))
            last = at
    return out


def cycle_messages(world: World, record: CycleRecord, arrays: Mapping[str, np.ndarray],
                   spatial: Any, epoch_ns: int,
                   expected: Mapping[str, np.ndarray] | None = None,
                   profile: RobotProfile | None = None) -> Iterator[BagMessage]:
    """The messages of one stored cycle (module docstring), its time 0 at ``epoch_ns``.

    record, arrays: the cycle as the store holds it; spatial: the
    :class:`~rapidds.human.spatial.SpatialModel` after the cycle (None: no cost clouds);
    expected: task -> the path the person is expected to take (their latest earlier one);
    profile: the robot's driver (default: the reference profile).
    """
    profile = profile or robot_profile(DEFAULT_PROFILE)
    dt, names = world.dt, body_point_names(world)
    times = record.realised.timeline
    plan = ros2.plan_payload(record.cycle, record.plan.human, record.plan.robot, times)
    agent_of = {t: a for a in ("human", "robot") for t in plan["order"][a]}
    out = [BagMessage(ros2.PLAN_TOPIC, "std_msgs/msg/String", epoch_ns,
                      ros2.string_message(plan))]
    for task, (start, end) in times.items():
        if task in agent_of:
            out += [_event(task, agent_of[task], "start", epoch_ns + _ns(start)),
                    _event(task, agent_of[task], "end", epoch_ns + _ns(end))]
    paths = cycle_paths(arrays)
    out += robot_messages(world, profile, paths["robot"], times, epoch_ns, epoch_ns)
    human = {t: body_points(v) for t, v in paths["human"].items()}
    for task, path in human.items():
        start, end = times[task]
        begin = epoch_ns + _ns(start)
        rel = _row_times(end - start, len(path), dt)
        out += [m for m in human_task_messages(world, task, path, end - start, begin)
                if m.topic == "/tf"]
        for k, name in enumerate(names):
            out.append(BagMessage(path_topic("realised", name), "nav_msgs/msg/Path", begin,
                                  _path_msg(path[:, k], begin, rel)))
            if expected and task in expected:
                exp = body_points(expected[task])
                out.append(BagMessage(path_topic("expected", name), "nav_msgs/msg/Path", begin,
                                      _path_msg(exp[:, k], begin, np.arange(len(exp)) * dt)))
    if spatial is not None:
        at = epoch_ns + _ns(record.realised.makespan)
        for task in spatial.tasks:
            m = spatial[task]
            out.append(BagMessage(cost_topic(task), "sensor_msgs/msg/PointCloud2", at,
                                  ros2.point_cloud(m.grid_points, m.mean, stamp_ns=at)))
    # one clock: a reader that replays the bag in receive order sees the cycle as it happened
    yield from sorted(out, key=lambda m: m.time_ns)


def run_messages(world: World, records: Sequence[CycleRecord], arrays_of: Any,
                 spatial_of: Any, exported: Collection[int] | None = None, epoch_ns: int = 0,
                 profile: RobotProfile | None = None) -> Iterator[BagMessage]:
    """The messages of several stored cycles, one after the other on the bag's clock from
    ``epoch_ns``. arrays_of(cycle) and spatial_of(cycle): a cycle's stored arrays and learned
    spatial model. exported: the cycles written (default: all). A task's expected path is the
    person's latest earlier path of it in the run, so cycles before the first exported one
    count: pass them in ``records`` and leave them out of ``exported``."""
    epoch, last_paths = epoch_ns, {}
    for rec in records:
        arrays = arrays_of(rec.cycle)
        if exported is None or rec.cycle in exported:
            yield from cycle_messages(world, rec, arrays, spatial_of(rec.cycle), epoch,
                                      dict(last_paths), profile)
            epoch += _ns(rec.realised.makespan + CYCLE_GAP_S)
        last_paths.update(cycle_paths(arrays)["human"])


def export_run(store: Any, run_id: str, world: World, out: Any,
               cycles: list[int] | None = None, epoch_ns: int | None = None,
               profile: RobotProfile | None = None) -> tuple[Any, int]:
    """Write the stored cycles ``cycles`` (default: all) of run ``run_id`` in ``store`` (a
    :class:`~rapidds.store.RunStore`) to the MCAP file ``out``; (path, messages written).
    epoch_ns: the bag's time of the first written cycle's start (default: the run's recorded
    wall-clock start); profile: the robot's driver (default: the reference profile)."""
    from rapidds.bridge.bag import write_bag
    from rapidds.errors import RapiddsError
    from rapidds.loop.model import HumanModel

    records = store.cycle_records(run_id)
    have = [r.cycle for r in records]
    if not records:
        raise RapiddsError(f"run '{run_id}' in {store.path} has no stored cycle")
    wanted = set(have if cycles is None else cycles)
    if missing := sorted(wanted - set(have)):
        raise RapiddsError(f"run '{run_id}' has no cycle {missing[0]} (stored: "
                           f"{have[0]}..{have[-1]})")
    last = max(wanted)
    chosen = [r for r in records if r.cycle <= last]
    if epoch_ns is None:
        epoch_ns = _ns(store.run_created(run_id) or 0.0)
    profile = profile or robot_profile(DEFAULT_PROFILE)
    profile.joint_names(world)  # a profile that does not fit the world: one line, nothing written

    def spatial_of(cycle: int) -> Any:
        state = store.state(run_id, cycle)
        return None if state is None else HumanModel.from_bytes(state).spatial

    count = 0

    def counted() -> Iterator[BagMessage]:
        nonlocal count
        for m in run_messages(world, chosen, lambda c: store.arrays(run_id, c), spatial_of,
                              wanted, epoch_ns, profile):
            count += 1
            yield m

    return write_bag(out, counted()), count
