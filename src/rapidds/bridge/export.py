"""A stored run as ROS 2 messages: each cycle's plan, robot motions, the person's paths and the
learned spatial cost, for an MCAP bag (``rapidds export``) that Foxglove and ``ros2 bag`` open.

Topics (frames: ``world``, REP-103 units; times: the cycle's realised timeline, cycle after
cycle on one clock starting at 0, with :data:`CYCLE_GAP_S` between cycles):

- ``/rapidds/plan`` (String JSON, :func:`~rapidds.bridge.ros2.plan_payload`) at the cycle's start;
- ``/rapidds/robot/trajectory`` (JointTrajectory) per robot task, sent with the plan, its
  header stamp the time the motion starts, ``time_from_start`` row k at k * dt;
- ``/rapidds/robot/joint_states`` (JointState) of the realised robot at every dt of its tasks;
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
from rapidds.store import cycle_paths
from rapidds.worlds.base import World, body_point_names, body_points, joint_names

if TYPE_CHECKING:
    from rapidds.record import CycleRecord

__all__ = ["CYCLE_GAP_S", "cost_topic", "cycle_messages", "human_task_messages", "path_topic",
           "run_messages", "tf_message"]

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


def cycle_messages(world: World, record: CycleRecord, arrays: Mapping[str, np.ndarray],
                   spatial: Any, epoch_ns: int,
                   expected: Mapping[str, np.ndarray] | None = None) -> Iterator[BagMessage]:
    """The messages of one stored cycle (module docstring), its time 0 at ``epoch_ns``.

    record, arrays: the cycle as the store holds it; spatial: the
    :class:`~rapidds.human.spatial.SpatialModel` after the cycle (None: no cost clouds);
    expected: task -> the path the person is expected to take (their latest earlier one).
    """
    dt, joints, names = world.dt, joint_names(world), body_point_names(world)
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
    robot = paths["robot"]
    human = {t: body_points(v) for t, v in paths["human"].items()}
    for task, q in robot.items():
        begin = epoch_ns + _ns(times[task][0])
        out.append(BagMessage(ros2.TRAJECTORY_TOPIC, "trajectory_msgs/msg/JointTrajectory",
                              epoch_ns, ros2.joint_trajectory(joints, q, dt, stamp_ns=begin)))
        for k, row in enumerate(q):
            at = begin + _ns(k * dt)
            out.append(BagMessage(ros2.JOINT_STATE_TOPIC, "sensor_msgs/msg/JointState", at,
                                  ros2.joint_state(joints, row, stamp_ns=at)))
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
                 spatial_of: Any, exported: Collection[int] | None = None
                 ) -> Iterator[BagMessage]:
    """The messages of several stored cycles, one after the other on the bag's clock.
    arrays_of(cycle) and spatial_of(cycle): a cycle's stored arrays and learned spatial model.
    exported: the cycles written (default: all). A task's expected path is the person's latest
    earlier path of it in the run, so cycles before the first exported one count: pass them in
    ``records`` and leave them out of ``exported``."""
    epoch, last_paths = 0, {}
    for rec in records:
        arrays = arrays_of(rec.cycle)
        if exported is None or rec.cycle in exported:
            yield from cycle_messages(world, rec, arrays, spatial_of(rec.cycle), epoch,
                                      dict(last_paths))
            epoch += _ns(rec.realised.makespan + CYCLE_GAP_S)
        last_paths.update(cycle_paths(arrays)["human"])


def export_run(store: Any, run_id: str, world: World, out: Any,
               cycles: list[int] | None = None) -> tuple[Any, int]:
    """Write the stored cycles ``cycles`` (default: all) of run ``run_id`` in ``store`` (a
    :class:`~rapidds.store.RunStore`) to the MCAP file ``out``; (path, messages written)."""
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

    def spatial_of(cycle: int) -> Any:
        state = store.state(run_id, cycle)
        return None if state is None else HumanModel.from_bytes(state).spatial

    count = 0

    def counted() -> Iterator[BagMessage]:
        nonlocal count
        for m in run_messages(world, chosen, lambda c: store.arrays(run_id, c), spatial_of,
                              wanted):
            count += 1
            yield m

    return write_bag(out, counted()), count
