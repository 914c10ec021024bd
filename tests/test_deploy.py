"""Deployment: the realised timeline obeys precedence, waits and agent order as they happen."""

import numpy as np
import pytest

from rapidds.human.spatial import point_cost
from rapidds.loop.deploy import HumanExecution, deploy
from rapidds.motion.interface import MotionPlan
from rapidds.problem import Problem, Task
from rapidds.schedule import Schedule, Wait, compile_schedule

BOTH = frozenset({"human", "robot"})


def _random_schedule(problem: Problem, rng: np.random.Generator) -> Schedule:
    """A random feasible schedule with waits: random assignment and precedence-respecting order."""
    while True:
        order = list(problem.ids)
        rng.shuffle(order)
        seqs: dict[str, list] = {"human": [], "robot": []}
        for t in order:
            seqs[str(rng.choice(["human", "robot"]))].append(t)
        for agent in ("human", "robot"):
            other = "robot" if agent == "human" else "human"
            if seqs[other] and rng.random() < 0.7:
                pos = int(rng.integers(0, len(seqs[agent]) + 1))
                seqs[agent].insert(pos, Wait(str(rng.choice(seqs[other]))))
        s = Schedule(tuple(seqs["human"]), tuple(seqs["robot"]))
        if compile_schedule(problem, s) is not None:
            return s


def _observed(schedule: Schedule, durations: dict[str, float]) -> dict[str, HumanExecution]:
    """A person standing still at the origin for the given durations."""
    return {t: HumanExecution(t, durations[t], np.zeros((int(np.ceil(durations[t] / 0.2)) + 1, 2)))
            for t in schedule.tasks("human")}


def test_realised_timeline_obeys_precedence_waits_and_order(fetch_world):
    problem = Problem(
        "p", tuple(Task(f"t{i}", BOTH, 3.0, 1.0, 2.0) for i in range(6)),
        precedence=(("t0", "t2"), ("t1", "t2"), ("t2", "t4"), ("t3", "t5")),
    )
    rng = np.random.default_rng(0)
    checked_waits = 0
    for _ in range(200):
        s = _random_schedule(problem, rng)
        human_d = {t: float(rng.uniform(0.5, 6.0)) for t in problem.ids}
        motions = {t: MotionPlan(t, frozenset(), float(rng.uniform(0.5, 6.0)), 0.0,
                                 np.zeros((4, 2))) for t in s.tasks("robot")}
        dep = deploy(fetch_world, problem, s, motions, _observed(s, human_d), beta=1.0)
        idx = problem.index
        st, fi = dep.timeline.start[0], dep.timeline.finish[0]
        for a, b in problem.precedence:
            assert fi[idx[a]] <= st[idx[b]] + 1e-9
        for agent in ("human", "robot"):
            gate = 0.0
            for item in s.sequence(agent):
                if isinstance(item, Wait):
                    gate = max(gate, fi[idx[item.task]])
                    checked_waits += 1
                    continue
                assert st[idx[item]] >= gate - 1e-9  # after the previous item and every wait
                gate = fi[idx[item]]
            for t in s.tasks(agent):  # actual durations were used
                want = human_d[t] if agent == "human" else motions[t].duration
                assert fi[idx[t]] - st[idx[t]] == pytest.approx(want)
        assert dep.makespan == pytest.approx(fi.max())
    assert checked_waits > 50


def test_fetch_costs_match_their_definition(fetch_world):
    world = fetch_world
    problem = world.problem().with_objective(gamma=1.75)
    person = world.teammate("fast-middle")
    s = Schedule(("t2", "t0"), ("t3", "t1"))
    motions = {}
    for j, mode in (("t3", "middle"), ("t1", "direct")):
        traj = world.robot_trajectory(j, mode)
        motions[j] = MotionPlan(j, frozenset(), float(world.completion_time(j, traj[None])[0]),
                                0.0, traj)
    human = person.execute(0, s.tasks("human"), np.random.default_rng(3))
    dep = deploy(world, problem, s, motions, human, beta=1.0)
    # t3 (robot, middle) runs while the human does t2 by the middle route: they meet
    assert "t2" in dep.overlaps["t3"]
    want = point_cost(motions["t3"].trajectory, dep.human["t2"].trajectory, 1.0).max()
    assert dep.spatial_by_task["t3"] == pytest.approx(want)
    assert dep.spatial_by_task["t3"] > 0.5
    assert dep.cost == pytest.approx(dep.makespan + 1.75 * dep.spatial)
    assert dep.min_separation < 1.5
    # the robot's outside route keeps its distance from the same person
    out = world.robot_trajectory("t3", "outside")
    motions["t3"] = MotionPlan("t3", frozenset(), float(world.completion_time("t3", out[None])[0]),
                               0.0, out)
    far = deploy(world, problem, s, motions, human, beta=1.0)
    assert far.min_separation > dep.min_separation + 1.0
    assert far.spatial_by_task["t3"] < dep.spatial_by_task["t3"]


def test_deadlocked_schedule_is_refused(fetch_world):
    problem = Problem("p", (Task("a", BOTH, 1.0, 0.0, 1.0), Task("b", BOTH, 1.0, 0.0, 1.0)))
    s = Schedule((Wait("b"), "a"), (Wait("a"), "b"))
    with pytest.raises(ValueError, match="deadlocked"):
        deploy(fetch_world, problem, s, {}, {}, beta=1.0)
