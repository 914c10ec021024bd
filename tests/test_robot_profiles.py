"""Robot profiles: names, the joint-6 offset, limits in the world's convention, lookups."""

from __future__ import annotations

import math

import numpy as np
import pytest
from cli_helpers import run_main

from rapidds.bridge.profiles import PROFILES, ProfileError, robot_profile
from rapidds.worlds.registry import make_world


@pytest.fixture(scope="module")
def painting():
    return make_world("painting")


def test_profiles_name_the_drivers_joints(painting) -> None:
    assert robot_profile("reference").joint_names(painting) == tuple(
        f"robot:panda0_joint{k}" for k in range(1, 8))
    assert robot_profile("franka-panda").joint_names(painting)[0] == "panda_joint1"
    assert robot_profile("franka-fr3").joint_names(painting)[-1] == "fr3_joint7"
    fr3 = robot_profile("franka-fr3")
    assert fr3.trajectory_topic == "/fr3_arm_controller/joint_trajectory"
    assert fr3.speed_scaling_topic == "/fr3_arm_controller/speed_scaling_input"


# Franka's published Denavit-Hartenberg table (Craig's convention: a, d, alpha per joint, then
# the flange), frankaemika/docs "Denavit-Hartenberg parameters"
_DH = ((0.0, 0.333, 0.0), (0.0, 0.0, -math.pi / 2), (0.0, 0.316, math.pi / 2),
       (0.0825, 0.0, math.pi / 2), (-0.0825, 0.384, -math.pi / 2), (0.0, 0.0, math.pi / 2),
       (0.088, 0.0, math.pi / 2), (0.0, 0.107, 0.0))


def _flange_z(q: np.ndarray) -> np.ndarray:
    """The flange's z axis in Franka's base frame, by Franka's DH table."""
    t = np.eye(4)
    for (a, d, alpha), theta in zip(_DH, [*q, 0.0], strict=True):
        ca, sa, ct, st = math.cos(alpha), math.sin(alpha), math.cos(theta), math.sin(theta)
        t = t @ np.array([[ct, -st, 0, a], [st * ca, ct * ca, -sa, -d * sa],
                          [st * sa, ct * sa, ca, d * ca], [0, 0, 0, 1]])
    return t[:3, 2]


def test_joint_six_maps_onto_frankas_convention(painting) -> None:
    """The world's rest pose points the tool straight down (motions.rest_pose); mapped by the
    profile, Franka's own kinematics (its DH table) points the flange down too, and without
    the +pi/2 on joint 6 it would be 90 degrees off."""
    panda = robot_profile("franka-panda")
    rest = painting.robot_rest()
    _names, q = panda.to_driver(painting, rest)
    assert q[5] == pytest.approx(rest[5] + math.pi / 2)
    np.testing.assert_allclose(q[[0, 1, 2, 3, 4, 6]], rest[[0, 1, 2, 3, 4, 6]])
    np.testing.assert_allclose(_flange_z(q), [0.0, 0.0, -1.0], atol=2e-3)
    assert abs(_flange_z(rest) @ [0.0, 0.0, -1.0]) < 0.1
    lim = panda.limits(painting)
    assert lim.lower[5] == pytest.approx(-0.0175 - math.pi / 2)
    assert ((rest >= lim.lower) & (rest <= lim.upper)).all()


def test_a_joint_state_round_trips_and_fingers_are_ignored(painting) -> None:
    fr3 = robot_profile("franka-fr3")
    q = painting.robot_rest()
    names, driver = fr3.to_driver(painting, q)
    got = fr3.from_driver(painting, ["fr3_finger_joint1", *reversed(names)],
                          [0.04, *driver[::-1]])
    np.testing.assert_allclose(got, q)
    with pytest.raises(ProfileError, match="missing"):
        robot_profile("reference").from_driver(painting, list(names), driver)


def test_fr3_limits_differ_from_the_pandas(painting) -> None:
    panda, fr3 = (robot_profile(n).limits(painting) for n in ("franka-panda", "franka-fr3"))
    assert fr3.velocity[1] == 1.0 and panda.velocity[1] == 2.175
    assert fr3.acceleration[1] == 10.0 and panda.acceleration[1] == 7.5
    assert fr3.jerk[0] == 5000.0 and panda.jerk[0] == 7500.0


def test_bad_names_and_mismatched_worlds_are_one_line() -> None:
    with pytest.raises(ProfileError, match="one of reference, franka-panda, franka-fr3"):
        robot_profile("ur5")
    fetch = make_world("fetch")
    assert robot_profile("reference").joint_names(fetch) == ("x", "y")
    with pytest.raises(ProfileError, match=r"maps 7 joints.*has 2"):
        robot_profile("franka-panda").joint_names(fetch)
    assert set(PROFILES) == {"reference", "franka-panda", "franka-fr3"}


@pytest.mark.parametrize("args", [
    ["deploy", "painting", "--robot", "ur5"], ["deploy", "fetch", "--robot", "franka-panda"],
    ["sim-robot", "painting", "--robot", "ur5"]])
def test_the_live_commands_refuse_a_bad_profile_before_starting(
        tmp_path, capsys: pytest.CaptureFixture[str], args: list[str]) -> None:
    extra = ["--out", str(tmp_path / "cell")] if args[0] == "deploy" else []
    code, _, err = run_main(capsys, *args, *extra)
    assert code == 2 and err.count("\n") == 1 and "robot profile" in err, err
    assert not (tmp_path / "cell").exists()
