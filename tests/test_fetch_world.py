"""Fetch world and simulated teammates: geometry, conventions and the properties the
experiments rely on (middle routes clash, outside routes avoid, durations vary by person)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rapidds.errors import ConfigError
from rapidds.worlds.base import SimulatedTeammate, World
from rapidds.worlds.fetch import (
    ARCHETYPES,
    MODES,
    FetchTeammate,
    FetchWorld,
    archetype,
    fetch_problem,
    population,
)
from rapidds.worlds.geometry import Rect, reach_then_return_time, segments_hit_rects

CORRIDOR = (4.2, 5.8, 2.4, 5.2)  # x0, x1, y0, y1 of the central corridor between the blocks


@pytest.fixture()
def world(fetch_world: FetchWorld) -> FetchWorld:
    return fetch_world


def _in_box(p: np.ndarray, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    return (p[:, 0] > x0) & (p[:, 0] < x1) & (p[:, 1] > y0) & (p[:, 1] < y1)


def _synced_min(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest distance between two (T, 2) walks at equal times; the shorter one is padded
    with its last row (the agent waits at home)."""
    n = max(len(a), len(b))
    a = np.vstack([a, np.repeat(a[-1:], n - len(a), axis=0)])
    b = np.vstack([b, np.repeat(b[-1:], n - len(b), axis=0)])
    return float(np.linalg.norm(a - b, axis=1).min())


# -- problem ----------------------------------------------------------------------------------
def test_problem_is_the_papers_fetch_job(world: FetchWorld) -> None:
    p = world.problem()
    assert p.ids == ("t0", "t1", "t2", "t3")
    assert set(p.precedence) == {("t2", "t0"), ("t2", "t1"), ("t3", "t0"), ("t3", "t1")}
    assert p.objective.gamma == 1.75
    for t in p.tasks:
        assert t.allowed == {"human", "robot"}
        assert t.human_mean is not None and t.human_std is not None
        assert t.human_mean > 0 and t.human_std > 0
        # Robot nominal duration: the default (shortest) route's completion time.
        nominal = world.completion_time(t.id, world.robot_trajectory(t.id)[None])[0]
        assert t.robot_duration == nominal
        # Human and robot durations of the same order, so allocation matters.
        assert t.robot_duration is not None and 0.3 < t.human_mean / t.robot_duration < 3.0
    assert fetch_problem() == FetchWorld().problem()


def test_world_protocol_and_config(world: FetchWorld) -> None:
    assert isinstance(world, World)
    assert isinstance(world.teammate("slow-middle"), SimulatedTeammate)
    with pytest.raises(ConfigError, match=r"FetchWorld.variant: .*\(got 'constrained'\)"):
        FetchWorld(variant="constrained")
    assert world.horizon % 8 == 0 and world.state_dim == 2
    lo, hi = world.bounds
    assert lo.shape == hi.shape == (2,) and np.all(lo < hi)
    np.testing.assert_array_equal(world.robot_start("t2"), world.home("robot"))
    assert len(world.obstacles()) == 4 and all(isinstance(r, Rect) for r in world.obstacles())
    poi = world.points_of_interest()
    assert {"human home", "robot home", "t0", "t1", "t2", "t3"} <= set(poi)
    with pytest.raises(ConfigError, match=r"FetchWorld.horizon: .*multiple of 8 \(got 60\)"):
        FetchWorld(horizon=60)
    with pytest.raises(ConfigError, match="FetchWorld: horizon \\* dt = 8 s is too short"):
        FetchWorld(horizon=40)
    for bad in ({"dt": True}, {"robot_speed": math.inf}, {"prior_people": 1}, {"lam": -1.0}):
        with pytest.raises(ConfigError, match=f"FetchWorld.{next(iter(bad))}: "):
            FetchWorld(**bad)
    with pytest.raises(ValueError, match="unknown fetch task"):
        world.completion_time("t9", np.zeros((1, 64, 2)))
    with pytest.raises(ValueError, match="no route"):
        world.route("robot", "t0", "middle")


# -- geometry ---------------------------------------------------------------------------------
def test_nominal_routes_are_collision_free_at_any_reasonable_speed(world: FetchWorld) -> None:
    for agent in ("human", "robot"):
        for task, modes in MODES.items():
            for mode in modes:
                for speed in (1.5, 2.6, 4.0, 5.5):
                    traj = world.trajectory(agent, task, mode, speed=speed, n_steps=200)
                    assert not world.collides(traj), (agent, task, mode, speed)


def test_middle_is_shorter_than_outside_for_both_agents(world: FetchWorld) -> None:
    for agent in ("human", "robot"):
        for task in ("t2", "t3"):
            mid = world.route(agent, task, "middle").length
            out = world.route(agent, task, "outside").length
            assert mid < out, (agent, task)
    for task in ("t2", "t3"):
        d = {m: world.completion_time(task, world.robot_trajectory(task, m)[None])[0]
             for m in ("middle", "outside")}
        assert d["middle"] < d["outside"]
    # On its own side (t3) the robot's outside route costs 20-40 % more time and less than
    # gamma = 1.75 s: a certain clash can justify it, a mere possibility cannot.
    mid, out = (world.completion_time("t3", world.robot_trajectory("t3", m)[None])[0]
                for m in ("middle", "outside"))
    assert 1.2 <= out / mid <= 1.4
    assert 0.5 < out - mid < 1.75


def test_concurrent_middle_routes_meet_and_outside_routes_keep_away(world: FetchWorld) -> None:
    n = 150
    robot = {m: world.trajectory("robot", "t3", m, n_steps=n) for m in ("middle", "outside")}
    # Same speed: the two middle routes meet in the corridor.
    same = world.trajectory("human", "t2", "middle", speed=world.robot_speed, n_steps=n)
    assert _synced_min(same, robot["middle"]) < 0.5
    fast = world.trajectory("human", "t2", "middle", speed=4.8, n_steps=n)
    assert _synced_min(fast, robot["middle"]) < 1.0
    # Middle vs the other agent's outside route: > 3 m at every time, for any human speed.
    for speed in np.linspace(2.0, 5.5, 15):
        h = {m: world.trajectory("human", "t2", m, speed=speed, n_steps=n)
             for m in ("middle", "outside")}
        assert _synced_min(h["middle"], robot["outside"]) > 3.0, speed
        assert _synced_min(h["outside"], robot["middle"]) > 3.0, speed
    # The crossed pairing (each agent on the other's side): middle routes still meet, and the
    # far outside route keeps > 3 m from the other agent while that agent is away from home.
    hm = world.trajectory("human", "t3", "middle", n_steps=n)
    assert _synced_min(hm, world.trajectory("robot", "t2", "middle", n_steps=n)) < 0.5
    ro = world.trajectory("robot", "t2", "outside", n_steps=n)
    away = np.linalg.norm(hm - world.home("human"), axis=1) > world.reach_radius
    assert np.linalg.norm(hm - ro, axis=1)[away].min() > 3.0


def test_segments_hit_rects_checks_whole_segments() -> None:
    wall = np.array([[1.0, 0.0, 1.2, 2.0]])
    jump = np.array([[0.0, 1.0], [2.0, 1.0]])  # both ends outside, the segment crosses
    beside = np.array([[0.0, 3.0], [2.0, 3.0]])
    vertical_in = np.array([[1.1, -1.0], [1.1, 3.0]])  # parallel to y, inside the x slab
    vertical_out = np.array([[1.5, -1.0], [1.5, 3.0]])
    hits = segments_hit_rects(np.stack([jump, beside, vertical_in, vertical_out]), wall)
    np.testing.assert_array_equal(hits, [True, False, True, False])
    near = np.array([[0.0, 2.1], [2.0, 2.1]])
    assert not segments_hit_rects(near, wall)
    assert segments_hit_rects(near, wall, margin=0.2)
    assert segments_hit_rects(near, (Rect(0.5, 2.0, 0.6, 2.2),))


# -- completion time --------------------------------------------------------------------------
def test_completion_time_convention_on_hand_made_paths(world: FetchWorld) -> None:
    h = world.horizon
    home, obj = world.home("robot"), world.object_position("t1")
    via = np.array([home[0], obj[1]])  # straight up from home, then across: clear of the fence
    out = np.vstack([np.linspace(home, via, 4), np.linspace(via, obj, 3)[1:]])
    out_and_back = np.vstack([out, out[::-1][1:]])
    k = len(out_and_back) - 1  # the row at which it is back home
    returns = np.vstack([out_and_back, np.repeat(home[None], h - len(out_and_back), axis=0)])
    never_back = np.vstack([out, np.repeat(obj[None], h - len(out), axis=0)])
    stays_home = np.repeat(home[None], h, axis=0)
    late = np.vstack([np.repeat(home[None], 7, axis=0), returns[: h - 7]])  # starts 7 rows late
    times = world.completion_time("t1", np.stack([returns, never_back, stays_home, late]))
    # Row k is the pose at time k * dt: a path back home at row k has finished at k * dt.
    assert times[0] == pytest.approx(k * world.dt)
    assert times[1] == world.penalty == 2 * h * world.dt
    assert times[2] == world.penalty  # being home without the object does not count
    assert times[3] == pytest.approx((k + 7) * world.dt)
    # Reaching the wrong object does not complete the task.
    assert world.completion_time("t0", returns[None])[0] == world.penalty
    # Neither does a path through a wall: the straight line home -> t1 cuts the right fence.
    direct = np.vstack([np.linspace(home, obj, 6), np.linspace(obj, home, 6)[1:]])
    direct = np.vstack([direct, np.repeat(home[None], h - len(direct), axis=0)])
    assert world.collides(direct[None])[0]
    assert world.completion_time("t1", direct[None])[0] == world.penalty
    # Any leading shape.
    batch = np.broadcast_to(returns, (2, 3, h, 2))
    assert world.completion_time("t1", batch).shape == (2, 3)


def test_reach_then_return_time_needs_the_goal_first() -> None:
    goal, home = np.array([5.0, 0.0]), np.array([0.0, 0.0])
    path = np.array([[0.0, 0.0], [2.5, 0.0], [0.0, 0.0], [5.0, 0.0], [2.5, 0.0], [0.0, 0.0]])
    t = reach_then_return_time(path, goal, home, radius=0.5, dt=0.5, penalty=99.0)
    assert t == 2.5  # home at rows 0 and 2 come before the goal (row 3); row 5 counts


# -- robot demonstrations ---------------------------------------------------------------------
def test_demonstrations_cover_every_mode_complete_and_avoid_walls(world: FetchWorld) -> None:
    demos = world.robot_demonstrations(25, np.random.default_rng(3))
    traj, idx, names, modes = demos
    assert names == world.task_ids
    assert traj.shape == (6 * 25, world.horizon, 2) and idx.shape == modes.shape == (150,)
    for i, task in enumerate(names):
        assert set(modes[idx == i]) == set(MODES[task])
    np.testing.assert_allclose(traj[:, 0], np.broadcast_to(world.home("robot"), (150, 2)))
    assert not world.collides(traj).any()
    for i, task in enumerate(names):
        for mode in MODES[task]:
            sel = (idx == i) & (modes == mode)
            t = world.completion_time(task, traj[sel])
            assert np.all(np.isfinite(t)) and np.all(t < world.penalty)
            nominal = world.completion_time(task, world.robot_trajectory(task, mode)[None])[0]
            assert np.all(np.abs(t - nominal) <= 0.1 * nominal + 2 * world.dt), (task, mode)
            # Noisy: no two demonstrations of a mode are the same.
            assert np.ptp(traj[sel][:, 5:15], axis=0).max() > 0.05
    # The two modes really differ: outside demos of t3 stay out of the central corridor.
    t3 = names.index("t3")
    for tr, m in zip(traj[idx == t3], modes[idx == t3], strict=True):
        assert _in_box(tr, *CORRIDOR).any() == (m == "middle")


# -- teammates --------------------------------------------------------------------------------
def test_archetypes_fast_is_faster_and_routes_are_used(world: FetchWorld) -> None:
    rng = np.random.default_rng(7)
    robot = {t.id: t.robot_duration for t in world.problem().tasks}
    people = {name: archetype(name, world) for name in ARCHETYPES}
    for route in ("middle", "outside"):
        fast, slow = people[f"fast-{route}"], people[f"slow-{route}"]
        for task in world.task_ids:
            assert fast.duration_mean(task) < slow.duration_mean(task)
            f = np.mean([fast.perform(task, rng)[0] for _ in range(20)])
            s = np.mean([slow.perform(task, rng)[0] for _ in range(20)])
            assert f < s
            # Slow people are slower than the robot except on their own top object t0,
            # which is the far one for the robot.
            assert (slow.duration_mean(task) > robot[task]) == (task != "t0"), task
    # A fast person beats the robot on the bottom objects by the middle route.
    for task in ("t2", "t3"):
        assert people["fast-middle"].duration_mean(task) < robot[task]
    # Middle walkers use the corridor; outside walkers never do and use the object's edge lane.
    for name, person in people.items():
        for task in ("t2", "t3"):
            for _ in range(5):
                _, tr = person.perform(task, rng)
                in_corridor = _in_box(tr, *CORRIDOR).any()
                lane = (0.0, 1.4) if task == "t2" else (8.6, 10.0)
                in_lane = _in_box(tr, *lane, 2.4, 5.2).any()
                if name.endswith("middle"):
                    assert in_corridor and not in_lane, (name, task)
                else:
                    assert in_lane and not in_corridor, (name, task)


def test_perform_walks_home_object_home_in_the_sampled_time(world: FetchWorld) -> None:
    rng = np.random.default_rng(11)
    for person in [archetype(n, world) for n in ARCHETYPES] + population(10, rng, world):
        for task in world.task_ids:
            d, tr = person.perform(task, rng)
            assert d > 0 and tr.shape == (math.ceil(d / world.dt - 1e-9) + 1, 2)
            np.testing.assert_allclose(tr[0], world.home("human"), atol=1e-9)
            np.testing.assert_allclose(tr[-1], world.home("human"), atol=1e-9)
            gap = np.linalg.norm(tr - world.object_position(task), axis=1).min()
            assert gap < 1e-6  # the person stands at the object while handling it
            assert not world.collides(tr), (person.name, task)


def test_durations_follow_the_true_distribution(world: FetchWorld) -> None:
    person = archetype("slow-middle", world)
    rng = np.random.default_rng(5)
    d = np.array([person.perform("t2", rng)[0] for _ in range(400)])
    mu, sd = person.true_mean_durations()["t2"], person.true_std_durations()["t2"]
    assert abs(d.mean() - mu) < 3 * sd / math.sqrt(len(d))
    assert d.std(ddof=1) == pytest.approx(sd, rel=0.15)


def test_population_is_mixed_and_statistics_are_complete(world: FetchWorld) -> None:
    rng = np.random.default_rng(2)
    people = population(30, rng, world)
    for task in ("t2", "t3"):
        assert {p.routes[task] for p in people} == {"middle", "outside"}
    speeds = [p.speed for p in people]
    assert max(speeds) - min(speeds) > 1.0
    prior = FetchWorld(prior_people=5, prior_samples=3).prior()
    assert set(prior.durations) == set(prior.paths) == set(world.task_ids)
    for task in world.task_ids:
        assert len(prior.durations[task]) == len(prior.paths[task]) == 15
        assert all(tr.ndim == 2 and tr.shape[1] == 2 for tr in prior.paths[task])


def test_teammate_rejects_bad_settings(world: FetchWorld) -> None:
    with pytest.raises(ValueError, match="modes are"):
        FetchTeammate("x", 3.0, 0.5, routes={"t0": "outside"}, world=world)
    with pytest.raises(ValueError, match="unknown task"):
        FetchTeammate("x", 3.0, 0.5, routes={"t7": "middle"}, world=world)
    with pytest.raises(ValueError, match="speed"):
        FetchTeammate("x", 0.0, 0.5, world=world)
    with pytest.raises(ValueError, match="unknown archetype"):
        archetype("medium-middle", world)


# -- determinism ------------------------------------------------------------------------------
def test_seeded_runs_repeat_exactly(world: FetchWorld) -> None:
    a = world.robot_demonstrations(4, np.random.default_rng(9))
    b = world.robot_demonstrations(4, np.random.default_rng(9))
    c = world.robot_demonstrations(4, np.random.default_rng(10))
    np.testing.assert_array_equal(a.trajectories, b.trajectories)
    assert not np.array_equal(a.trajectories, c.trajectories)

    person = archetype("fast-outside", world)
    d1, t1 = person.perform("t2", np.random.default_rng(1))
    d2, t2 = person.perform("t2", np.random.default_rng(1))
    assert d1 == d2
    np.testing.assert_array_equal(t1, t2)
    # The habit is part of the person: rebuilding the archetype gives the same route.
    np.testing.assert_array_equal(person.route("t2").points,
                                  archetype("fast-outside", world).route("t2").points)

    p1 = population(5, np.random.default_rng(4), world)
    p2 = population(5, np.random.default_rng(4), world)
    assert [(p.speed, p.routes, p.habit_seed) for p in p1] == [
        (p.speed, p.routes, p.habit_seed) for p in p2
    ]
    assert FetchWorld(prior_seed=3).problem() == FetchWorld(prior_seed=3).problem()
    assert FetchWorld(prior_seed=3).problem() != FetchWorld(prior_seed=4).problem()


def test_bundled_fetch_example_matches_the_world():
    from pathlib import Path

    from rapidds.problem import load_problem

    example = load_problem(Path(__file__).resolve().parents[1] / "examples" / "fetch.yaml")
    world = fetch_problem()
    assert example.precedence == world.precedence
    for a, b in zip(example.tasks, world.tasks, strict=True):
        assert (a.id, a.allowed, a.human_mean, a.human_std, a.robot_duration) == (
            b.id, b.allowed, b.human_mean, b.human_std, b.robot_duration
        )


def test_route_mode_recognises_every_demonstrated_route(world: FetchWorld) -> None:
    demos = world.robot_demonstrations(3, np.random.default_rng(0))
    for traj, k, mode in zip(demos.trajectories, demos.task_index, demos.modes, strict=True):
        assert world.route_mode(demos.task_names[k], traj) == mode
