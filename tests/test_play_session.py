"""The browser game's run without a browser: the BrowserPlayer as the loop's teammate, driven by
the same bot the browser test uses, tick by tick as fast as the CPU goes. Two cycles stored with
the person's durations and paths, the second planned with what the first taught, a resume, a
person who leaves mid-cycle."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from play_bot import RouteBot

from rapidds.errors import RapiddsError
from rapidds.loop.config import RunConfig
from rapidds.loop.execute import CycleSetup, execute_cycle
from rapidds.loop.model import HumanModel, prior_model
from rapidds.loop.observation import Observation
from rapidds.loop.run import AdaptiveRun, CyclePlan, FreeOrderTeammate, LiveTeammate
from rapidds.motion.interface import MotionPlan
from rapidds.motion.policy import DiffusionPolicy
from rapidds.schedule import Schedule
from rapidds.scheduler import Evaluation
from rapidds.store import RunStore
from rapidds.web.player import BrowserPlayer, PlayerGone
from rapidds.web.session import STORE_NAME, PlaySession
from rapidds.worlds.fetch.world import FetchWorld

SEARCH = dict(population=8, generations=4, samples=8, patience=2, particles=2, candidates=4)


def _session(world: FetchWorld, policy: DiffusionPolicy, out: Path, resume: bool = False,
             cycles: int = 3) -> PlaySession:
    cfg = RunConfig(world="fetch", human="tester", adapt="full", cycles=cycles, seed=3, **SEARCH)
    return PlaySession(cfg, out, world=world, policy=policy,
                       player=BrowserPlayer(world, "tester"), resume=resume)


def _drive(session: PlaySession, bot: RouteBot, cycles: int, plans: dict[int, dict],
           states: dict[int, dict], stop_in: int | None = None, timeout: float = 120.0) -> None:
    """Play until ``cycles`` cycles are over (or, with ``stop_in``, until cycle ``stop_in`` is
    under way); the plan views and the last state of every cycle are collected."""
    player = session.player
    end = time.monotonic() + timeout
    while True:
        assert time.monotonic() < end, f"stuck: phase {session.phase}, {session.error}"
        assert session.error is None, session.error
        state = player.tick()
        phase = player.phase
        if state is None or phase in ("waiting", "over"):
            if state is not None:
                states[state["cycle"]] = state
            if state is not None and state["cycle"] + 1 >= cycles and phase == "over":
                return
            time.sleep(0.002)
            continue
        c = state["cycle"]
        states[c] = state
        if phase == "ready":
            plans[c] = player.plan_view()
            if c >= cycles:
                return
            assert player.start(c)
            continue
        if stop_in is not None and c == stop_in and state["t"] > 1.0:
            return
        player.steer(move=bot.move(state))


@pytest.fixture(scope="module")
def played(tmp_path_factory: pytest.TempPathFactory, fetch_world: FetchWorld,
           fetch_policy: DiffusionPolicy) -> dict[str, Any]:
    """Two cycles played and stored, the third one left in the middle (the server killed)."""
    out = tmp_path_factory.mktemp("play")
    session = _session(fetch_world, fetch_policy, out)
    session.open()
    plans: dict[int, dict] = {}
    states: dict[int, dict] = {}
    bot = RouteBot(fetch_world, {"t2": "middle", "t3": "middle"})
    try:
        _drive(session, bot, 2, plans, states)
        _drive(session, bot, 3, plans, states, stop_in=2)
    finally:
        session.stop()
    return {"out": out, "plans": plans, "states": states, "session": session}


def test_two_cycles_are_stored_with_the_persons_durations_and_paths(
        played: dict[str, Any], fetch_world: FetchWorld) -> None:
    session: PlaySession = played["session"]
    with RunStore(played["out"] / STORE_NAME) as store:
        recs = store.records(session.run_id)
        assert [r["cycle"] for r in recs] == [0, 1]  # cycle 2 was under way: not stored
        for rec in recs:
            c = rec["cycle"]
            live = played["states"][c]["times"]
            human = [t for t in rec["human"] if not t.startswith("wait:")]
            assert human and set(rec["observed"]) == set(human)
            arrays = store.arrays(session.run_id, c)
            for t in human:
                s, f = live[t]
                assert rec["observed"][t] == pytest.approx(f - s, abs=2e-3)
                path = arrays[f"human/{t}"]
                n = math.ceil(rec["observed"][t] / fetch_world.dt - 1e-9) + 1
                assert path.shape == (n, 2)
                assert np.linalg.norm(path[-1] - fetch_world.home("human")) <= 0.5
                near = np.linalg.norm(path - fetch_world.object_position(t), axis=1).min()
                assert near <= 0.5 + 4.5 * fetch_world.dt
            # the stored (rebuilt) timeline is the one that was played
            for t, (s, f) in live.items():
                assert rec["realised"]["timeline"][t] == pytest.approx([s, f], abs=2e-3)
            assert rec["realised"]["makespan"] == pytest.approx(
                max(f for _, f in live.values()), abs=2e-3)


def test_the_second_plan_uses_what_the_first_cycle_taught(
        played: dict[str, Any], fetch_world: FetchWorld) -> None:
    session: PlaySession = played["session"]
    with RunStore(played["out"] / STORE_NAME) as store:
        rec0 = store.records(session.run_id)[0]
        model0 = HumanModel.from_bytes(store.state(session.run_id, 0))
    prior = prior_model(fetch_world, session.config.resolved(fetch_world))
    ids = fetch_world.problem().ids
    prior_mean = dict(zip(ids, prior.temporal.mean(), strict=True))
    learned = rec0["belief"]["mean_durations"]
    for t, seen in rec0["observed"].items():
        # the belief moved from the population's mean towards what this person did
        assert abs(learned[t] - seen) < abs(prior_mean[t] - seen) - 0.1
        assert model0.spatial[t].n_obs == 1
    # cycle 1 was planned with it: the expected durations the page showed are the learned ones
    plan1 = played["plans"][1]
    for t in plan1["sequences"]["human"]:
        if t.startswith("wait:"):
            continue
        s, f = plan1["expected"][t]
        assert f - s == pytest.approx(learned[t], abs=2e-3)


def test_a_stored_run_resumes_with_its_learned_models(
        played: dict[str, Any], fetch_world: FetchWorld, fetch_policy: DiffusionPolicy,
        tmp_path: Path) -> None:
    out = played["out"]
    with pytest.raises(RapiddsError, match="pass --resume"):
        _session(fetch_world, fetch_policy, out).open()
    with pytest.raises(RapiddsError, match="no cycle"):
        _session(fetch_world, fetch_policy, tmp_path, resume=True).open()
    with pytest.raises(RapiddsError, match="other settings"):
        _session(fetch_world, fetch_policy, out, resume=True, cycles=5).open()
    session = _session(fetch_world, fetch_policy, out, resume=True)
    session.open()
    try:
        assert session.summary is not None and session.summary["cycle"] == 1
        plans: dict[int, dict] = {}
        _drive(session, RouteBot(fetch_world), 2, plans, {})  # up to cycle 2 on screen
    finally:
        session.stop()
    with RunStore(out / STORE_NAME) as store:
        learned = store.records(session.run_id)[1]["belief"]["mean_durations"]
    # cycle 2 is planned again, from the model stored after cycle 1
    assert set(plans) == {2}
    for t in plans[2]["sequences"]["human"]:
        if not t.startswith("wait:"):
            s, f = plans[2]["expected"][t]
            assert f - s == pytest.approx(learned[t], abs=2e-3)
    assert plans[2] == played["plans"][2]  # the same seed plans the same cycle


# -- the player alone ---------------------------------------------------------------------------
def _plan(world: FetchWorld, cycle: int, human: tuple[str, ...],
          robot: tuple[str, ...]) -> CyclePlan:
    problem = world.problem()
    motions = {}
    for j in robot:
        traj = world.robot_trajectory(j)
        motions[j] = MotionPlan(j, frozenset(), float(world.completion_time(j, traj[None])[0]),
                                0.0, traj)
    n = len(problem.ids)
    best = Evaluation(Schedule(human, robot), True, 0.0, 0.0, 0.0, np.zeros(1), 0.0, 0.0,
                      motions, {}, True, 0, np.zeros(n), np.ones(n))
    return CyclePlan(cycle, best, 0.0, {}, np.random.default_rng(0))


def test_the_player_blocks_until_played_and_queues_the_next_plan(
        fetch_world: FetchWorld) -> None:
    player = BrowserPlayer(fetch_world)
    plan0 = _plan(fetch_world, 0, ("t3",), ("t2", "t0", "t1"))  # the robot's part is long
    player.show(plan0)
    assert player.phase == "ready" and player.cycle == 0
    assert not player.start(1) and player.start(0)
    bot = RouteBot(fetch_world)
    while not player.tick()["human_done"]:
        player.steer(move=bot.move(player.snapshot()))
    obs = player.execute(0, ("t3",), np.random.default_rng(0))  # reported: returns at once
    assert set(obs) == {"t3"} and obs["t3"].duration > 0
    # the next plan comes while the robot is still out: it waits for the cycle to end
    player.show(_plan(fetch_world, 1, ("t2",), ("t3", "t0", "t1")))
    assert player.cycle == 0 and player.phase == "playing"
    assert not player.restart()  # the person's part is with the loop already: nothing to redo
    while player.cycle == 0:
        player.tick()
    assert player.phase == "ready" and player.cycle == 1
    player.close()
    with pytest.raises(PlayerGone):
        player.execute(1, ("t2",), np.random.default_rng(0))


def test_a_person_who_leaves_mid_cycle_plays_it_again(fetch_world: FetchWorld) -> None:
    player = BrowserPlayer(fetch_world)
    player.show(_plan(fetch_world, 4, ("t2", "t0"), ("t3", "t1")))
    player.start(4)
    player.steer(move=(1, -1))
    for _ in range(60):
        state = player.tick()
    assert state is not None and state["t"] == pytest.approx(1.0)
    assert player.restart()
    assert player.phase == "ready" and player.cycle == 4
    again = player.snapshot()
    assert again is not None and again["t"] == 0 and again["h"] == [2.2, 7.0]


def test_the_loop_shows_a_live_teammate_the_plan_before_asking(
        fetch_world: FetchWorld, fetch_policy: DiffusionPolicy) -> None:
    """``run.step()`` works with a person: the plan is shown, then what they did is asked for."""
    calls: list[tuple[str, int]] = []
    person = fetch_world.teammate("fast-middle")

    class Told:
        name = "told"

        def show(self, plan: CyclePlan) -> None:
            calls.append(("show", plan.cycle))

        def execute(self, cycle: int, tasks: Any, rng: np.random.Generator) -> dict:
            calls.append(("execute", cycle))
            return person.execute(cycle, tasks, rng)

    assert isinstance(Told(), LiveTeammate) and not isinstance(person, LiveTeammate)
    run = AdaptiveRun(RunConfig(human="told", cycles=2, **SEARCH), fetch_policy,
                      world=fetch_world, teammate=Told())
    run.step()
    assert calls == [("show", 0), ("execute", 0)]
    plan = run.plan()
    run.execute(plan, Observation(
        human=person.execute(1, plan.best.schedule.tasks("human"), plan.rng)))
    assert calls == [("show", 0), ("execute", 0)]  # observations given: nobody is asked


def test_the_loop_records_the_order_the_person_fetched_in(fetch_world: FetchWorld) -> None:
    """The plan says t2 then t3; the person fetches t3 first. The player hands the loop the
    order they took (FreeOrderTeammate), and the loop's execute step stores that cycle: the
    realised schedule in their order, the live timeline to the millisecond."""
    player = BrowserPlayer(fetch_world, hz=30)
    assert isinstance(player, FreeOrderTeammate)
    plan = _plan(fetch_world, 0, ("t2", "t3"), ("t0", "t1"))
    player.show(plan)
    assert player.start(0) and player.played_order(0) is None
    bot = RouteBot(fetch_world, prefer=("t3",))
    state = player.snapshot()
    while state is not None and not state["over"]:
        player.steer(move=bot.move(state))
        state = player.tick()
    assert state is not None and state["over"]
    obs = player.played(0, ("t2", "t3"))
    assert obs is not None and player.played_order(0) == ["t3", "t2"]
    cfg = RunConfig(world="fetch", human="tester", cycles=1, seed=0, **SEARCH)
    model = prior_model(fetch_world, cfg.resolved(fetch_world))
    problem = fetch_world.problem()
    setup = CycleSetup(fetch_world, problem, cfg, 0, problem.objective.gamma,
                       plan.best.schedule, plan.best.motions,
                       (model.temporal.mean(), model.temporal.std()), model.spatial, 1.0)
    dep, deviation = execute_cycle(setup, obs, player, None, order=player.played_order(0))
    assert deviation is None
    assert dep.timeline.schedule.tasks("human") == ("t3", "t2")
    for t, (s, f) in state["times"].items():
        k = problem.index[t]
        assert (dep.timeline.start[0, k], dep.timeline.finish[0, k]) == pytest.approx(
            (s, f), abs=2e-3)
    # without the order, the plan's order is replayed: another timeline than the one played
    dep_plan, _ = execute_cycle(setup, obs, player, None)
    assert dep_plan.timeline.schedule.tasks("human") == ("t2", "t3")
