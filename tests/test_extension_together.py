"""The three plug-ins of issue 32 together: a world (tests/tinyworld.py), a source (the camera
of test_extension_source) and an execution policy (the creeping robot of
test_extension_execution), each written outside the package, run one cycle as one run."""

from __future__ import annotations

import numpy as np
from test_extension_execution import SEEN
from test_extension_source import CameraSource
from tinyworld import TinyWorld

from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.motion.config import DiffusionConfig
from rapidds.motion.demos import Demonstrations
from rapidds.motion.train import train_policy
from rapidds.worlds import make_world, register


def test_an_outside_world_source_and_execution_run_a_cycle_together() -> None:
    register("tiny-all", TinyWorld)
    world = make_world("tiny-all")
    d = world.robot_demonstrations(8, np.random.default_rng(0))
    demos = Demonstrations(d.trajectories.astype(np.float32), d.task_index, d.task_names)
    policy, _ = train_policy(demos, DiffusionConfig(
        horizon=world.horizon, state_dim=world.state_dim, task_names=d.task_names,
        down_dims=(8, 16), step_embed_dim=16, num_train_timesteps=50, num_inference_steps=4,
        batch_size=32, lr=3e-3, lr_warmup_steps=5, steps=60, device="cpu"))
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
