"""The world contract, checked for every registered world, and a second world that runs through
``rapidds run`` by name without any change to the loop or the CLI."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import cli_cmd

from rapidds.errors import RapiddsError
from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.worlds import World, make_world, register, world_names
from rapidds.worlds.base import SimulatedTeammate, body_points
from rapidds.worlds.registry import UnknownWorldError

HERE = Path(__file__).resolve().parent
register("tiny", "tinyworld:TinyWorld")
WORLDS = world_names()


@pytest.fixture(scope="module", params=WORLDS)
def world(request) -> World:
    return make_world(request.param)


def test_every_world_keeps_the_contract(world: World) -> None:
    assert isinstance(world, World)
    assert world.variant in world.variants
    assert world.horizon % 8 == 0 and world.dt > 0
    problem = world.problem()
    assert problem.ids == world.task_ids
    lo, hi = world.workspace_bounds
    assert lo.shape == hi.shape == (world.workspace_dim,) and np.all(lo < hi)
    assert world.spatial_beta > 0 and world.spatial_grid >= 2
    for view, (i, j) in world.views.items():
        assert view and 0 <= i < world.workspace_dim and 0 <= j < world.workspace_dim

    # one population for both priors: every human task has durations and paths
    prior = world.prior()
    human_tasks = [t.id for t in problem.tasks if t.can("human")]
    for t in human_tasks:
        d = np.asarray(prior.durations[t])
        assert len(d) >= 2 and np.all(d > 0)
        task = problem.task(t)
        assert task.human_mean == pytest.approx(d.mean(), abs=0.006)
        for path in prior.paths[t]:
            pts = body_points(path)
            assert pts.shape[-1] == world.workspace_dim and np.isfinite(pts).all()

    rest = world.robot_rest()
    assert rest.shape == (world.state_dim,)
    pts = world.robot_points(np.broadcast_to(rest, (3, world.horizon, world.state_dim)))
    assert pts.shape[:2] == (3, world.horizon) and pts.shape[-1] == world.workspace_dim
    assert world.human_rest().shape[-1] == world.workspace_dim

    demos = world.robot_demonstrations(2, np.random.default_rng(0))
    assert demos.trajectories.shape[1:] == (world.horizon, world.state_dim)
    for traj, k in zip(demos.trajectories, demos.task_index, strict=True):
        task = demos.task_names[k]
        assert problem.task(task).can("robot")
        done = world.completion_time(task, traj[None])[0]
        assert 0 < done < world.horizon * world.dt  # every demonstration completes its task
        assert isinstance(world.motion_label(task, traj), str)

    for name in world.teammate_names:
        person = world.teammate(name)
        assert isinstance(person, SimulatedTeammate)
        done = person.execute(0, human_tasks, np.random.default_rng(1))
        assert list(done) == human_tasks
        for t, ex in done.items():
            assert ex.task == t and ex.duration > 0
            assert body_points(ex.trajectory).shape[-1] == world.workspace_dim
        truth = person.true_mean_durations()
        assert all(truth[t] > 0 for t in human_tasks)
    with pytest.raises((ValueError, RapiddsError)):
        world.teammate("no-such-person")


def test_unknown_worlds_and_variants_are_one_line_errors() -> None:
    with pytest.raises(UnknownWorldError, match="unknown world 'moon'; available: fetch"):
        make_world("moon")
    with pytest.raises(UnknownWorldError, match="has no variant"):
        make_world("tiny", "upside-down")
    with pytest.raises(RapiddsError, match="unknown human 'nobody' for world tiny"):
        AdaptiveRun(RunConfig(world="tiny", human="nobody"), policy=object())  # type: ignore[arg-type]


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "RAPIDDS_WORLDS": "tiny=tinyworld:TinyWorld",
           "PYTHONPATH": os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run(cli_cmd(*args),
                          capture_output=True, text=True, env=env, timeout=300)


@pytest.mark.slow
def test_a_new_world_trains_and_runs_by_name(tmp_path: Path) -> None:
    listed = _cli("worlds", "--json")
    assert listed.returncode == 0, listed.stderr
    assert json.loads(listed.stdout)["tiny"]["teammates"] == ["steady", "quick"]

    trained = _cli("train-policy", "--world", "tiny", "--out", str(tmp_path / "policy"),
                   "--demos-per-mode", "16", "--seed", "0")
    assert trained.returncode == 0, trained.stderr
    run = _cli("run", "tiny", "--human", "quick", "--cycles", "3", "--policy",
               str(tmp_path / "policy"), "--population", "8", "--generations", "4",
               "--samples", "8", "--particles", "2", "--candidates", "2", "--json",
               "--out", str(tmp_path / "run"))
    assert run.returncode == 0, run.stderr
    records = [json.loads(line) for line in run.stdout.splitlines()]
    assert [r["cycle"] for r in records] == [0, 1, 2]
    for r in records:
        assert "c" in r["human"]  # the person-only task stays with the person
        assert set(r["human"]) | set(r["robot"]) >= {"a", "b", "c"}
        assert r["realised"]["makespan"] > 0
    assert (tmp_path / "run" / "tiny-quick-full-s0-map.png").is_file()
