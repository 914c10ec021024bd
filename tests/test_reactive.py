"""Execution inside the cycle: the clock-driven executor, people who react and
deviate, speed and separation monitoring and re-planning; the paper's execution unchanged."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import cli_cmd, kill_run, resume_and_compare, run_main
from conftest import SMALL_SEARCH as SMALL
from record_helpers import decided, stored

from rapidds.execution import (
    CycleExecutor,
    CycleRules,
    PlannedRobot,
    Replanning,
    SimulatedHuman,
    SpeedSeparation,
    protective_distance,
)
from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.loop.deploy import deploy
from rapidds.worlds.reactions import Deviation, Reaction, cell_reactions

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def plans(fetch_policy):
    """Planned fetch cycles for four people (the first cycle of each, small search)."""
    out = []
    for seed, human in enumerate(("slow-middle", "fast-middle", "slow-outside", "fast-outside")):
        run = AdaptiveRun(RunConfig(human=human, cycles=1, seed=seed, **SMALL), fetch_policy)
        out.append((run, run.plan()))
    return out


def _person(run, plan, seed, reaction=None, deviation=None):
    human = run.teammate.execute(plan.cycle, plan.best.schedule.tasks("human"),
                                 np.random.default_rng(seed))
    rng = np.random.default_rng([seed, 1])
    return human, SimulatedHuman(run.world, human,
                                 lambda t: run.teammate.perform(t, rng), reaction, deviation)


def _execute(run, plan, person, policy=None, replanning=None):
    ex = CycleExecutor(run.world, run.problem, plan.best.schedule, person,
                       PlannedRobot(run.world, plan.best.motions), policy,
                       beta=run.model.spatial.config.beta,
                       rules=CycleRules(replanning=replanning))
    return ex, ex.run()


def _replanning(run, plan):
    mean, std = run.model.temporal.mean(), run.model.temporal.std()
    return Replanning(mean=dict(zip(run.problem.ids, mean.tolist(), strict=True)),
                      std=dict(zip(run.problem.ids, std.tolist(), strict=True)),
                      robot={j: m.duration for j, m in plan.best.motions.items()},
                      spatial=lambda j, c: 0.0, gamma=run.problem.objective.gamma)


def test_open_loop_execution_equals_the_papers_replay_exactly(plans):
    for run, plan in plans:
        for seed in range(3):
            human, person = _person(run, plan, seed)
            _, got = _execute(run, plan, person)
            want = deploy(run.world, run.problem, plan.best.schedule, plan.best.motions, human,
                          beta=run.model.spatial.config.beta)
            assert np.array_equal(got.timeline.start, want.timeline.start)
            assert np.array_equal(got.timeline.finish, want.timeline.finish)
            assert (got.makespan, got.spatial, got.cost, got.min_separation) == (
                want.makespan, want.spatial, want.cost, want.min_separation)
            assert got.overlaps == want.overlaps and got.spatial_by_task == want.spatial_by_task
            assert got.human == want.human and got.robot.keys() == want.robot.keys()
            assert got.pauses == () and got.replans == ()


def test_planned_execution_keeps_the_base_commits_records(fetch_policy):
    # records of 3412e09 (before the executor existed), same settings and seed
    want = json.loads((DATA / "records-3412e09-fetch.json").read_text())
    cfg = RunConfig(human="slow-middle", cycles=2, seed=7, **SMALL)
    got = json.loads(json.dumps([stored(r) for r in AdaptiveRun(cfg, fetch_policy).run()]))
    assert got == want


def test_a_reacting_person_loses_time_near_the_moving_robot(plans):
    lost, slowed = 0.0, 0
    for run, plan in plans:
        for seed in range(4):
            _, calm = _person(run, plan, seed)
            _, base = _execute(run, plan, calm)
            _, person = _person(run, plan, seed, Reaction(comfort=2.0, stop=1.0, slow=0.4))
            _, dep = _execute(run, plan, person)
            for t, ex in dep.human.items():
                assert ex.duration >= base.human[t].duration - 1e-9
            gained = sum(ex.duration - base.human[t].duration for t, ex in dep.human.items())
            lost += gained
            slowed += bool(dep.pauses)
            assert (gained > 0) == any(p["agent"] == "person" for p in dep.pauses)
    assert slowed >= 2 and lost > 0.5, (slowed, lost)


def test_a_person_who_takes_a_robot_task_makes_the_robot_replan(plans):
    took = 0
    for run, plan in plans:
        robot_tasks = plan.best.schedule.tasks("robot")
        _, person = _person(run, plan, 0, deviation=Deviation("take", pick=0.0))
        _, dep = _execute(run, plan, person, replanning=_replanning(run, plan))
        taken = set(dep.timeline.schedule.tasks("human")) & set(robot_tasks)
        if not taken:
            continue
        took += 1
        (task,) = taken
        assert [r["reason"] for r in dep.replans][:1] == ["took"]
        assert dep.replans[0]["task"] == task
        assert task in dep.human and task not in dep.robot  # the person did it, not the robot
    assert took >= 2


def test_a_long_pause_is_an_overrun_that_triggers_a_replan(plans):
    run, plan = plans[0]
    _, person = _person(run, plan, 0, deviation=Deviation("pause", pick=0.0, task=0, at=0.3,
                                                          seconds=20.0))
    _, dep = _execute(run, plan, person, replanning=_replanning(run, plan))
    first = plan.best.schedule.tasks("human")[0]
    assert dep.human[first].duration > 20.0
    assert any(r["reason"] == "overran" and r["task"] == first for r in dep.replans)
    assert any(p["reason"] == "deviation" and p["end"] - p["start"] == pytest.approx(20.0)
               for p in dep.pauses)


def test_every_deviation_lets_the_cycle_finish(plans):
    # pauses starting and ending anywhere in a task, taken tasks and other orders, with a
    # reacting person and the monitoring robot: each cycle ends, every task done once
    _, limits = cell_reactions(plans[0][0].world)
    for k, (run, plan) in enumerate(plans):
        for j, at in enumerate(np.linspace(0.2, 0.8, 7)):
            kind = ("pause", "take", "order")[(j + k) % 3]
            dev = Deviation(kind, pick=at - 0.2, task=j, at=float(at), seconds=1.0 + 0.37 * j)
            _, person = _person(run, plan, j, Reaction(1.5, 0.7, 0.4), dev)
            _, dep = _execute(run, plan, person, SpeedSeparation(limits),
                              _replanning(run, plan))
            done = [*dep.timeline.schedule.human, *dep.timeline.schedule.robot]
            assert sorted(done) == sorted(run.problem.ids)
            assert np.isfinite(dep.makespan) and dep.makespan < 120


def _violations(ex, limits) -> int:
    """Ticks at which the robot moved while the person was within the protective distance."""
    return sum(rate > 0 and sep < protective_distance(limits, vh, rate * vr) - 1e-9
               for _, sep, vh, vr, rate in ex.trace)


def test_no_person_within_the_protective_distance_of_a_moving_robot(plans):
    _, limits = cell_reactions(plans[0][0].world)
    moved, unsafe_open_loop = 0, 0
    for run, plan in plans:
        for seed in range(4):
            reaction = Reaction(comfort=1.5, stop=0.7, slow=0.4)
            dev = Deviation(("take", "pause", "order", "take")[seed], pick=0.5, seconds=3.0)
            _, person = _person(run, plan, seed, reaction, dev)
            ex, _ = _execute(run, plan, person, SpeedSeparation(limits),
                               _replanning(run, plan))
            assert ex.trace, "the executor watched nothing"
            assert _violations(ex, limits) == 0
            moved += sum(rate > 0 for *_, rate in ex.trace)
            _, person = _person(run, plan, seed, reaction, dev)
            ex, _ = _execute(run, plan, person)  # the paper's robot, same person
            unsafe_open_loop += _violations(ex, limits)
    assert moved > 100
    assert unsafe_open_loop > 0  # the check can fail: an open-loop robot does come close


def test_speed_and_separation_slows_before_it_stops():
    limits = cell_reactions(type("W", (), {"workspace_bounds": (np.zeros(2), np.ones(2))})())[1]
    ssm = SpeedSeparation(limits)
    still = protective_distance(limits, 1.0, 0.0)
    full = protective_distance(limits, 1.0, 2.0)
    assert ssm.rate_at(still - 1e-6, 1.0, 2.0) == 0.0
    assert 0.0 < ssm.rate_at((still + full) / 2, 1.0, 2.0) < 1.0
    assert ssm.rate_at(full + 1e-6, 1.0, 2.0) == 1.0
    r = ssm.rate_at((still + full) / 2, 1.0, 2.0)
    assert protective_distance(limits, 1.0, r * 2.0) == pytest.approx((still + full) / 2)


@pytest.mark.parametrize("command", [["run", "--cycles", "1"], ["ablation", "--trials", "1"],
                                     ["study", "simulate"]])
@pytest.mark.parametrize(("flag", "value", "says"), [
    ("--deviate", "1.5", "deviate"), ("--execution", "sideways", "execution"),
    ("--deviate", "-0.1", "deviate"),
])
def test_bad_execution_settings_are_one_line_errors(capsys, tmp_path, command, flag, value,
                                                    says):
    out = tmp_path / "out"
    where = [] if command[0] == "run" else ["--out", str(out)]
    code, _, err = run_main(capsys, *command, *where, flag, value)
    assert not out.exists()  # refused before anything is written
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("rapidds: error:") and says in err, err


@pytest.mark.slow
def test_a_killed_reactive_run_resumes_identically(tmp_path):
    import os
    import subprocess

    args = ["run", "--human", "slow-middle", "--cycles", "4", "--seed", "3",
            "--population", "12", "--generations", "10", "--samples", "16",
            "--particles", "2", "--candidates", "4", "--json",
            "--execution", "reactive", "--reacts", "--deviate", "0.6"]
    rid = "fetch-slow-middle-full-reactive-reacts-dev0.6-s3"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    full = subprocess.run(cli_cmd(*args, "--out", str(tmp_path / "a")), capture_output=True,
                          text=True, env=env, timeout=400)
    assert full.returncode == 0, full.stderr
    lines = [json.loads(x) for x in full.stdout.splitlines()]
    assert [r["cycle"] for r in lines] == list(range(4))
    assert all("pauses" in r and "replans" in r for r in lines)

    db = tmp_path / "b" / "run.sqlite"
    kept = kill_run(cli_cmd(*args, "--out", str(tmp_path / "b")), db, rid, 1, env, 300)
    assert kept is not None and kept < 3, "the run finished before it could be killed"
    ra, rb, _, _ = resume_and_compare(cli_cmd(*args, "--out", str(tmp_path / "b"), "--resume"),
                                      tmp_path / "a" / "run.sqlite", db, env, timeout=400)
    assert [decided(r) for r in ra] == [decided(r) for r in rb]
    assert (tmp_path / "b" / "gantt" / f"{rid}-cycle-03.png").exists()


def test_the_gantt_chart_draws_pauses_and_replans(plans):
    from rapidds.plots.gantt import plot_gantt

    run, plan = plans[0]
    _, limits = cell_reactions(run.world)
    _, person = _person(run, plan, 0, Reaction(1.5, 0.7, 0.4), Deviation("take", pick=0.0))
    _, dep = _execute(run, plan, person, SpeedSeparation(limits), _replanning(run, plan))
    assert dep.pauses and dep.replans
    plain = plot_gantt(dep.timeline)
    drawn = plot_gantt(dep.timeline, pauses=dep.pauses, replans=dep.replans)
    assert len(drawn.patches) == len(plain.patches) + len(dep.pauses)
    marks = [ln for ln in drawn.lines if ln.get_marker() == "v"]
    assert sorted(float(ln.get_xdata()[0]) for ln in marks) == sorted(
        r["time"] for r in dep.replans)


def test_a_replan_can_hand_the_robot_a_task_of_the_person(plans):
    from rapidds.loop.execute import contingency_motions

    handed = 0
    for run, plan in plans:
        cfg = run.config.replace(execution="reactive")
        spare = contingency_motions(run.world, run.problem, cfg, 0, plan.gamma, run.policy,
                                    run.model.spatial, plan.best.motions)
        assert set(spare) == set(run.problem.ids) - set(plan.best.motions)
        motions = {**spare, **plan.best.motions}
        _, person = _person(run, plan, 0, deviation=Deviation("take", pick=0.0))
        rp = _replanning(run, plan)
        rp = Replanning(rp.mean, rp.std, {j: m.duration for j, m in motions.items()},
                        rp.spatial, rp.gamma)
        ex = CycleExecutor(run.world, run.problem, plan.best.schedule, person,
                           PlannedRobot(run.world, motions), beta=1.0,
                           rules=CycleRules(replanning=rp))
        dep = ex.run()
        mine = set(plan.best.schedule.tasks("human"))
        robot_did = set(dep.timeline.schedule.tasks("robot"))
        if robot_did & mine:
            handed += 1
            assert any(r["changed"] for r in dep.replans)
            assert (robot_did & mine) <= set(dep.robot)  # it followed a trajectory for it
    assert handed >= 1


def test_deviation_kinds_are_those_the_plan_leaves_room_for(plans):
    from rapidds.schedule import Schedule
    from rapidds.worlds.reactions import deviation_kinds

    problem = plans[0][0].problem  # fetch: t2 and t3 precede t0 and t1
    assert deviation_kinds(problem, Schedule(("t2", "t3"), ("t0", "t1"))) == (
        "order", "pause", "take")
    # a chain of the person's tasks leaves no other order
    assert deviation_kinds(problem, Schedule(("t2", "t0"), ("t3", "t1"))) == ("pause", "take")
    # the robot's only task starts at once: nothing is left to take
    assert deviation_kinds(problem, Schedule(("t3", "t0", "t1"), ("t2",))) == ("order", "pause")


def test_a_deviation_without_room_is_redrawn_and_the_rest_stay_as_drawn():
    from rapidds.worlds.reactions import ReactionPopulation, draw_deviation

    pop = ReactionPopulation((1.0, 0.1), (0.5, 0.1))
    kinds_seen, redrawn, deviated = set(), 0, 0
    for s in range(300):
        every = draw_deviation(0.6, np.random.default_rng(s), pop)
        some = draw_deviation(0.6, np.random.default_rng(s), pop, ("pause", "take"))
        assert (every is None) == (some is None)  # the rate does not depend on the kinds
        if every is None:
            continue
        deviated += 1
        kinds_seen.add(some.kind)
        assert some.kind in ("pause", "take")
        if every.kind == "order":
            redrawn += 1
            assert some.instead_of == "order" and some.to_json()["instead_of"] == "order"
            assert (some.pick, some.task, some.at, some.seconds) == (
                every.pick, every.task, every.at, every.seconds)
        else:
            assert some == every  # a kind with room is drawn as all kinds would draw it
    assert kinds_seen == {"pause", "take"} and redrawn > 30 and 120 < deviated < 240
    assert draw_deviation(1.0, np.random.default_rng(0), pop, ()) is None


def _steering_cycle(run, plan, deviation, steer_max):
    """A reactive cycle whose re-plans steer with an empty memory (every changed pair is new)."""
    from rapidds.loop.execute import CycleMotions, contingency_motions, replan_steering
    from rapidds.loop.model import workspace_cost

    cfg = run.config.replace(execution="reactive")
    motions = {**contingency_motions(run.world, run.problem, cfg, 0, plan.gamma, run.policy,
                                     run.model.spatial, plan.best.motions), **plan.best.motions}
    supply = CycleMotions(motions, {}, replan_steering(run.world, cfg, 0, plan.gamma,
                                                       run.policy, run.model.spatial),
                          workspace_cost(run.world, run.model.spatial))
    rp = _replanning(run, plan)
    rp = Replanning(rp.mean, rp.std, {j: m.duration for j, m in motions.items()},
                    lambda j, c: supply.cost(c, motions[j].trajectory), rp.gamma,
                    motions=supply, steer_max=steer_max)
    _, person = _person(run, plan, 0, deviation=deviation)
    dep = CycleExecutor(run.world, run.problem, plan.best.schedule, person,
                        PlannedRobot(run.world, motions), beta=1.0,
                        rules=CycleRules(replanning=rp)).run()
    return motions, supply, dep


def test_a_replan_steers_a_motion_only_where_the_concurrency_changed(plans):
    steered = used = 0
    for run, plan in plans:
        for dev in (Deviation("take", pick=0.0), Deviation("order", pick=0.0)):
            motions, supply, dep = _steering_cycle(run, plan, dev, steer_max=4)
            resteered = {}
            for q in dep.replans:
                assert q["steer_s"] >= 0.0 and q["latency_s"] >= q["steer_s"]
                for m in q["motions"]:
                    assert m["now"] != m["was"]
                    assert m["by"] in ("steered", "recalled")  # none over the budget of 4
                    new = supply.recall((m["task"], frozenset(m["now"])))
                    assert new is not None and new.concurrent == frozenset(m["now"])
                    assert m["used"] == (m["value"][1] < m["value"][0] - 1e-9)
                    steered += m["by"] == "steered"
                    if m["used"]:
                        resteered[m["task"]] = new
            for j, traj in dep.robot.items():  # no monitoring: every motion ran undisturbed
                want = resteered[j] if j in resteered else motions[j]
                assert np.array_equal(traj, np.asarray(want.trajectory, float)), j
            used += len(resteered)
    assert steered >= 2 and used >= 1, (steered, used)


def test_over_the_steering_budget_a_replan_keeps_the_plans_motion(plans):
    kept = 0
    for run, plan in plans:
        motions, _, dep = _steering_cycle(run, plan, Deviation("take", pick=0.0), steer_max=0)
        for q in dep.replans:
            assert all(m["by"] == "kept (steering budget)" and "used" not in m
                       for m in q["motions"])
            kept += len(q["motions"])
        for j, traj in dep.robot.items():
            assert np.array_equal(traj, np.asarray(motions[j].trajectory, float))
    assert kept >= 1


def test_robot_concurrency_is_read_off_the_expected_rest_of_the_cycle(plans):
    from rapidds.execution.replan import robot_concurrency

    problem = plans[0][0].problem  # fetch: t2 and t3 precede t0 and t1
    mean = {"robot:t3": 2.0, "robot:t1": 3.0, "human:t0": 4.0}
    fixed = {"t2": ("human", 0.0, 5.0)}  # the person's t2 runs until 5 s
    near = robot_concurrency(problem, 0.0, ["t0"], ["t3", "t1"], fixed,
                             {"human": 5.0, "robot": 0.0}, mean)
    assert near == {"t3": frozenset({"t2"}), "t1": frozenset({"t0"})}
    # the person's t0 after the robot's t1 ends: t1 runs beside nothing
    mean["human:t0"] = 1.0
    near = robot_concurrency(problem, 0.0, ["t0"], ["t3", "t1"], fixed,
                             {"human": 9.0, "robot": 0.0}, mean)
    assert near == {"t3": frozenset({"t2"}), "t1": frozenset()}
    # an order that cannot finish has no timeline
    assert robot_concurrency(problem, 0.0, ["t0"], ["t1", "t3"], fixed,
                             {"human": 5.0, "robot": 0.0}, mean) == {}
