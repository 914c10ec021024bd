"""No mutual hold lasts (issue 34 item 6): a robot held for a person who waits for it yields,
the record says so, and a cycle that still cannot progress is a runtime fault (exit 3)."""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import run_main
from conftest import SMALL_SEARCH as SMALL

from rapidds.errors import RuntimeFault
from rapidds.execution import CycleExecutor, PlannedRobot, SimulatedHuman, SpeedSeparation
from rapidds.execution.yielding import YieldGuard, YieldRule
from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.record import InCycle, Yield
from rapidds.worlds.reactions import Reaction, SafetyLimits

DT = 0.2


def _ticks(guard, start, n, robot, person_task, person, rates, finished):
    return [guard.rate(start + k * DT, robot, person_task, person, rates, finished)
            for k in range(n)]


def test_a_held_robot_and_a_still_person_make_the_robot_back_off_then_give_way():
    guard = YieldGuard(YieldRule(after=2.0, retreat=1.0), DT)
    still = np.zeros((3, 2))
    # held at 1 % speed for 2 s: the policy's rate until the rule's time is up
    assert _ticks(guard, 0.0, 10, ("t2", 1.5), "t3", still, (0.01, 0.5), 0) == [0.01] * 10
    assert guard.rate(2.0, ("t2", 1.5), "t3", still, (0.01, 0.5), 0) == -0.5  # backs off
    assert guard.phase == "retreat" and guard.retreat_left(1.5) == pytest.approx(1.0)
    assert guard.rate(2.2, ("t2", 1.4), "t3", still, (0.01, 0.5), 0) == -0.5
    # backed as far as the rule says (1 s of path): stands still while the person's task runs
    assert guard.rate(3.0, ("t2", 0.5), "t3", still, (0.01, 0.5), 0) == 0.0
    assert guard.phase == "hold"
    assert guard.rate(9.0, ("t2", 0.5), "t3", still + 1.0, (0.01, 0.5), 0) == 0.0
    # the person's task ended: the robot goes on at the monitor's rate
    assert guard.rate(9.2, ("t2", 0.5), None, still, (0.7, 0.7), 1) == 0.7
    (y,) = guard.finish(9.4)
    assert y == {"task": "t2", "person_task": "t3", "start": 2.0, "held": pytest.approx(2.0),
                 "retreat": pytest.approx(1.0), "end": 9.2}


def test_a_person_who_moves_or_a_robot_that_progresses_is_no_mutual_hold():
    guard = YieldGuard(YieldRule(after=2.0), DT)
    pts = np.zeros((3, 2))
    for k in range(40):  # the person walks on: no yield however long the robot is held
        assert guard.rate(k * DT, ("t2", 1.0), "t3", pts + 0.01 * k, (0.0, 0.0), 0) == 0.0
    for k in range(40):  # the robot moves on at half speed: no yield either
        assert guard.rate(8 + k * DT, ("t2", 1.0 + 0.1 * k), "t3", pts, (0.5, 0.5), 0) == 0.5
    assert guard.finish(16.0) == []


def test_a_stall_that_yielding_did_not_resolve_is_a_runtime_fault():
    guard = YieldGuard(YieldRule(after=1.0, retreat=0.0), DT)
    pts = np.zeros((3, 2))
    _ticks(guard, 0.0, 6, ("t2", 1.0), None, pts, (0.0, 0.0), 2)  # yields at 1.0 s
    assert guard.phase == "hold"
    _ticks(guard, 1.2, 6, ("t2", 1.0), None, pts, (0.0, 0.0), 2)  # gives way 1 s, goes on
    assert guard.phase == ""
    with pytest.raises(RuntimeFault, match="cannot progress"):  # held again, nothing done
        _ticks(guard, 2.4, 8, ("t2", 1.0), None, pts, (0.0, 0.0), 2)


def test_a_yield_rule_refuses_impossible_times():
    with pytest.raises(ValueError, match="after > 0"):
        YieldRule(after=0.0)


@pytest.fixture(scope="module")
def plan(fetch_policy):
    run = AdaptiveRun(RunConfig(human="slow-middle", cycles=1, seed=3, **SMALL), fetch_policy)
    return run, run.plan()


def test_a_creeping_robot_yields_until_the_person_is_done_then_the_cycle_faults(plan):
    """A monitor that never lets the robot past a crawl (it needs 10^6 s to stop) and a
    person who pauses whenever a moving robot is in the room: a mutual hold at every task of
    the person. The robot yields each time, so the person finishes every task they may start;
    then nothing can finish (the robot crawls, the person waits for it): a runtime fault."""
    run, p = plan
    human = run.teammate.execute(p.cycle, p.best.schedule.tasks("human"),
                                 np.random.default_rng(0))
    person = SimulatedHuman(run.world, human, lambda t: None,
                            Reaction(comfort=1e3, stop=1e3, slow=0.5))
    creep = SpeedSeparation(SafetyLimits(0.1, 1e6, 0.0, 0.0, 0.0))
    ex = CycleExecutor(run.world, run.problem, p.best.schedule, person,
                       PlannedRobot(run.world, p.best.motions), creep,
                       beta=run.model.spatial.config.beta)
    with pytest.raises(RuntimeFault, match="cannot progress"):
        ex.run()
    unblocked = [y["person_task"] for y in ex.guard.yields if y["person_task"] is not None]
    assert unblocked and set(unblocked) <= set(ex.finish)  # each yield let the person finish
    left = set(p.best.schedule.tasks("human")) - set(ex.finish)
    assert all(not ex._gated(t) for t in left)  # what the person has left waits for the robot
    assert ex.guard.yields[-1]["person_task"] is None
    assert any(pause["reason"].startswith("yielded") for pause in ex._robot_pauses)


def test_yields_are_a_typed_part_of_the_record_and_old_records_still_read():
    base = {"executed": {"human": ["t0"], "robot": ["t1"]}, "deviation": None, "pauses": [],
            "replans": [], "protective": None}
    assert InCycle.from_json(base).yields is None  # stored before yields were kept
    assert InCycle.from_json(base).to_json() == base
    y = {"task": "t1", "person_task": "t0", "start": 5.8, "held": 2.0, "retreat": 0.4,
         "end": 12.9}
    new = InCycle.from_json({**base, "yields": [y]})
    assert new.yields == (Yield("t1", "t0", 5.8, 2.0, 0.4, 12.9),)
    assert new.to_json() == {**base, "yields": [y]}
    assert new.yielded == pytest.approx(7.1)


def test_the_mutual_hold_of_issue_34_no_longer_stops_the_run(capsys, tmp_path):
    """The seed and settings of the trial that stopped the reactive ablation (cycle 3 held
    both until t = 600 s and exited 2): the run goes on past it."""
    code, _, err = run_main(capsys, "run", "fetch", "--human", "slow-middle", "--adapt",
                            "spatial", "--execution", "reactive", "--reacts", "--seed", "70011",
                            "--particles", "2", "--candidates", "4", "--cycles", "4", "--out",
                            str(tmp_path / "out"))
    assert code == 0, err
    from rapidds.store import RunStore

    with RunStore.open_readonly(tmp_path / "out" / "run.sqlite") as store:
        recs = store.cycle_records()
    assert len(recs) == 4
    assert all(r.execution.in_cycle is not None and r.execution.in_cycle.yields is not None
               for r in recs)


def test_an_unresolvable_mutual_hold_is_exit_3_from_the_cli(capsys, tmp_path, monkeypatch):
    """The cell of the creeping-robot test above, from the command line: a robot that needs
    10^6 s to stop crawls wherever the person is, a person who pauses for any moving robot in
    the room. The robot yields until nothing can finish: a runtime fault, one line, exit 3 (not
    2, the bad-input code)."""
    from rapidds.worlds.fetch.world import FetchWorld
    from rapidds.worlds.reactions import ReactionPopulation

    monkeypatch.setattr(FetchWorld, "safety_limits", SafetyLimits(0.1, 1e6, 0.0, 0.0, 0.0))
    monkeypatch.setattr(FetchWorld, "reaction_population",
                        ReactionPopulation(comfort=(1e3, 0.0), stop=(1e3, 0.0)))
    code, _, err = run_main(capsys, "run", "fetch", "--human", "slow-middle", "--execution",
                            "reactive", "--reacts", "--slowdowns", "off", "--seed", "3",
                            "--cycles", "1", "--population", "8", "--generations", "2",
                            "--particles", "1", "--candidates", "2", "--out",
                            str(tmp_path / "out"))
    assert code == 3, err
    assert err.count("\n") == 1 and err.startswith("rapidds: error:"), err
    assert "cannot progress" in err


# -- directed speeds (issue 34 item 3) -----------------------------------------------------------
def _scene(human_v, robot_v):
    from rapidds.execution import Scene

    human = np.array([[0.0, 0.0], [0.0, 0.5]])
    robot = np.array([[2.0, 0.0], [3.0, 0.0]])
    return Scene(human, np.array(human_v, float), robot,
                 None if robot_v is None else np.array(robot_v, float), 4.0, 1.5)


def test_directed_speeds_count_only_what_closes_in():
    from rapidds.execution import directed_speeds

    # the person walks towards the robot at 1 u/s, the robot comes towards them at 2 u/s
    d, vh, vr = directed_speeds(_scene([[1.0, 0.0], [1.0, 0.0]], [[-2.0, 0.0], [-2.0, 0.0]]))
    assert d == pytest.approx(2.0) and vh == pytest.approx(1.0) and vr == pytest.approx(2.0)
    # walking away, or across: nothing towards (floored at 0, never a credit)
    _, vh, vr = directed_speeds(_scene([[-1.5, 0.0], [-1.5, 0.0]], [[2.0, 0.0], [0.0, 2.0]]))
    assert vh == 0.0 and vr == pytest.approx(0.0, abs=1e-12)
    # the fastest point's component counts, not only the closest pair's
    _, vh, _ = directed_speeds(_scene([[0.0, 0.0], [3.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]]))
    assert vh == pytest.approx(3.0 * 2.0 / np.hypot(2.0, 0.5))
    # a direction the monitor cannot know: the speed it has counts as towards
    _, vh, vr = directed_speeds(_scene([[-1.5, 0.0], [-1.5, 0.0]], None))
    assert vr == 4.0


def test_a_person_walking_away_no_longer_holds_the_robot():
    from rapidds.execution import SpeedSeparation
    from rapidds.worlds.reactions import SafetyLimits as Limits

    ssm = SpeedSeparation(Limits(0.5, 0.5, 0.2, 0.1, 0.05))
    away = _scene([[-1.5, 0.0], [-1.5, 0.0]], [[-4.0, 0.0], [-4.0, 0.0]])
    towards = _scene([[1.5, 0.0], [1.5, 0.0]], [[-4.0, 0.0], [-4.0, 0.0]])
    undirected = ssm.rate_at(2.0, 1.5, 4.0)  # what the monitor did with total speeds
    assert ssm.rate(towards) == pytest.approx(undirected)
    assert 0.0 < undirected < ssm.rate(away) < 1.0
    # the robot backing off (a yield) goes away from the person: allowed at full rate
    assert ssm.rate(towards.backwards()) == 1.0


def test_planned_execution_records_no_yields(fetch_policy):
    """People who react under the paper's open-loop robot: an in-cycle record, but no policy
    holds the robot, so no yield can happen and the record has no ``yields`` (unchanged)."""
    cfg = RunConfig(human="slow-middle", cycles=1, seed=7, reacts=True, **SMALL)
    (res,) = list(AdaptiveRun(cfg, fetch_policy).run())
    ic = res.execution.in_cycle
    assert ic is not None and ic.yields is None and "yields" not in res.to_json()
