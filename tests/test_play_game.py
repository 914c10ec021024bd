"""The live fetch cycle (rapidds.web.game): avatar physics against the world's walls, the plan's
timeline semantics evaluated live (locked objects, waits), and what is observed of the person."""

from __future__ import annotations

import math

import numpy as np
import pytest
from play_bot import RouteBot

from rapidds.execution import CycleExecutor, PlannedRobot, SimulatedHuman
from rapidds.loop.deploy import deploy
from rapidds.motion.interface import MotionPlan
from rapidds.schedule import Schedule, Wait
from rapidds.web.game import AVATAR_RADIUS, FetchGame
from rapidds.worlds.fetch.world import FetchWorld


def _motions(world: FetchWorld, tasks: tuple[str, ...]) -> dict[str, MotionPlan]:
    out = {}
    for j in tasks:
        traj = world.robot_trajectory(j)
        out[j] = MotionPlan(j, frozenset(), float(world.completion_time(j, traj[None])[0]), 0.0,
                            traj)
    return out


def _game(world: FetchWorld, human: tuple, robot: tuple, **kw: object) -> FetchGame:
    schedule = Schedule(tuple(human), tuple(robot))
    return FetchGame(world, world.problem(), schedule, _motions(world, schedule.tasks("robot")),
                     **kw)  # type: ignore[arg-type]


def _play(game: FetchGame, bot: RouteBot, max_s: float = 60.0) -> None:
    game.start()
    while not game.over and game.now < max_s:
        game.steer(move=bot.move(game.state()))
        game.step()
    assert game.over, f"the cycle did not finish in {max_s} s: {game.state()}"


def test_walls_stop_the_avatar_and_it_slides_along_them(fetch_world: FetchWorld) -> None:
    g = _game(fetch_world, ("t2",), ("t3", "t0", "t1"))
    g.start()
    g.pos = np.array([2.0, 5.8])  # above the left block (x 1.4 .. 4.2, y 2.4 .. 5.2)
    g.steer(move=(0, -1))
    for _ in range(120):
        g.step()
    assert g.pos[1] >= 5.2 + AVATAR_RADIUS - 1e-9
    assert g.pos[1] < 5.2 + AVATAR_RADIUS + 0.08  # it walked up to the wall, not short of it
    x0 = g.pos[0]
    g.steer(move=(1, -1))  # into the wall at 45 degrees: slides along it (the x component)
    for _ in range(30):
        g.step()
    assert g.pos[0] == pytest.approx(x0 + 30 * 4.5 / 60 / math.sqrt(2))
    assert g.pos[1] >= 5.2 + AVATAR_RADIUS - 1e-9
    # the fences are thin (0.3 m) and the avatar fast: it still never passes through
    g.pos = np.array([2.2, 7.0])
    g.steer(move=(-1, 0))
    for _ in range(120):
        g.step()
    assert g.pos[0] >= 1.7 + AVATAR_RADIUS - 1e-9


def test_the_avatar_stays_on_the_map_and_walks_to_a_target(fetch_world: FetchWorld) -> None:
    g = _game(fetch_world, ("t2",), ("t3", "t0", "t1"))
    g.start()
    g.pos = np.array([0.9, 9.0])
    g.steer(move=(-1, 1))
    for _ in range(120):
        g.step()
    assert g.pos == pytest.approx([AVATAR_RADIUS, 10 - AVATAR_RADIUS])
    g.steer(target=(3.0, 9.0))
    for _ in range(60):
        g.step()
    assert np.allclose(g.pos, [3.0, 9.0])  # 2.1 m in 1 s at 4.5 m/s: there, and stopped
    g.steer(target=(3.0, 9.0))
    g.steer(move=(0, -1))  # a key cancels the target
    g.step()
    assert g.state()["target"] is None and g.pos[1] < 9.0


def test_an_object_is_locked_until_its_predecessors_are_home(fetch_world: FetchWorld) -> None:
    g = _game(fetch_world, ("t0",), ("t2", "t3", "t1"))
    g.start()
    assert g.status("t0") == "locked" and g.status("t2") == "active"
    g.steer(target=tuple(fetch_world.object_position("t0")))
    for _ in range(90):  # the avatar stands on t0 long before the robot is back with t2, t3
        g.step()
    assert np.linalg.norm(g.pos - fetch_world.object_position("t0")) < 0.1
    assert g.status("t0") == "locked" and "t0" not in g.start_time
    while g.status("t0") == "locked":
        g.step()
    # it unlocks exactly when the robot's t3 is home, and is picked up at once
    assert g.start_time["t0"] == pytest.approx(g.finish_time["t3"])
    g.step()
    assert g.status("t0") == "carried"
    bot = RouteBot(fetch_world)
    while not g.over:
        g.steer(move=bot.move(g.state()))
        g.step()
    obs = g.observations()["t0"]
    assert obs.duration == pytest.approx(g.finish_time["t0"] - g.finish_time["t3"])
    assert np.linalg.norm(obs.trajectory[0] - fetch_world.object_position("t0")) < 0.5


def test_the_live_timeline_is_the_one_deploy_rebuilds(fetch_world: FetchWorld) -> None:
    """Waits and precedence decided live give the timeline the loop stores for the observed
    durations, so nothing the loop records depends on how the cycle was ticked."""
    g = _game(fetch_world, ("t2", "t0"), ("t3", Wait("t0"), "t1"), hz=50)
    _play(g, RouteBot(fetch_world, {"t2": "outside"}))
    obs = g.observations()
    problem = fetch_world.problem()
    dep = deploy(fetch_world, problem, g.schedule, g.motions, obs, beta=1.0)
    for t in problem.ids:
        k = problem.index[t]
        assert dep.timeline.start[0, k] == pytest.approx(g.start_time[t], abs=1e-9)
        assert dep.timeline.finish[0, k] == pytest.approx(g.finish_time[t], abs=1e-9)
    assert g.start_time["t1"] == pytest.approx(g.finish_time["t0"])  # the robot waited
    assert dep.makespan == pytest.approx(g.makespan)
    assert fetch_world.route_mode("t2", obs["t2"].trajectory) == "outside"


def test_observed_paths_are_sampled_at_dt_from_start_to_end(fetch_world: FetchWorld) -> None:
    g = _game(fetch_world, ("t2", "t1"), ("t3", "t0"))
    _play(g, RouteBot(fetch_world))
    dt, hz = fetch_world.dt, g.hz
    trace = np.asarray(g._trace)
    for task, ex in g.observations().items():
        s, f = g.start_time[task], g.finish_time[task]
        assert ex.duration == pytest.approx(f - s)
        n = math.ceil(ex.duration / dt - 1e-9) + 1
        assert ex.trajectory.shape == (n, 2)
        for k in range(n - 1):  # every start here is on a tick, and dt is 12 ticks
            tick = round((s + k * dt) * hz)
            assert np.allclose(ex.trajectory[k], trace[tick])
        assert np.allclose(ex.trajectory[-1], trace[round(f * hz)])
        assert np.linalg.norm(ex.trajectory[-1] - fetch_world.home("human")) <= 0.5
        near = np.linalg.norm(ex.trajectory - fetch_world.object_position(task), axis=1)
        assert near.min() <= 0.5 + 4.5 * dt  # it passed the object (between two samples)
        assert not fetch_world.collides(ex.trajectory)


def test_the_robot_plays_its_trajectory_row_by_row(fetch_world: FetchWorld) -> None:
    g = _game(fetch_world, ("t2",), ("t3", "t0", "t1"))
    g.start()
    traj = g.motions["t3"].trajectory
    for k in range(0, 20):
        assert np.allclose(g.robot_position(), traj[k])
        for _ in range(12):
            g.step()
    assert g.status("t3") == "carried"  # it has passed its object by row 20


def test_a_deadlocked_schedule_is_refused(fetch_world: FetchWorld) -> None:
    with pytest.raises(ValueError, match="deadlock"):
        _game(fetch_world, (Wait("t3"), "t2"), (Wait("t2"), "t3", "t0", "t1"))


def test_the_person_fetches_in_any_order_precedence_allows(fetch_world: FetchWorld) -> None:
    """No lock on the plan's order: the plan says t2 then t3, the person takes t3 first (both are
    open at once), and t0 stays locked until both are home. The executor the loop records with
    replays the order they took and gives the live timeline to the last bit."""
    g = _game(fetch_world, ("t2", "t3"), ("t0", "t1"), hz=50)
    g.start()
    assert g.status("t2") == g.status("t3") == "active" and g.status("t0") == "locked"
    assert g.state()["cur"] == "t2"  # the plan's next, as advice
    _play(g, RouteBot(fetch_world, prefer=("t3",)))
    assert g.order == ["t3", "t2"] and list(g.observations()) == ["t3", "t2"]
    assert g.start_time["t3"] == 0.0
    assert g.start_time["t2"] == pytest.approx(g.finish_time["t3"])
    assert g.start_time["t0"] == pytest.approx(g.finish_time["t2"])
    problem = fetch_world.problem()
    obs = g.observations()
    person = SimulatedHuman(fetch_world, obs, None, order=g.order)
    dep = CycleExecutor(fetch_world, problem, g.schedule, person,
                        PlannedRobot(fetch_world, g.motions), beta=1.0).run()
    assert dep.timeline.schedule.tasks("human") == ("t3", "t2")
    for t in problem.ids:
        k = problem.index[t]
        assert dep.timeline.start[0, k] == pytest.approx(g.start_time[t], abs=1e-9)
        assert dep.timeline.finish[0, k] == pytest.approx(g.finish_time[t], abs=1e-9)


def test_one_open_object_at_a_time_while_carrying(fetch_world: FetchWorld) -> None:
    g = _game(fetch_world, ("t2", "t3"), ("t0", "t1"))
    g.start()
    g.pos = fetch_world.object_position("t3").astype(float)
    g.step()
    assert g.status("t3") == "carried" and g.status("t2") == "queued"
    g.pos = fetch_world.object_position("t2").astype(float)
    g.step()  # walking over t2 while carrying t3 picks nothing up
    assert g.status("t2") == "queued" and g.order == ["t3"]
