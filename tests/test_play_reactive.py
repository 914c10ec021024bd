"""The browser game with a robot that reacts live (``rapidds play --execution reactive``),
without a browser: the player driven tick by tick by the bot the browser test uses, the robot
by the loop's executor. It stops for a person standing in its path and resumes when they leave;
a person who takes a robot task does it, and the robot re-plans; through the loop, the stored
cycle holds the order the person took, the re-plans and the robot's pauses."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from play_bot import RouteBot, human_tasks

from rapidds.execution import CycleExecutor, Deployment, HumanSource
from rapidds.loop.config import RunConfig
from rapidds.loop.execute import CycleSetup, cycle_executor
from rapidds.loop.model import prior_model
from rapidds.loop.run import AdaptiveRun, CyclePlan, ReactiveTeammate
from rapidds.motion.interface import MotionPlan
from rapidds.motion.policy import DiffusionPolicy
from rapidds.schedule import Schedule
from rapidds.scheduler import Evaluation
from rapidds.store import RunStore
from rapidds.web.player import BrowserPlayer
from rapidds.web.session import STORE_NAME, PlaySession
from rapidds.worlds.fetch.world import FetchWorld

SEARCH = dict(population=8, generations=4, samples=8, patience=2, particles=2, candidates=4)
HZ = 30


def _plan(world: FetchWorld, human: tuple[str, ...],
          robot: tuple[str, ...]) -> tuple[CyclePlan, dict[str, MotionPlan]]:
    """A hand-made plan with the world's nominal robot motions; every task's motion (the
    executor's spares included)."""
    problem = world.problem()
    motions = {}
    for j in problem.ids:
        traj = world.robot_trajectory(j)
        motions[j] = MotionPlan(j, frozenset(), float(world.completion_time(j, traj[None])[0]),
                                0.0, traj)
    n = len(problem.ids)
    best = Evaluation(Schedule(human, robot), True, 0.0, 0.0, 0.0, np.zeros(1), 0.0, 0.0,
                      {j: motions[j] for j in robot}, {}, True, 0, np.zeros(n), np.ones(n))
    return CyclePlan(0, best, 0.0, {}, np.random.default_rng(0)), motions


def _builder(world: FetchWorld, plan: CyclePlan,
             motions: dict[str, MotionPlan]) -> Callable[[HumanSource], CycleExecutor]:
    cfg = RunConfig(world="fetch", human="tester", cycles=1, seed=0, execution="reactive")
    model = prior_model(world, cfg.resolved(world))
    problem = world.problem()
    setup = CycleSetup(world, problem, cfg, 0, problem.objective.gamma, plan.best.schedule,
                       motions, (model.temporal.mean(), model.temporal.std()), model.spatial,
                       1.0)
    return lambda person: cycle_executor(setup, person, max_time=math.inf)


class _Played:
    """``player.play`` in a thread (it blocks until the cycle is over, as for the loop)."""

    def __init__(self, player: BrowserPlayer, plan: CyclePlan,
                 build: Callable[[HumanSource], CycleExecutor]):
        self.dep: Deployment | None = None
        self._thread = threading.Thread(target=self._run, args=(player, plan, build))
        self._thread.start()
        end = time.monotonic() + 30
        while player.phase != "ready":
            assert time.monotonic() < end
            time.sleep(0.005)

    def _run(self, player: BrowserPlayer, plan: CyclePlan,
             build: Callable[[HumanSource], CycleExecutor]) -> None:
        self.dep = player.play(plan, build)

    def result(self) -> Deployment:
        self._thread.join(30)
        assert self.dep is not None
        return self.dep


def _walk_to(player: BrowserPlayer, goal: tuple[float, float], ticks: int = 600) -> dict:
    player.steer(target=goal)
    for _ in range(ticks):
        state = player.tick()
        if np.linalg.norm(np.subtract(state["h"], goal)) < 0.05:
            return state
    raise AssertionError(f"the avatar did not reach {goal}: {state['h']}")


def _finish(player: BrowserPlayer, bot: RouteBot) -> dict[str, Any]:
    state = player.snapshot()
    for _ in range(20 * 60 * HZ):
        if state["over"]:
            return state
        player.steer(move=bot.move(state))
        state = player.tick()
    raise AssertionError(f"the cycle did not end: {state}")


def test_the_robot_stops_for_a_person_in_its_path_and_resumes(fetch_world: FetchWorld) -> None:
    player = BrowserPlayer(fetch_world, hz=HZ)
    assert isinstance(player, ReactiveTeammate)
    plan, motions = _plan(fetch_world, ("t2",), ("t3", "t0", "t1"))
    played = _Played(player, plan, _builder(fetch_world, plan, motions))
    assert player.start(0)
    # into the corridor between the two blocks, where the robot's route to t3 runs
    _walk_to(player, (5.0, 6.0))
    state = _walk_to(player, (5.0, 3.8))
    for _ in range(10 * HZ):  # standing still: the robot comes and stops in front of us
        if state["robot"] == "stopped":
            break
        state = player.tick()
    assert state["robot"] == "stopped" and state["rcur"] == "t3"
    held, t_held = state["r"], state["t"]
    for _ in range(HZ):  # a second later it has not moved
        state = player.tick()
        assert state["robot"] == "stopped" and state["r"] == held
    _walk_to(player, (5.0, 6.0))
    state = _walk_to(player, (2.2, 7.0))
    for _ in range(5 * HZ):
        if state["r"] != held:
            break
        state = player.tick()
    assert state["r"] != held  # resumed once we were out of its way
    end = _finish(player, RouteBot(fetch_world))
    dep = played.result()
    stops = [p for p in dep.pauses if p["agent"] == "robot" and "stop" in p["reason"]]
    assert any(p["task"] == "t3" and p["start"] <= t_held and p["end"] >= t_held + 1.0
               for p in stops), dep.pauses
    assert dep.protective is not None and dep.protective["moving_inside"] == 0
    assert dep.makespan == pytest.approx(max(f for _, f in end["times"].values()), abs=2e-3)


def test_a_person_who_leaves_a_reactive_cycle_plays_it_again(fetch_world: FetchWorld) -> None:
    """A restart builds the cycle's executor afresh: nothing of the left cycle remains."""
    player = BrowserPlayer(fetch_world, hz=HZ)
    plan, motions = _plan(fetch_world, ("t2", "t3"), ("t0", "t1"))
    played = _Played(player, plan, _builder(fetch_world, plan, motions))
    assert player.start(0)
    bot, state = RouteBot(fetch_world, prefer=("t3",)), player.snapshot()
    for _ in range(5 * HZ):  # t3 is picked up out of the plan's order: a re-plan
        player.steer(move=bot.move(state))
        state = player.tick()
        if state["replans"]:
            break
    assert state["replans"] and state["tasks"]["t3"] == "carried" and player.restart()
    again = player.snapshot()
    assert again is not None and again["t"] == 0 and not again["started"]
    assert again["replans"] == [] and again["robot"] == "idle" and again["h"] == [2.2, 7.0]
    assert player.start(0)
    end = _finish(player, RouteBot(fetch_world))  # now in the plan's order
    dep = played.result()
    assert dep.replans == () and end["over"]
    assert dep.timeline.schedule.tasks("human") == ("t2", "t3")


def test_a_person_who_takes_a_robot_task_does_it_and_the_robot_replans(
        fetch_world: FetchWorld) -> None:
    """The plan gives the robot t3 then t2; t2 is open to the person while the robot is out for
    t3 (a person may fetch it, its predecessors are none). They fetch it: theirs in the
    record, and the robot re-planned the rest at that instant."""
    player = BrowserPlayer(fetch_world, hz=HZ)
    plan, motions = _plan(fetch_world, ("t1",), ("t3", "t2", "t0"))
    played = _Played(player, plan, _builder(fetch_world, plan, motions))
    assert player.start(0)
    first = player.tick()
    assert first["takeable"] == ["t2"] and first["owner"]["t2"] == "robot"
    end = _finish(player, RouteBot(fetch_world, prefer=("t2",)))
    dep = played.result()
    assert "t2" in dep.timeline.schedule.tasks("human") and "t2" in dep.human
    took = [r for r in dep.replans if r["reason"] == "took"]
    assert [r["task"] for r in took] == ["t2"] and end["owner"]["t2"] == "human"
    assert 0.0 < took[0]["time"] < end["times"]["t2"][1]
    assert "t2" not in took[0]["after"]["robot"]
    problem = fetch_world.problem()
    for t, (s, f) in end["times"].items():  # the record's timeline is the one played
        k = problem.index[t]
        assert (dep.timeline.start[0, k], dep.timeline.finish[0, k]) == pytest.approx(
            (s, f), abs=2e-3)
    assert dep.human["t2"].duration == pytest.approx(end["times"]["t2"][1]
                                                     - end["times"]["t2"][0], abs=2e-3)


def test_another_order_than_the_plans_makes_the_robot_replan(fetch_world: FetchWorld) -> None:
    player = BrowserPlayer(fetch_world, hz=HZ)
    plan, motions = _plan(fetch_world, ("t2", "t3"), ("t0", "t1"))
    played = _Played(player, plan, _builder(fetch_world, plan, motions))
    assert player.start(0)
    end = _finish(player, RouteBot(fetch_world, prefer=("t3",)))
    dep = played.result()
    (replan,) = dep.replans  # at the pick-up of t3, the plan's second
    assert (replan["reason"], replan["task"]) == ("order", "t3")
    assert player.played_order(0)[0] == "t3"
    # what was done is the re-plan's: the robot's part and the rest of the person's
    assert dep.timeline.schedule.tasks("robot") == tuple(replan["after"]["robot"])
    assert dep.timeline.schedule.tasks("human") == ("t3", *replan["after"]["human"])
    assert dep.timeline.schedule.tasks("human") == tuple(player.played_order(0))
    assert dep.makespan == pytest.approx(max(f for _, f in end["times"].values()), abs=2e-3)


def test_a_taken_robot_task_is_the_persons_in_the_stored_record(
        tmp_path: Path, fetch_world: FetchWorld, fetch_policy: DiffusionPolicy) -> None:
    """The loop's own execute, learn and record steps on a hand-made plan that leaves a robot
    task open to the person: the stored cycle says the person did it, with their duration
    and path, and the re-plan it caused."""
    cfg = RunConfig(world="fetch", human="tester", cycles=1, seed=0, execution="reactive",
                    **SEARCH)
    player = BrowserPlayer(fetch_world, "tester", hz=HZ)
    plan, _ = _plan(fetch_world, ("t1",), ("t3", "t2", "t0"))
    with RunStore(tmp_path / STORE_NAME) as store:
        run = AdaptiveRun(cfg, fetch_policy, store, fetch_world, teammate=player)
        out: dict[str, Any] = {}
        worker = threading.Thread(target=lambda: out.setdefault("dep", run.execute(plan)))
        worker.start()
        end = time.monotonic() + 60
        while player.phase != "ready":
            assert time.monotonic() < end and worker.is_alive()
            time.sleep(0.005)
        assert player.start(0)
        _finish(player, RouteBot(fetch_world, prefer=("t2",)))
        worker.join(30)
        run.learn(plan, out["dep"])
        rec = run.record(plan, out["dep"])
        (stored,) = store.records(run.config.run_id)
        arrays = store.arrays(run.config.run_id, 0)
    assert stored == {**rec.to_json(), "run_id": run.config.run_id}
    ran = rec.execution.in_cycle
    assert ran is not None
    assert list(rec.plan.robot) == ["t3", "t2", "t0"] and "t2" in ran.executed["human"]
    assert "t2" not in ran.executed["robot"] and rec.observed["t2"] > 0
    assert arrays["human/t2"].shape[0] == math.ceil(rec.observed["t2"] / fetch_world.dt
                                                    - 1e-9) + 1
    assert (ran.replans[0]["reason"], ran.replans[0]["task"]) == ("took", "t2")


def test_the_loop_stores_a_live_reactive_cycle_with_its_replans(
        tmp_path: Path, fetch_world: FetchWorld, fetch_policy: DiffusionPolicy) -> None:
    cfg = RunConfig(world="fetch", human="tester", cycles=1, seed=3, execution="reactive",
                    **SEARCH)
    player = BrowserPlayer(fetch_world, "tester", hz=HZ)
    session = PlaySession(cfg, tmp_path, world=fetch_world, policy=fetch_policy, player=player)
    session.open()
    try:
        end = time.monotonic() + 180
        while player.phase != "ready":
            assert time.monotonic() < end and session.error is None, session.error
            time.sleep(0.01)
        view = player.plan_view()
        assert view is not None and session.info()["execution"] == "reactive"
        # in this job's first plan precedence leaves the person one order (t2 before t0) and
        # the robot starts its tasks the moment they may start: the person deviates by
        # dawdling with their last object (t0: past its learned mean + 1.28 sd, 3.1 s)
        last_task = human_tasks(view["sequences"]["human"])[-1]
        bot = RouteBot(fetch_world, hold={last_task: 4.0})
        assert player.start(0)
        last = _finish(player, bot)
        while session.stored < 1:
            assert time.monotonic() < end and session.error is None, session.error
            time.sleep(0.01)
    finally:
        session.stop()
    with RunStore(tmp_path / STORE_NAME) as store:
        (rec,) = store.records(session.run_id)
    assert session.run_id.endswith("-reactive-s3")
    # the order the person took, what they did, and the re-plan their overrun caused
    assert rec["executed"]["human"] == player.played_order(0)
    assert set(rec["observed"]) == set(rec["executed"]["human"])
    assert session.summary is not None and session.summary["human"] == rec["executed"]["human"]
    assert [(r["reason"], r["task"]) for r in rec["replans"]] == [("overran", last_task)]
    assert rec["replans"][0]["latency_s"] < 1.0  # a re-plan of the rest: milliseconds
    robot = [p for p in rec["pauses"] if p["agent"] == "robot"]
    assert all(p["end"] > p["start"] for p in robot)
    assert rec["protective"]["moving_inside"] == 0
    for t, (s, f) in last["times"].items():
        assert rec["realised"]["timeline"][t] == pytest.approx([s, f], abs=2e-3)
