"""The painting world: the World contract, the MuJoCo scene and its kinematics, the robot's
demonstrations, the simulated people and their mirror symmetry."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest

from rapidds.errors import ConfigError, RapiddsError
from rapidds.motion.config import DiffusionConfig
from rapidds.plots._mpl import plt
from rapidds.worlds.base import HumanExecution, SimulatedTeammate, World
from rapidds.worlds.painting import PaintingWorld
from rapidds.worlds.painting.kinematics import (
    POINT_NAMES,
    POINT_RADII,
    TOOL,
    arm_kinematics,
    mirror_joints,
    solve_ik,
)
from rapidds.worlds.painting.scene import (
    ARM_BODIES,
    SceneError,
    build_model,
    franka_assets_dir,
    load_model,
)
from rapidds.worlds.painting.teammates import (
    ARCHETYPES,
    BODY_POINTS,
    HUMAN_TASKS,
    PaintingTeammate,
    mirror_body,
    population,
)


@pytest.fixture(scope="module")
def world() -> PaintingWorld:
    return PaintingWorld(prior_people=8)


@pytest.fixture(scope="module")
def demos(world: PaintingWorld):
    return world.robot_demonstrations(6, np.random.default_rng(0))


# -- the contract -------------------------------------------------------------------------------
def test_world_contract_members(world: PaintingWorld) -> None:
    assert isinstance(world, World)
    assert world.name == "painting" and world.variant == "unconstrained"
    assert world.variants == ("unconstrained", "constrained")
    assert world.task_ids == ("prep_vise", "secure_piece", "mix_l", "mix_r", "brush")
    assert world.state_dim == 7 and world.workspace_dim == 3
    assert world.horizon % 8 == 0 and world.dt > 0
    lo, hi = world.workspace_bounds
    assert lo.shape == hi.shape == (3,) and np.all(lo < hi)
    assert 5.0 <= world.spatial_beta <= 20.0 and world.spatial_grid >= 16
    assert world.teammate_names == tuple(ARCHETYPES)
    assert set(world.views) == {"top", "side"}
    # the policy defaults are DiffusionConfig fields
    DiffusionConfig(horizon=world.horizon, state_dim=7, task_names=("mix_l", "mix_r", "brush"),
                    **world.policy_defaults)
    rest = world.robot_rest()
    assert rest.shape == (7,)
    np.testing.assert_allclose(mirror_joints(rest), rest)  # the rest pose is its own mirror
    body = world.human_rest()
    assert body.shape == (len(BODY_POINTS), 3)
    np.testing.assert_allclose(mirror_body(body), body, atol=1e-12)
    pts = world.robot_points(np.zeros((2, 3, 5, 7)))
    assert pts.shape == (2, 3, 5, len(POINT_NAMES), 3)
    for name in world.teammate_names:
        assert isinstance(world.teammate(name), SimulatedTeammate)
    fig, axes = plt.subplots(1, 2)
    for ax, view in zip(axes, ("top", "side"), strict=True):
        world.draw(ax, view)
        assert ax.patches
    plt.close(fig)
    with pytest.raises(ValueError, match="unknown view"):
        world.draw(axes[0], "front")
    policy = world.bundled_policy()
    assert policy is None or (policy / "config.json").is_file()


@pytest.mark.parametrize("variant", ["unconstrained", "constrained"])
def test_problem_tasks_agents_and_precedence(variant: str) -> None:
    w = PaintingWorld(variant=variant, prior_people=8)
    p = w.problem()
    assert p.ids == w.task_ids
    allowed = {t.id: set(t.allowed) for t in p.tasks}
    assert allowed == {"prep_vise": {"human"}, "secure_piece": {"human"}, "mix_l": {"robot"},
                       "mix_r": {"robot"}, "brush": {"human", "robot"}}
    base = {("prep_vise", "secure_piece"), ("secure_piece", "brush"), ("mix_l", "brush"),
            ("mix_r", "brush")}
    want = base | ({("mix_r", "mix_l")} if variant == "constrained" else set())
    assert set(p.precedence) == want
    assert p.objective.gamma == 12.0
    prior = w.prior()
    for t in p.tasks:
        if t.can("human"):
            d = np.asarray(prior.durations[t.id])
            assert t.human_mean == round(float(d.mean()), 2) and t.human_std > 0
        if t.can("robot"):
            # nominal duration: the time the arm takes, within its limits, to follow the
            # direct motion's path to its completion: never less than the path's own
            # completion time (row k at k * dt)
            q = w.robot_trajectory(t.id, "direct")
            rows = w.completion_time(t.id, q[None])[0]
            assert t.robot_duration == w.robot_duration(t.id, q)
            assert rows < t.robot_duration < rows * 1.25 < w.penalty
    # the brush prior sits between the fast and the slow archetype: it favours neither
    brush = p.task("brush")
    assert ARCHETYPES["left-fast"][1] < brush.human_mean < ARCHETYPES["left-slow"][1]


def test_bad_variant_teammate_and_task_are_rejected(world: PaintingWorld) -> None:
    with pytest.raises(ConfigError, match=r"PaintingWorld.variant: Input should be 'unconstrained' "
                                          r"or 'constrained' \(got 'loose'\)"):
        PaintingWorld(variant="loose")
    with pytest.raises(ValueError, match="unknown painting teammate 'left-medium'"):
        world.teammate("left-medium")
    with pytest.raises(ValueError, match="multiple of 8"):
        PaintingWorld(horizon=60)
    with pytest.raises(ValueError, match="the person's task"):
        world.completion_time("prep_vise", np.zeros((1, 64, 7)))
    with pytest.raises(ValueError, match="unknown painting task"):
        world.completion_time("mix_x", np.zeros((1, 64, 7)))
    with pytest.raises(ValueError, match="unknown painting human task"):
        world.teammate("left-fast").perform("mix_l", np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"shape \(\.\.\., H, 7\)"):
        world.completion_time("mix_l", np.zeros((1, 64, 2)))


# -- scene and kinematics ---------------------------------------------------------------------
def test_scene_holds_the_panda_the_cell_and_the_persons_mocap_bodies() -> None:
    m = load_model()
    assert m is load_model()  # compiled once per process
    assert m.nq == 9 and m.nmocap == 4
    for name in ("table_top", "vise", "workpiece", "bowl", "left_tray", "right_tray"):
        assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name) >= 0
    # left and right trays are mirror images
    lt, rt = m.geom("left_tray"), m.geom("right_tray")
    np.testing.assert_allclose(m.geom_pos[lt.id] * [-1, 1, 1], m.geom_pos[rt.id])


def test_corrupt_or_missing_assets_give_one_line_scene_errors(tmp_path: Path) -> None:
    good = franka_assets_dir()
    with pytest.raises(SceneError, match="missing"):
        build_model(assets=tmp_path)
    broken = tmp_path / "franka"
    shutil.copytree(good, broken)
    (broken / "chain.xml").write_text("<mujocoinclude><body name='x'>")
    with pytest.raises(SceneError) as err:
        build_model(assets=broken)
    assert isinstance(err.value, RapiddsError) and "\n" not in str(err.value)
    (broken / "chain.xml").write_text((good / "chain.xml").read_text())
    (broken / "meshes" / "collision" / "link3.stl").write_bytes(b"not a mesh")
    with pytest.raises(SceneError, match="cannot build the painting scene"):
        build_model(assets=broken)


def test_forward_kinematics_equals_mujoco() -> None:
    m = load_model()
    kin = arm_kinematics()
    rng = np.random.default_rng(0)
    q = rng.uniform(kin.lower, kin.upper, size=(40, 7))
    pos, rot = kin.link_frames(q)
    pts = kin.points(q)
    data = mujoco.MjData(m)
    ids = [m.body(b).id for b in ARM_BODIES]
    for i in range(len(q)):
        data.qpos[:7] = q[i]
        mujoco.mj_kinematics(m, data)
        np.testing.assert_allclose(pos[i], data.xpos[ids], atol=1e-9, rtol=0)
        np.testing.assert_allclose(rot[i], data.xmat[ids].reshape(-1, 3, 3), atol=1e-9, rtol=0)
        np.testing.assert_allclose(pts[i, -1], data.site("end_effector").xpos, atol=1e-9, rtol=0)
        for p, link in enumerate(kin.point_link):
            want = data.xpos[ids[link]] + data.xmat[ids[link]].reshape(3, 3) @ kin.point_offset[p]
            np.testing.assert_allclose(pts[i, p], want, atol=1e-9, rtol=0)
    # batched shapes
    assert kin.points(q.reshape(4, 10, 7)).shape == (4, 10, len(POINT_NAMES), 3)


def test_kept_forward_kinematics_answers_only_the_same_joints() -> None:
    """The last answer is reused for the very same joints only, and callers may write into
    what they get."""
    kin = arm_kinematics()
    q = np.random.default_rng(4).uniform(kin.lower, kin.upper, size=(5, 9, 7))
    first = kin.points(q)
    first[:] = 0.0                                   # a caller writing into its answer
    np.testing.assert_array_equal(kin.points(q.copy()), kin._points(q))
    moved = q.copy()
    moved[2, 3, 4] += 1e-9                           # one joint of one row, barely
    np.testing.assert_array_equal(kin.points(moved), kin._points(moved))
    assert not np.array_equal(kin.points(moved), kin.points(q))


def test_mirrored_joints_mirror_the_arm() -> None:
    # exact up to the model's 1.57 for pi/2 in the wrist: under a millimetre
    kin = arm_kinematics()
    q = np.random.default_rng(1).uniform(kin.lower, kin.upper, size=(30, 7))
    a, b = kin.points(q), kin.points(mirror_joints(q))
    a[..., 0] *= -1
    grip = [POINT_NAMES.index("gripper_a"), POINT_NAMES.index("gripper_b")]
    a[:, grip] = a[:, grip[::-1]]  # the two gripper sides trade places
    assert np.abs(a - b).max() < 1e-3


def test_ik_reaches_targets_and_rejects_unreachable_ones(world: PaintingWorld) -> None:
    kin = arm_kinematics()
    rest = world.robot_rest()
    for target in ((-0.3, 0.05, 0.05), (0.1, -0.05, 0.2), (0.0, 0.3, 0.1)):
        q = solve_ik(target, rest)
        assert np.linalg.norm(kin.tool(q) - target) < 1e-3
        _, rot = kin.link_frames(q)
        assert rot[7][2, 2] < -0.999  # tool pointing down
    with pytest.raises(ValueError, match="IK did not reach"):
        solve_ik((0.0, -1.2, 0.1), rest)


# -- robot motions ------------------------------------------------------------------------------
def test_demonstrations_are_executable_complete_and_cover_both_modes(world, demos) -> None:
    traj, index, names, modes = demos
    assert traj.shape == (6 * 6, world.horizon, 7) and names == ("mix_l", "mix_r", "brush")
    assert set(modes) == {"direct", "avoidant"}
    assert world.executable(traj).all()
    for i, task in enumerate(names):
        rows = index == i
        t = world.completion_time(task, traj[rows])
        assert (t < world.penalty).all()
        direct, avoidant = t[modes[rows] == "direct"], t[modes[rows] == "avoidant"]
        assert len(direct) == len(avoidant) == 6
        assert direct.max() < avoidant.min()  # the avoidant motion is the slower one
        rest = np.broadcast_to(world.robot_rest(), (int(rows.sum()), 7))
        np.testing.assert_allclose(traj[rows, 0], rest, atol=1e-12)
        np.testing.assert_allclose(traj[rows, -1], rest, atol=1e-12)
        for tr, mode in zip(traj[rows], modes[rows], strict=True):
            assert world.motion_label(task, tr) == mode
    again = world.robot_demonstrations(6, np.random.default_rng(0))
    np.testing.assert_array_equal(again.trajectories, traj)


def test_mix_r_is_the_mirror_image_of_mix_l(world: PaintingWorld) -> None:
    for mode in ("direct", "avoidant"):
        left = world.robot_points(world.robot_trajectory("mix_l", mode))
        right = world.robot_points(world.robot_trajectory("mix_r", mode))
        left[..., 0] *= -1
        assert np.abs(np.sort(left, axis=-2) - np.sort(right, axis=-2)).max() < 2e-3
        assert (world.completion_time("mix_l", world.robot_trajectory("mix_l", mode)[None])
                == world.completion_time("mix_r", world.robot_trajectory("mix_r", mode)[None]))


def test_trajectories_that_cannot_be_executed_never_complete(world: PaintingWorld) -> None:
    good = world.robot_trajectory("mix_l")
    assert world.completion_time("mix_l", good[None])[0] < world.penalty
    kin = arm_kinematics()
    bad = []
    out_of_range = good.copy()
    out_of_range[20:24, 3] = kin.upper[3] + 0.05              # joint 4 past its limit
    bad.append(out_of_range)
    jump = good.copy()
    jump[30, 0] += 0.5                                        # 3.3 rad/s for one row
    bad.append(jump)
    into_table = good.copy()
    dip = int(np.argmin(world.kinematics.tool(good)[:, 2]))
    into_table[dip - 1:dip + 2, 1] += 0.35                   # shoulder leans in: tool under 0
    bad.append(into_table)
    assert (world.kinematics.tool(into_table)[:, 2] < -0.01).any()
    assert not world.executable(np.stack(bad)).any()
    t = world.completion_time("mix_l", np.stack(bad))
    # not executable: the penalty and H * dt more, even though the goals were all visited
    np.testing.assert_allclose(t, world.penalty + world.horizon * world.dt)
    assert world.penalty == 2 * world.horizon * world.dt


def test_collisions_are_every_points_sphere_against_the_table_and_every_object(
        world: PaintingWorld) -> None:
    """Rows touching the table skip the object test; the answer is still, row by row, whether
    any point's sphere touches the table or an object the point may not enter."""
    rng = np.random.default_rng(3)
    base = np.stack([world.robot_trajectory(t, m) for t in ("mix_l", "mix_r", "brush")
                     for m in ("direct", "avoidant")])
    q = np.concatenate([base, base[rng.integers(0, 6, 30)] + rng.normal(0.0, 0.25, (30, 64, 7))])
    pts = world.kinematics.points(q)
    radius = np.broadcast_to(POINT_RADII, pts.shape[1:-1])
    boxes = world.layout.obstacles()
    open_to_tool = {"workpiece", "bowl", "left_tray", "right_tray"}
    expected = []
    for row in pts:
        touch = (row[..., 2] - radius < 0.0).any()
        for name, box in boxes.items():
            gap = np.maximum(box.lo - row, 0.0) + np.maximum(row - box.hi, 0.0)
            near = (gap * gap).sum(axis=-1) <= radius * radius
            if name in open_to_tool:
                near[..., TOOL] = False
            touch |= near.any()
        expected.append(touch)
    got = world.collides(pts)
    np.testing.assert_array_equal(got, expected)
    assert 0 < got.sum() < len(got)  # both kinds present


def test_the_penalty_grows_with_how_far_a_trajectory_stays_short(world: PaintingWorld) -> None:
    rest = np.repeat(world.robot_rest()[None], world.horizon, axis=0)  # never leaves
    other_tray = world.robot_trajectory("mix_r")   # dips into the wrong tray, visits the bowl
    backwards = world.robot_trajectory("mix_l")[::-1]  # bowl first, then the tray
    t = world.completion_time("mix_l", np.stack([rest, other_tray, backwards]))
    assert (t > world.penalty).all()
    tool = world.kinematics.tool(world.robot_rest())
    (lo1, hi1), (lo2, hi2) = world.goal_boxes("mix_l")
    gap1 = np.linalg.norm(np.maximum(lo1 - tool, 0) + np.maximum(tool - hi1, 0))
    gap2 = np.linalg.norm(np.maximum(lo2 - tool, 0) + np.maximum(tool - hi2, 0))
    # resting: short by the distance to the tray, to the bowl, and back (0 from rest)
    assert t[0] == pytest.approx(world.penalty + 100.0 * (gap1 + gap2))
    assert t[2] < t[1] < t[0]  # the nearer to done, the smaller the penalty


def test_goals_must_be_visited_in_order(world: PaintingWorld) -> None:
    good = world.robot_trajectory("mix_l")
    # bowl first, then tray: play the motion backwards
    assert world.completion_time("mix_l", good[::-1][None])[0] > world.penalty
    # brush: stroke start then stroke end
    brush = world.robot_trajectory("brush")
    t = world.completion_time("brush", brush[None])[0]
    tool = world.kinematics.tool(brush)
    (lo1, hi1), (lo2, hi2) = world.goal_boxes("brush")
    first = int(np.argmax(((tool >= lo1) & (tool <= hi1)).all(-1)))
    second = int(np.argmax(((tool >= lo2) & (tool <= hi2)).all(-1)))
    assert 0 < first < second < round(t / world.dt)


# -- people -------------------------------------------------------------------------------------
def test_teammate_paths_are_body_points_at_the_worlds_dt(world: PaintingWorld) -> None:
    person = world.teammate("left-fast")
    rng = np.random.default_rng(2)
    out = person.execute(0, list(HUMAN_TASKS), rng)
    assert set(out) == set(HUMAN_TASKS)
    rest = world.human_rest()
    for ex in out.values():
        assert isinstance(ex, HumanExecution)
        path = ex.trajectory
        assert path.shape == (math.ceil(ex.duration / world.dt - 1e-9) + 1, 4, 3)
        np.testing.assert_allclose(path[0], rest, atol=1e-12)
        np.testing.assert_allclose(path[-1], rest, atol=1e-12)
        # forearms have their length everywhere
        np.testing.assert_allclose(np.linalg.norm(path[:, 0] - path[:, 2], axis=-1),
                                   person.layout.forearm, atol=1e-9)
    # Secure Piece: the left hand goes to the left rack, next to the left tray; the right
    # hand stays within a few cm of rest
    path = person.nominal_path("secure_piece")
    rack = np.array(person.layout.left_rack.center)
    assert np.linalg.norm(path[:, 0, :2] - rack[:2], axis=-1).min() < 0.03
    assert np.linalg.norm(path[:, 1] - rest[1], axis=-1).max() < 0.06
    assert person.at(5) is person


def test_right_handed_people_are_the_mirror_images_of_left_handed_ones() -> None:
    for speed in ("fast", "slow"):
        left, right = (PaintingWorld().teammate(f"{h}-{speed}") for h in ("left", "right"))
        assert left.true_mean_durations() == right.true_mean_durations()
        for task in HUMAN_TASKS:
            d1, p1 = left.perform(task, np.random.default_rng(7))
            d2, p2 = right.perform(task, np.random.default_rng(7))
            assert d1 == d2
            np.testing.assert_array_equal(mirror_body(p1), p2)
            assert not np.allclose(p1, p2)


def test_archetypes_brush_around_the_robot_and_durations_follow_their_model() -> None:
    world = PaintingWorld(prior_people=8)
    robot = world.problem().task("brush").robot_duration
    fast, slow = world.teammate("left-fast"), world.teammate("right-slow")
    assert fast.true_mean_durations()["brush"] < robot < slow.true_mean_durations()["brush"]
    rng = np.random.default_rng(3)
    d = np.array([slow.perform("brush", rng)[0] for _ in range(400)])
    mean, sd = slow.true_mean_durations()["brush"], slow.true_std_durations()["brush"]
    assert abs(d.mean() - mean) < 4 * sd / math.sqrt(len(d))
    assert d.min() > 0.5 * mean
    with pytest.raises(ValueError, match="hand"):
        PaintingTeammate("x", hand="both")
    with pytest.raises(ValueError, match="unknown task"):
        PaintingTeammate("x", hand="left", means={"mix_l": 3.0})


def test_population_is_half_left_half_right_and_seeded() -> None:
    people = population(20, np.random.default_rng(4))
    hands = [p.hand for p in people]
    assert hands.count("left") == hands.count("right") == 10
    assert hands != sorted(hands)  # shuffled
    brush = np.array([p.means["brush"] for p in people])
    assert brush.min() < 4.0 and brush.max() > 5.5
    again = population(20, np.random.default_rng(4))
    assert [(p.hand, p.means, p.habit_seed) for p in again] == \
        [(p.hand, p.means, p.habit_seed) for p in people]
    w1, w2 = PaintingWorld(prior_people=6), PaintingWorld(prior_people=6)
    for task in HUMAN_TASKS:
        assert w1.prior().durations[task] == w2.prior().durations[task]
        for a, b in zip(w1.prior().paths[task], w2.prior().paths[task], strict=True):
            np.testing.assert_array_equal(a, b)
