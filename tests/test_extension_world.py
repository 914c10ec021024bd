"""A world added from outside the package, in under 100 lines (tests/tinyworld.py, the worked
example of docs/architecture.md), runs a cycle; and what a world can do beyond the contract is
declared by name, listed, checked when the world is made, and asked for by name."""

from __future__ import annotations

import json
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import cli_cmd
from tinyworld import GOALS, HOME, H, TinyWorld, _walk

from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.motion.config import DiffusionConfig
from rapidds.motion.demos import Demonstrations
from rapidds.motion.interface import MotionPlan
from rapidds.motion.policy import DiffusionPolicy
from rapidds.motion.train import train_policy
from rapidds.schedule import Schedule
from rapidds.settings import ConfigError
from rapidds.web.game import FetchGame
from rapidds.worlds import make_world, register
from rapidds.worlds.base import joint_names
from rapidds.worlds.capabilities import CAPABILITIES, capabilities, capability, lacks
from rapidds.worlds.geometry import Rect
from rapidds.worlds.registry import UnknownWorldError

HERE = Path(__file__).resolve().parent


def test_the_example_world_is_under_100_lines() -> None:
    assert len((HERE / "tinyworld.py").read_text().splitlines()) < 100


def tiny_policy(world: TinyWorld) -> DiffusionPolicy:
    """A toy policy for ``world``, trained in a second from its own demonstrations."""
    d = world.robot_demonstrations(8, np.random.default_rng(0))
    demos = Demonstrations(d.trajectories.astype(np.float32), d.task_index, d.task_names)
    policy, _ = train_policy(demos, DiffusionConfig(
        horizon=world.horizon, state_dim=world.state_dim, task_names=d.task_names,
        down_dims=(8, 16), step_embed_dim=16, num_train_timesteps=50, num_inference_steps=4,
        batch_size=32, lr=3e-3, lr_warmup_steps=5, steps=60, device="cpu"))
    return policy


def test_a_world_from_outside_runs_a_cycle() -> None:
    register("tiny-ext", TinyWorld)
    world = make_world("tiny-ext")
    policy = tiny_policy(world)
    run = AdaptiveRun(RunConfig(world="tiny-ext", human="quick", cycles=1, population=4,
                                generations=2, samples=8, particles=2, candidates=2),
                      policy=policy)
    (record,) = run.run()
    human, robot = record.plan.tasks("human"), record.plan.tasks("robot")
    assert "c" in human  # the person-only task stays with the person
    assert sorted(human + robot) == ["a", "b", "c"]
    assert record.execution.realised.makespan > 0
    assert capabilities(world) == () and capability(world, "browser_play") is None
    assert joint_names(world) == ("joint1", "joint2")  # the spec names none


def test_capabilities_are_declared_listed_and_asked_by_name() -> None:
    fetch, painting = make_world("fetch"), make_world("painting")
    assert capability(fetch, "browser_play") is fetch
    assert capability(painting, "browser_play") is None
    assert capability(painting, "physics") is painting and capability(fetch, "physics") is None
    assert set(capabilities(fetch)) | set(capabilities(painting)) == set(CAPABILITIES)
    assert lacks(painting, "browser_play").startswith(
        "world painting does not declare the browser_play capability")
    with pytest.raises(ValueError, match="unknown world capability 'flying'"):
        capability(fetch, "flying")  # type: ignore[call-overload]


def test_a_declared_capability_the_world_lacks_is_refused_when_made() -> None:
    class Boasting(TinyWorld):
        spec = replace(TinyWorld.spec, capabilities=("physics",))

    register("boasting", Boasting)
    with pytest.raises(UnknownWorldError, match="declares physics but has no physics_model, "
                                                "place_person"):
        make_world("boasting")


@pytest.mark.parametrize(("change", "message"), [
    ({"capabilities": ("flying",)}, r"WorldSpec.capabilities\[0\]: .*\(got 'flying'\)"),
    ({"joint_names": ("x",)}, "1 joint names for a 2-D robot"),
    ({"workspace_bounds": ((0.0, 0.0), (0.0, 4.0))}, "lo < hi"),
    ({"views": {"top": (0, 2)}}, "view 'top' names axes"),
    ({"spatial_grid": 1}, "WorldSpec.spatial_grid: "),
])
def test_a_bad_spec_is_one_line(change: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message) as err:
        replace(TinyWorld.spec, **change)
    assert "\n" not in str(err.value)


def test_rapidds_worlds_lists_capabilities() -> None:
    out = subprocess.run(cli_cmd("worlds", "--json"), capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    assert "browser_play" in info["fetch"]["capabilities"]
    assert "physics" in info["painting"]["capabilities"]
    assert "browser_play" not in info["painting"]["capabilities"]


class PlayableTiny(TinyWorld):
    """The tiny room with a pillar, declared playable in the browser: its floor's members."""

    spec = replace(TinyWorld.spec, capabilities=("browser_play",))
    reach_radius = 0.3

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.workspace_bounds

    def home(self, agent: str) -> np.ndarray:
        return HOME[agent].copy()

    def object_position(self, task: str) -> np.ndarray:
        return GOALS[task].copy()

    def obstacles(self) -> tuple[Rect, ...]:
        return (Rect(2.0, 1.7, 2.4, 2.3),)


def test_the_browser_game_plays_any_world_that_declares_it_can() -> None:
    register("tiny-play", PlayableTiny)
    world = capability(make_world("tiny-play"), "browser_play")
    assert world is not None
    traj = _walk("robot", "b", 2.0, H)
    motion = MotionPlan("b", frozenset(), float(world.completion_time("b", traj[None])[0]),
                        0.0, traj)
    game = FetchGame(world, world.problem(), Schedule(("c", "a"), ("b",)), {"b": motion})
    game.start()
    while not game.over and game.now < 60.0:
        state = game.state()
        task = state["cur"]
        goal = world.home("human") if task is None or task in state["times"] else \
            world.object_position(task)
        game.steer(target=(float(goal[0]), float(goal[1])))
        game.step()
    assert game.over and game.order == ["c", "a"]  # a waited for the robot's b
    seen = game.observations()
    assert set(seen) == {"c", "a"} and all(ex.duration > 0 for ex in seen.values())
    assert game.start_time["a"] >= game.finish_time["b"]
    assert game.state()["tasks"] == {"a": "done", "b": "done", "c": "done"}
