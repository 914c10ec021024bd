"""What the hub sends a robot over the live link: each trajectory of a fetch and a painting plan,
received by a plain Zenoh subscriber and decoded by mcap-ros2-support's CDR decoder (not the
library that wrote it), is cut to its task, in the profile's joint names, with velocities and
accelerations in every point, and differenced stays within the profile's limits."""

from __future__ import annotations

import contextlib
import json
import queue
import time
from typing import Any

import numpy as np
import pytest
from test_bridge_live import free_endpoint

from rapidds.bridge import ros2
from rapidds.bridge.cell import CellOptions, LiveCell, hub_topics
from rapidds.bridge.link import Link, StampGate
from rapidds.bridge.live import CycleObservation
from rapidds.bridge.profiles import robot_profile
from rapidds.loop.config import RunConfig
from rapidds.loop.run import AdaptiveRun
from rapidds.motion.timing import limit_excess
from rapidds.worlds.base import body_point_names
from rapidds.worlds.registry import make_world

SMALL = {"cycles": 1, "population": 4, "generations": 2, "samples": 8, "particles": 2,
         "candidates": 2}
TRAJ = "trajectory_msgs/msg/JointTrajectory"


def _decoder() -> Any:
    """mcap-ros2-support's decoder of JointTrajectory CDR, from the message definition."""
    from mcap_ros2._dynamic import generate_dynamic

    text, _ = ros2.typestore().generate_msgdef(TRAJ, ros_version=2)
    return generate_dynamic(TRAJ, text)[TRAJ]


def _sent(world_name: str, profile_name: str) -> tuple[Any, list[Any], list[str]]:
    import torch
    import zenoh

    torch.set_num_threads(1)
    world = make_world(world_name)
    run = AdaptiveRun(RunConfig(world=world_name, **SMALL), world=world)
    plan = run.plan()
    ep = free_endpoint()
    got: queue.Queue[bytes] = queue.Queue()
    with Link(hub_topics(body_point_names(world)), listen=ep) as link:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("connect/endpoints", json.dumps([ep]))
        with zenoh.open(conf) as robot:
            robot.declare_subscriber(ros2.zenoh_key(ros2.TRAJECTORY_TOPIC),
                                     lambda s: got.put(s.payload.to_bytes()))
            time.sleep(0.5)  # the subscription reaches the hub
            cell = LiveCell(run, link, CellOptions(lead=0.0), robot_profile(profile_name))
            live = cell._publish_plan(plan)
            obs = CycleObservation(live, cell.points, gate=StampGate())
            obs.end.update({t: 0.0 for t in live.agent})  # every prerequisite has ended
            sent: set[str] = set()
            while time.time_ns() < live.stamp_ns:
                time.sleep(0.01)
            cell._dispatch(plan, live, obs, sent)
            order = list(live.order["robot"])
            decode, msgs = _decoder(), []
            deadline = time.monotonic() + 10
            while len(msgs) < len(order) and time.monotonic() < deadline:
                with contextlib.suppress(queue.Empty):
                    msgs.append(decode(got.get(timeout=0.2)))
    return world, msgs, order


@pytest.mark.parametrize(("world_name", "profile_name"), [
    ("fetch", "reference"), ("painting", "reference"), ("painting", "franka-fr3")])
def test_sent_trajectories_stay_within_the_profiles_limits(world_name: str,
                                                           profile_name: str) -> None:
    world, msgs, order = _sent(world_name, profile_name)
    profile = robot_profile(profile_name)
    limits, offset = profile.limits(world), profile.offset(world)
    assert len(msgs) == len(order) > 0
    for msg in msgs:
        assert list(msg.joint_names) == list(profile.joint_names(world))
        t = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9
                      for p in msg.points])
        q = np.array([p.positions for p in msg.points]) - offset
        v = np.array([p.velocities for p in msg.points])
        a = np.array([p.accelerations for p in msg.points])
        assert v.shape == a.shape == q.shape
        excess = limit_excess(t, q, limits, v, a)
        assert max(excess.values()) <= 1.0 + 1e-6, excess
        # cut to its task: far fewer rows than the horizon's, times 3 samples per row
        assert len(q) < 3 * (world.horizon - 1) + 1
