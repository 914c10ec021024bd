"""Time-parameterization (ruckig): a path becomes a trajectory through every row, from rest to
rest, within every limit when differenced, never faster than the path's own row timing, a
dwell kept, no joint past its rows; bad input is a TimingError line."""

from __future__ import annotations

import numpy as np
import pytest

from rapidds.motion.timing import JointLimits, TimingError, limit_excess, parameterize, row_times
from rapidds.worlds.registry import make_world

PANDA = JointLimits(lower=np.full(7, -3.0), upper=np.full(7, 3.0),
                    velocity=np.array([2.175] * 4 + [2.61] * 3),
                    acceleration=np.array([15, 7.5, 10, 12.5, 15, 20, 20.0]),
                    jerk=np.array([7500, 3750, 5000, 6250, 7500, 10000, 10000.0]))


def test_a_fast_path_is_slowed_to_the_limits_and_passes_every_row() -> None:
    rng = np.random.default_rng(3)
    # a path whose rows, at 0.15 s, ask 0.9 of the speed limit and far too much acceleration
    steps = rng.uniform(-1, 1, (40, 7)) * PANDA.velocity * 0.9 * 0.15
    path = np.cumsum(np.vstack([np.zeros(7), steps]), axis=0)
    timed = parameterize(path, 0.15, PANDA, samples_per_row=4)
    np.testing.assert_array_equal(timed.positions[::4], path)
    np.testing.assert_allclose(timed.times[::4], timed.row_times)
    np.testing.assert_allclose(timed.velocities[[0, -1]], 0.0, atol=1e-12)
    np.testing.assert_allclose(timed.accelerations[[0, -1]], 0.0, atol=1e-9)
    assert (np.diff(timed.row_times) >= 0.15 - 1e-9).all()  # never faster than the path
    assert timed.duration > 40 * 0.15  # the rows' own timing breaks the acceleration limit
    assert limit_excess(np.arange(41) * 0.15, path, PANDA)["acceleration"] > 1.0
    excess = limit_excess(timed.times, timed.positions, PANDA, timed.velocities,
                          timed.accelerations)
    assert max(excess.values()) <= 1.0, excess
    np.testing.assert_allclose(row_times(path, 0.15, PANDA), timed.row_times)


def test_a_dwell_stays_a_dwell() -> None:
    path = np.vstack([np.zeros((1, 7)), np.full((5, 7), 0.2), np.full((1, 7), 0.3)])
    timed = parameterize(path, 0.15, PANDA)
    dwell = np.diff(timed.row_times)[1:5]
    np.testing.assert_allclose(dwell, 0.15, atol=1e-9)


def test_painting_paths_stay_between_their_rows() -> None:
    world = make_world("painting")
    for task in ("mix_l", "brush"):
        for mode in ("direct", "avoidant"):
            q = world.robot_trajectory(task, mode)
            rows = q[:round(world.completion_time(task, q[None])[0] / world.dt) + 1]
            timed = parameterize(rows, world.dt, world.robot_limits, samples_per_row=8)
            for i in range(len(rows) - 1):
                seg = timed.positions[8 * i:8 * (i + 1) + 1]
                lo, hi = np.minimum(rows[i], rows[i + 1]), np.maximum(rows[i], rows[i + 1])
                assert (seg >= lo - 1e-9).all() and (seg <= hi + 1e-9).all()


@pytest.mark.parametrize(("path", "says"), [
    (np.zeros((3, 6)), "must be"), (np.full((3, 7), np.nan), "NaN")])
def test_bad_paths_are_one_line(path: np.ndarray, says: str) -> None:
    with pytest.raises(TimingError, match=says):
        parameterize(path, 0.15, PANDA)


def test_bad_limits_are_one_line() -> None:
    with pytest.raises(TimingError, match="velocity"):
        JointLimits(np.zeros(2), np.ones(2), np.array([1.0, 0.0]), np.ones(2), np.ones(2))
    with pytest.raises(TimingError, match="lower <= upper"):
        JointLimits(np.ones(2), np.zeros(2), np.ones(2), np.ones(2), np.ones(2))
