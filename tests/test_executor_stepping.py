"""The executor's stepping API: a cycle advanced piece by piece (``advance_to``, as the browser
game does once per tick) is the cycle ``run()`` gives in one call, to the last bit, for the
paper's open loop (any cut) and for a reacting, deviating person beside the monitoring,
re-planning robot (cuts on the world's clock, the instants it watches anyway)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import SMALL_SEARCH as SMALL

from rapidds.errors import RapiddsError
from rapidds.execution import (
    CycleExecutor,
    CycleRules,
    Deployment,
    PlannedRobot,
    Replanning,
    SimulatedHuman,
    SpeedSeparation,
)
from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.worlds.reactions import Deviation, Reaction, cell_reactions


@pytest.fixture(scope="module")
def planned(fetch_policy):
    run = AdaptiveRun(RunConfig(human="slow-middle", cycles=1, seed=2, **SMALL), fetch_policy)
    return run, run.plan()


def _executor(run, plan, reactive: bool, deviation: Deviation | None = None) -> CycleExecutor:
    human = run.teammate.execute(plan.cycle, plan.best.schedule.tasks("human"),
                                 np.random.default_rng(5))
    rng = np.random.default_rng([5, 1])
    person = SimulatedHuman(run.world, human, lambda t: run.teammate.perform(t, rng),
                            Reaction(1.5, 0.7, 0.4) if reactive else None, deviation)
    _, limits = cell_reactions(run.world)
    mean, std = run.model.temporal.mean(), run.model.temporal.std()
    replanning = Replanning(mean=dict(zip(run.problem.ids, mean.tolist(), strict=True)),
                            std=dict(zip(run.problem.ids, std.tolist(), strict=True)),
                            robot={j: m.duration for j, m in plan.best.motions.items()},
                            spatial=lambda j, c: 0.0, gamma=run.problem.objective.gamma)
    return CycleExecutor(run.world, run.problem, plan.best.schedule, person,
                         PlannedRobot(run.world, plan.best.motions),
                         SpeedSeparation(limits) if reactive else None,
                         beta=run.model.spatial.config.beta,
                         rules=CycleRules(replanning=replanning if reactive else None,
                                          limits=limits))


def _same(a: Deployment, b: Deployment) -> None:
    assert np.array_equal(a.timeline.start, b.timeline.start)
    assert np.array_equal(a.timeline.finish, b.timeline.finish)
    assert a.timeline.schedule == b.timeline.schedule
    assert set(a.human) == set(b.human) and set(a.robot) == set(b.robot)
    for t in a.human:
        assert a.human[t].duration == b.human[t].duration
        assert np.array_equal(a.human[t].trajectory, b.human[t].trajectory)
    for j in a.robot:
        assert np.array_equal(a.robot[j], b.robot[j])
    strip = {"latency_s": 0.0}  # wall time of a re-plan, not what it decided
    assert [{**r, **strip} for r in a.replans] == [{**r, **strip} for r in b.replans]
    assert (a.pauses, a.cost, a.min_separation) == (b.pauses, b.cost, b.min_separation)
    assert dataclasses.replace(a, replans=()).protective == b.protective


def test_the_open_loop_cycle_stepped_at_any_cuts_is_the_one_run_gives(planned):
    run, plan = planned
    whole = _executor(run, plan, reactive=False).run()
    stepped = _executor(run, plan, reactive=False)
    with pytest.raises(RapiddsError, match="not over"):
        stepped.result()
    t, cuts = 0.0, 0
    while not stepped.advance_to(t := t + 0.37):
        cuts += 1
        assert stepped.now == pytest.approx(t)  # nothing past the cut
    assert cuts > 5
    _same(stepped.result(), whole)


@pytest.mark.parametrize("kind", ["take", "pause"])
def test_a_reactive_cycle_stepped_tick_by_tick_is_the_one_run_gives(planned, kind):
    run, plan = planned
    dev = Deviation(kind, pick=0.0, task=0, at=0.4, seconds=3.0)
    whole_ex = _executor(run, plan, reactive=True, deviation=dev)
    whole = whole_ex.run()
    stepped = _executor(run, plan, reactive=True, deviation=dev)
    dt, k = run.world.dt, 0
    while not stepped.advance_to((k := k + 1) * dt):
        pass
    _same(stepped.result(), whole)
    # something happened between the cuts: a re-plan, a pause (of the person or the robot)
    assert whole.replans or whole.pauses
