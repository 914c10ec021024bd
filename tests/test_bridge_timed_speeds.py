"""The reactive monitor's and the fail-safe guard's expected robot speeds are those of the
trajectory the hub sends (the robot profile's ruckig timing), not the path's rows at dt: the
arm's limits slow a row step down, and a rest-to-rest step peaks above its row speed. The hub
parameterizes each robot task once per plan and hands the same trajectories to the dispatch,
the monitor and the guard (``LiveCell.timed``)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from rapidds.bridge.cell import CellFault, CellOptions, LiveCell
from rapidds.bridge.failsafe import planned_joint_speeds
from rapidds.bridge.live import STOP_TOPIC
from rapidds.bridge.profiles import RobotProfile, robot_profile
from rapidds.bridge.reactive import planned_speeds
from rapidds.execution.registry import execution_setting
from rapidds.motion.timing import parameterize
from rapidds.worlds.registry import make_world

TASK = "mix_l"  # a painting robot task; the synthetic paths below never complete it: all rows


def _rows_speed(world: Any, path: np.ndarray) -> tuple[np.ndarray, float]:
    """What the monitor and the guard used to expect: per joint and body point, rows dt apart."""
    joints = np.abs(np.diff(path, axis=0)).max(axis=0) / world.dt
    pts = world.robot_points(path)
    return joints, float(np.linalg.norm(np.diff(pts, axis=0), axis=-1).max() / world.dt)


def _fast_path(world: Any) -> np.ndarray:
    """From rest, joint 1 turns 0.6 rad a row (4 rad/s at dt 0.15: twice the FR3's 2 rad/s)."""
    rest = np.asarray(world.robot_rest(), float)
    path = np.repeat(rest[None], 5, axis=0)
    path[:, 0] += 0.6 * np.arange(5)
    return path


def test_a_row_step_the_arm_slows_down_is_expected_at_the_arms_speed() -> None:
    world, fr3 = make_world("painting"), robot_profile("franka-fr3")
    limits = fr3.limits(world)
    path = _fast_path(world)
    timed = {"t": parameterize(path, world.dt, limits)}
    rows_joints, rows_points = _rows_speed(world, path)
    joints = planned_joint_speeds(timed)["t"]
    assert rows_joints[0] == pytest.approx(4.0)
    assert joints[0] <= limits.velocity[0] + 1e-6  # the sent trajectory's, not 4 rad/s
    assert joints[0] > 0.9 * limits.velocity[0]  # it does reach the limit on the long turn
    np.testing.assert_allclose(joints[1:], 0.0, atol=1e-9)
    points = planned_speeds(world, timed)["t"]
    assert 0.0 < points < 0.6 * rows_points


def test_a_rest_to_rest_step_is_expected_at_its_peak_not_its_row_speed() -> None:
    """Rows at dt understate it: the arm starts and stops within the step, so it is faster than
    the step over dt in between (an unsafe bound for the monitor)."""
    world, fr3 = make_world("painting"), robot_profile("franka-fr3")
    rest = np.asarray(world.robot_rest(), float)
    path = np.stack([rest, rest + np.eye(7)[0] * 0.05])
    timed = {"t": parameterize(path, world.dt, fr3.limits(world))}
    rows_joints, rows_points = _rows_speed(world, path)
    assert planned_joint_speeds(timed)["t"][0] > 1.3 * rows_joints[0]
    assert planned_speeds(world, timed)["t"] > 1.3 * rows_points


def _cell(world: Any, profile: RobotProfile, sent: list[tuple[str, Any]]) -> LiveCell:
    run = SimpleNamespace(world=world, next_cycle=0,
                          config=SimpleNamespace(execution=execution_setting("reactive")))
    link = SimpleNamespace(faults=None, publish=lambda topic, msg: sent.append((topic, msg)))
    return LiveCell(run, link, CellOptions(), profile)  # type: ignore[arg-type]


def _plan(path: np.ndarray) -> Any:
    motion = SimpleNamespace(trajectory=path)
    return SimpleNamespace(cycle=4, best=SimpleNamespace(motions={TASK: motion}))


def test_the_hub_watches_the_trajectories_it_sends(monkeypatch: pytest.MonkeyPatch) -> None:
    world, fr3 = make_world("painting"), robot_profile("franka-fr3")
    calls: list[str] = []
    real = RobotProfile.timed

    def counted(self: RobotProfile, w: Any, task: str, path: np.ndarray) -> Any:
        calls.append(task)
        return real(self, w, task, path)

    monkeypatch.setattr(RobotProfile, "timed", counted)
    cell, plan = _cell(world, fr3, []), _plan(_fast_path(world))
    monitor = cell._monitor(plan)
    assert monitor is not None
    timed = cell.timed(plan)
    assert cell.timed(plan) is timed and calls == [TASK]  # once per plan: one owner
    assert monitor.speeds[TASK] == planned_speeds(world, timed)[TASK]
    np.testing.assert_array_equal(cell._guard.speeds[TASK], planned_joint_speeds(timed)[TASK])
    assert cell._guard.speeds[TASK][0] <= fr3.limits(world).velocity[0] + 1e-6  # rows: 4 rad/s
    cell.timed(_plan(_fast_path(world)))  # the next plan is parameterized anew
    assert calls == [TASK, TASK]


def test_a_path_the_arm_would_refuse_stops_the_cycle_before_it_is_watched() -> None:
    world, fr3 = make_world("painting"), robot_profile("franka-fr3")
    sent: list[tuple[str, Any]] = []
    path = _fast_path(world)
    path[:, 0] += 1.0  # joint 1 to 3.4 rad: past the FR3's 2.7437
    with pytest.raises(CellFault, match="leaves robot profile 'franka-fr3''s range of joint 1"):
        _cell(world, fr3, sent)._monitor(_plan(path))
    assert [t for t, _ in sent] == [STOP_TOPIC]
