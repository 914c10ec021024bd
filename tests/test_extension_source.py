"""A source is a plug-in: a camera tracker written outside the package feeds a cycle.

The camera films the simulated fetch person at 20 Hz on its own clock (it started 100 s before
the cycle) and hands the loop what it saw: task events, tracked samples and the person's comfort
answer. Nothing in the package knows it; it implements ``observe(cycle) -> Observation`` and
turns its samples into executions with the one resampler, ``execution_of``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.loop.cycle import Cycle
from rapidds.loop.observation import Observation, Said, Source, Track, execution_of, resample
from rapidds.worlds.base import SimulatedTeammate, World

CAMERA_HZ = 20.0
CLOCK = 100.0  # the camera's clock at the cycle's time 0


@dataclass
class CameraSource:
    """The outside source: films ``person`` doing the cycle's tasks one after another."""

    world: World
    person: SimulatedTeammate
    answer: int = 5

    def observe(self, cycle: Cycle) -> Observation:
        human, events, t = {}, {}, CLOCK
        for task in cycle.best.schedule.tasks("human"):
            duration, path = self.person.perform(task, cycle.rng)
            rows = np.arange(len(path)) * self.world.dt  # the person's own samples
            seen = np.arange(0.0, duration + 1e-9, 1.0 / CAMERA_HZ)  # what the camera caught
            track = Track(t + seen, resample(np.minimum(rows, duration), path, seen))
            human[task] = execution_of(task, t, duration, track, self.world.dt)
            events[task] = (t, t + duration)
            t += duration
        return Observation(human=human, events=events, said=Said(self.answer, ()))


def _run(world: World, policy: object, small: dict[str, int]) -> AdaptiveRun:
    cfg = RunConfig(world="fetch", human="slow-middle", cycles=2, seed=5, **small)
    person = world.teammate("slow-middle")
    return AdaptiveRun(cfg, policy, world=world, teammate=person)  # type: ignore[arg-type]


def test_a_camera_source_from_outside_runs_a_cycle(fetch_world, fetch_policy, small) -> None:
    run = _run(fetch_world, fetch_policy, small)
    camera = CameraSource(fetch_world, fetch_world.teammate("slow-middle"))
    assert isinstance(camera, Source)
    res = run.step(camera)
    obs = res.plan.observation
    assert obs is not None and obs.said == Said(5, ())
    tasks = res.plan.best.schedule.tasks("human")
    assert tasks and set(res.record.observed) == set(tasks)
    for task in tasks:
        start, end = obs.events[task]
        assert res.record.observed[task] == pytest.approx(end - start, abs=1e-9)
        path = res.deployment.human[task].trajectory
        rows = int(np.ceil((end - start) / fetch_world.dt - 1e-9)) + 1
        assert path.shape == (rows, 2)  # back on the world's dt, in the world's 2-D
    assert res.record.comfort is not None and res.record.comfort["answer"] == 5
    assert run.next_cycle == 1

    again = _run(fetch_world, fetch_policy, small)  # the same seed: the same cycle
    same = again.step(CameraSource(fetch_world, fetch_world.teammate("slow-middle")))
    assert same.record.observed == res.record.observed
    assert same.record.plan == res.record.plan
