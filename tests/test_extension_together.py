"""The three plug-ins of issue 32 together: a world (tests/tinyworld.py), a source (the camera
of test_extension_source) and an execution policy (the creeping robot of
test_extension_execution), each written outside the package, run one cycle as one run."""

from __future__ import annotations

from test_extension_execution import SEEN
from test_extension_source import CameraSource
from test_extension_world import tiny_policy
from tinyworld import TinyWorld

from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.worlds import make_world, register


def test_an_outside_world_source_and_execution_run_a_cycle_together() -> None:
    register("tiny-all", TinyWorld)
    world = make_world("tiny-all")
    policy = tiny_policy(world)
    cfg = RunConfig(world="tiny-all", human="quick", cycles=1, population=4, generations=2,
                    samples=8, particles=2, candidates=2, execution="creeping",
                    slowdowns="off")
    person = world.teammate("quick")
    run = AdaptiveRun(cfg, policy, world=world, teammate=person)
    SEEN.clear()
    res = run.step(CameraSource(world, person, answer=3))
    tasks = res.plan.best.schedule.tasks("human")
    assert tasks and set(res.record.observed) == set(tasks)  # the camera's observation
    assert res.record.comfort is not None and res.record.comfort["answer"] == 3
    assert SEEN  # the outside policy watched the cycle
    assert res.record.execution.in_cycle is not None  # an execution inside the cycle ran
    assert "-creeping" in run.config.run_id and run.next_cycle == 1
