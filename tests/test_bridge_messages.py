"""ROS 2 messages built by rapidds.bridge.ros2 survive CDR, and the contract's parsers refuse
what breaks it."""

from __future__ import annotations

import numpy as np
import pytest

from rapidds.bridge import ros2


def test_joint_trajectory_survives_cdr() -> None:
    q = np.linspace(0, 1, 21).reshape(3, 7)
    msg = ros2.joint_trajectory([f"j{i}" for i in range(7)], q, dt=0.1, stamp_ns=2_500_000_000)
    back = ros2.deserialize(ros2.serialize(msg), "trajectory_msgs/msg/JointTrajectory")
    names, pos, t = ros2.trajectory_positions(back)
    assert names == [f"j{i}" for i in range(7)]
    np.testing.assert_array_equal(pos, q)
    np.testing.assert_allclose(t, [0.0, 0.1, 0.2])
    assert ros2.stamp_ns(back.header) == 2_500_000_000


def test_point_cloud_fields_and_values() -> None:
    pts, cost = np.random.default_rng(0).random((5, 3)), np.arange(5.0)
    back = ros2.deserialize(ros2.serialize(ros2.point_cloud(pts, cost)),
                            "sensor_msgs/msg/PointCloud2")
    names, arr = ros2.cloud_array(back)
    assert names == ["x", "y", "z", "cost"]
    np.testing.assert_allclose(arr[:, :3], pts, rtol=1e-6)
    np.testing.assert_allclose(arr[:, 3], cost)


def test_events_round_trip_and_refusals() -> None:
    ev = ros2.Event("brush", "human", "start")
    msg = ros2.deserialize(ros2.serialize(ros2.event_message(ev)), "std_msgs/msg/String")
    assert ros2.parse_event(msg.data) == ev
    stamped = ros2.Event("brush", "robot", "end", 1_700_000_000_123_456_789)
    assert ros2.parse_event(ros2.event_message(stamped).data) == stamped
    for bad in ["not json", "[" * 5000, '{"task": "a", "agent": "dog", "event": "start"}',
                '{"task": "a", "agent": "human", "event": "start", "x": 1}',
                '{"task": "a", "agent": "human", "event": "start", "stamp_ns": 1.5}',
                '{"task": "a", "agent": "human", "event": "start", "stamp_ns": -1}']:
        with pytest.raises(ros2.MessageError):
            ros2.parse_event(bad)
    with pytest.raises(ros2.MessageError):
        ros2.deserialize(b"\x00\x01", "trajectory_msgs/msg/JointTrajectory")
    with pytest.raises(ros2.MessageError):
        ros2.string_message({"x": float("nan")})


def test_tracked_points_of_each_message_kind() -> None:
    p = ros2.point_stamped([1.0, 2.0, 3.0], stamp_ns=7)
    (tp,) = ros2.tracked_points(p, "/tracker/hand")
    assert tp.name == "/tracker/hand" and tp.stamp_ns == 7
    np.testing.assert_array_equal(tp.position, [1, 2, 3])
    assert ros2.zenoh_key("/rapidds/plan") == "rapidds/plan"
