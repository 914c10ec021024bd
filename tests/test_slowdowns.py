"""Plans that expect the safety monitor: the predicted hold (the monitor's own S_p over a
steered trajectory against the path belief), its learned correction, and the run that plans with
them; the paper's planned execution unchanged."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_helpers import run_main
from conftest import SMALL_SEARCH as SMALL

from rapidds.errors import ConfigError
from rapidds.execution import Scene, SpeedSeparation
from rapidds.execution.policies import directed_arrays, monitor_rates
from rapidds.execution.slowdowns import (
    HoldModel,
    _towards_point,
    approach_speeds,
    directed_rates,
    predicted_hold,
)
from rapidds.human.slowdowns import MIN_PREDICTED, SlowdownBelief
from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.loop.model import HumanModel, prior_model
from rapidds.motion.interface import FixedDurationMotion, MotionPlan, TrajectoryCache
from rapidds.problem import problem_from_dict
from rapidds.record import CycleRecord
from rapidds.schedule import Schedule
from rapidds.scheduler import EvaluationContext, evaluate_population
from rapidds.worlds.reactions import SafetyLimits, cell_reactions
from rapidds.worlds.registry import make_world

LIMITS = SafetyLimits(reaction_time=0.1, stopping_time=0.3, intrusion=0.2, sensing=0.1,
                      position=0.05)


def test_the_predicted_rate_is_the_monitors_rate():
    rng = np.random.default_rng(0)
    sep = rng.uniform(0, 4, 2000)
    vh = rng.uniform(0, 3, 2000)
    vr = np.where(rng.random(2000) < 0.1, 0.0, rng.uniform(0, 6, 2000))
    got = monitor_rates(LIMITS, sep, vh, vr)
    monitor = SpeedSeparation(LIMITS)
    want = np.array([monitor.rate_at(s, h, r) for s, h, r in zip(sep, vh, vr, strict=True)])
    assert np.allclose(got, want, atol=1e-12)
    assert 0 < (got == 0).sum() < 2000 and 0 < (got == 1).sum() < 2000


@pytest.mark.parametrize("dim", [2, 3])
def test_the_vectorised_directed_rate_is_the_executors_per_tick_rate(dim):
    """Random instants with velocities (3 person's points, 4 robot points): one batched call of
    the planner's computation against the policy the executor asks at every tick."""
    rng = np.random.default_rng(dim)
    n = 1000
    human = rng.uniform(-1.5, 1.5, (n, 3, dim))
    robot = rng.uniform(-1.5, 1.5, (n, 4, dim))
    h_vel = rng.normal(0, 1.5, (n, 3, dim))
    r_vel = rng.normal(0, 2.0, (n, 4, dim))
    got = monitor_rates(LIMITS, *directed_arrays(human, h_vel, robot, r_vel))
    monitor = SpeedSeparation(LIMITS)
    want = np.array([monitor.rate(Scene(human[k], h_vel[k], robot[k], r_vel[k]))
                     for k in range(n)])
    assert np.array_equal(got, want)
    assert 0 < (got == 0).sum() < n and 0 < ((got > 0) & (got < 1)).sum() < n


def test_the_directed_prediction_counts_only_what_closes_in():
    """A robot point 0.6 m above a route (the x axis): moving along the route it is held less
    than moving straight at it, and a person who passes (approach speed 0.2) holds it less than
    one who walks straight at it (1.6); total speeds would have held it most."""
    robot = np.array([[[0.0, 0.6]]])  # (1, P=1, 2)
    dist, grad = np.array([[0.6]]), np.array([[0.0, 1.0]])

    def rate(velocity: list[float], approach: float) -> float:
        return float(directed_rates(LIMITS, robot, np.array([[velocity]]), dist, grad,
                                    np.array([approach]))[0])

    total = monitor_rates(LIMITS, np.array(0.6), np.array(1.6), np.array(2.0))
    assert total == rate([0.0, -2.0], 1.6) < rate([0.0, -2.0], 0.2) < rate([2.0, 0.0], 0.2)
    assert rate([0.0, 2.0], 1.6) == rate([2.0, 0.0], 1.6)  # moving away: v_r = 0


def test_the_approach_speed_is_the_full_speed_head_on_and_little_in_passing(fetch_holds):
    world, spatial, model = fetch_holds
    fastest = {t: max(np.linalg.norm(np.diff(np.asarray(p, float).reshape(len(p), -1, 2),
                                             axis=0), axis=-1).max() for p in paths) / world.dt
               for t, paths in world.prior().paths.items()}
    for t, v in model.speeds.items():
        assert v.shape == (len(spatial.config.grid()),)
        assert (v >= -1e-9).all() and (v <= fastest[t] + 1e-9).all()
        assert v.max() > 0.5 * float(np.median(v)) and v.min() < v.max()
    # the written-out computation is the monitor's directed speeds for one still point
    rng = np.random.default_rng(1)
    pts, vel, x = rng.normal(size=(6, 3, 2)), rng.normal(size=(6, 3, 2)), rng.normal(size=(5, 2))
    sep, v_h = _towards_point(pts, vel, x)
    want = directed_arrays(pts[None], vel[None], x[:, None, None, :], np.zeros((5, 1, 1, 2)))
    assert np.allclose(sep, want[0]) and np.allclose(v_h, want[1])


def test_the_predicted_hold_counts_the_slowed_steps_of_the_moving_motion():
    far = np.full((1, 5), 10.0)
    speed = np.full((1, 5), 2.0)
    moving = np.ones((1, 5), dtype=bool)
    assert predicted_hold(LIMITS, far, np.array(1.0), speed, moving, 0.2)[0] == 0.0
    near = far.copy()
    near[0, 2] = 0.0  # one step inside S_p(0): stopped, counted at the floor rate 0.1
    assert predicted_hold(LIMITS, near, np.array(1.0), speed, moving, 0.2)[0] == \
        pytest.approx(0.2 * 9)
    done = moving.copy()
    done[0, 2:] = False  # the motion is over by then: nothing to hold
    assert predicted_hold(LIMITS, near, np.array(1.0), speed, done, 0.2)[0] == 0.0


def test_the_correction_is_the_conjugate_inverse_gamma_update():
    b = SlowdownBelief(1.0, 0.5)
    a0 = 2 + (1.0 / 0.5) ** 2
    assert b.factor("t1", "t0") == pytest.approx(1.0)
    assert b.observe("t1", "t0", 2.0, 0.0)  # predicted 2 s, lost nothing: theta goes down
    assert b.factor("t1", "t0") == pytest.approx((a0 - 1) / a0)
    assert b.observe("t1", "t0", 2.0, 12.0)  # lost 6x the prediction: up again
    assert b.factor("t1", "t0") == pytest.approx((a0 - 1 + 6) / (a0 + 1))
    assert b.factor("t3", "t2") == pytest.approx(1.0)  # other pairs keep the prior
    assert not b.observe("t3", "t2", MIN_PREDICTED / 2, 5.0)  # no ratio to a prediction of 0
    assert b.factor("t3", "t2") == pytest.approx(1.0)
    back = SlowdownBelief.from_dict(json.loads(json.dumps(b.to_dict())))
    assert back.pairs == b.pairs and back.summary() == b.summary()
    assert b.summary()["t1|t0"]["n"] == 2
    with pytest.raises(ValueError, match="lost time"):
        b.observe("t1", "t0", 1.0, -1.0)
    with pytest.raises(ValueError, match="prior"):
        SlowdownBelief(-1.0, 1.0)


def test_the_makespan_adds_the_predicted_hold_to_the_robots_motion():
    problem = problem_from_dict({"name": "held", "tasks": [
        {"id": "a", "allowed": ["human"], "human": {"mean": 3.0, "std": 0.5}},
        {"id": "b", "allowed": ["robot"], "robot": {"duration": 2.0}},
        {"id": "c", "allowed": ["robot"], "robot": {"duration": 2.0}}],
        "precedence": [["b", "c"]]})

    class Held(FixedDurationMotion):
        def plan(self, requests):
            return [MotionPlan(p.task, p.concurrent, p.duration, hold=1.5 * bool(p.concurrent))
                    for p in super().plan(requests)]

    sched = Schedule(("a",), ("b", "c"))
    n = len(problem.tasks)
    args = (problem, np.full((4, n), 3.0), np.full(n, 3.0))
    base = evaluate_population(EvaluationContext(
        *args, TrajectoryCache(FixedDurationMotion(problem)),
        FixedDurationMotion(problem).nominal_durations(problem), 0, 0), [sched])[0]
    held = evaluate_population(EvaluationContext(
        *args, TrajectoryCache(Held(problem)), Held(problem).nominal_durations(problem), 0, 0),
        [sched])[0]
    assert base.makespan_mean == pytest.approx(4.0)
    # b runs beside a and is held 1.5 s; c starts after a ended (3.5 s > 3 s): nothing to hold
    assert held.makespan_mean == pytest.approx(2.0 + 1.5 + 2.0)
    assert held.overlaps == {"b": frozenset({"a"}), "c": frozenset()}


@pytest.fixture(scope="module")
def fetch_holds():
    world = make_world("fetch")
    cfg = RunConfig(human="slow-middle").resolved(world)
    spatial = prior_model(world, cfg).spatial
    limits = cell_reactions(world)[1]
    return world, spatial, HoldModel(world, spatial, limits,
                                     approach_speeds(world, spatial, limits))


def test_a_motion_across_the_persons_route_is_predicted_to_be_held(fetch_holds):
    world, _, model = fetch_holds
    path = np.asarray(world.prior().paths["t0"][0], dtype=float).reshape(-1, 2)
    mid = path[len(path) // 2]
    lo, hi = (np.asarray(b, float) for b in world.workspace_bounds)
    corner = lo if np.linalg.norm(mid - lo) > np.linalg.norm(mid - hi) else hi
    h = world.horizon
    across = np.linspace(mid - 1.0, mid + 1.0, h)[None]
    away = np.repeat(corner[None], h, axis=0)[None] + np.linspace(0, 0.3, h)[None, :, None]
    got_across = model.raw("t1", ["t0"], np.asarray(across))["t0"][0]
    got_away = model.raw("t1", ["t0"], np.asarray(away))["t0"][0]
    assert got_across > 0.5 and got_away == 0.0
    model.belief = SlowdownBelief(0.5, 0.1)
    assert model.hold("t1", ["t0"], across)[0] == pytest.approx(0.5 * got_across)
    assert model.hold("t1", [], across)[0] == 0.0


@pytest.mark.parametrize(("args", "says"), [
    (["--slowdown-mean", "-1"], "--slowdown-mean"),
    (["--slowdown-sd", "0"], "--slowdown-sd"),
    (["--slowdowns", "sometimes"], "--slowdowns"),
    (["--slowdowns", "learned"], "reactive"),  # planned execution has no monitor to expect
])
def test_bad_slowdown_settings_are_one_line_errors(capsys, args, says):
    code, _, err = run_main(capsys, "run", "--cycles", "1", "--execution",
                            "reactive" if says != "reactive" else "planned", *args)
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("rapidds: error:") and says in err, err


def test_slowdowns_default_to_learned_under_reactive_execution_only():
    world = make_world("fetch")
    assert RunConfig(execution="reactive").resolved(world).slowdowns == "learned"
    assert RunConfig().resolved(world).slowdowns is None
    assert RunConfig().slowdown_mode == "off"
    assert RunConfig(execution="reactive", slowdowns="off").run_id.endswith("-noslow-s0")
    assert RunConfig(execution="reactive").run_id == "fetch-None-full-reactive-s0"
    with pytest.raises(ConfigError):
        RunConfig(slowdowns="predicted")


def test_a_reactive_run_plans_with_and_learns_its_slowdowns(fetch_policy, tmp_path):
    cfg = RunConfig(human="slow-middle", adapt="none", cycles=2, seed=5, execution="reactive",
                    reacts=True, **SMALL)
    run = AdaptiveRun(cfg, fetch_policy)
    records = run.run()
    for rec in records:
        s = rec.slowdowns
        assert s is not None and s.mode == "learned"
        assert set(s.lost) <= set(rec.tasks("robot")) or rec.execution.in_cycle is not None
        assert all(v >= 0 for v in s.lost.values()) and all(
            p >= 0 and lost >= 0 for p, lost in s.pairs.values())
        back = CycleRecord.from_json(json.loads(json.dumps(rec.to_json())))
        assert back.slowdowns == s
    belief = HumanModel.from_bytes(run.model.to_bytes()).slowdowns
    assert belief is not None and belief.pairs == run.model.slowdowns.pairs
    learned = {k for k, (p, _) in records[0].slowdowns.pairs.items() if p >= MIN_PREDICTED}
    assert all(belief.pairs[k][2] >= 1 for k in learned)


def test_a_monitored_run_on_the_device_path_scores_its_holds_there(fetch_policy, monkeypatch):
    """With steering on the device (forced here on the CPU, as benchmarks do), a run that
    plans for the monitor scores its candidates, hold included, as tensor operations: the
    value handed to steering is a tensor value, never the host's fallback."""
    import rapidds.motion.diffusion_motion as dm
    from rapidds.motion.steering import TensorValue

    kinds: list[bool] = []
    real = dm.steer

    def watched(policy, request, value, **kw):
        kinds.append(isinstance(value, TensorValue))
        return real(policy, request, value, **kw)

    monkeypatch.setattr(dm, "steer", watched)
    monkeypatch.setattr(dm.DiffusionMotion, "default_on_device", True)
    cfg = RunConfig(human="slow-middle", adapt="none", cycles=1, seed=5, execution="reactive",
                    **SMALL)
    rec = AdaptiveRun(cfg, fetch_policy).run()[0]
    assert kinds and all(kinds)
    assert rec.slowdowns is not None and set(rec.slowdowns.predicted) == set(rec.tasks("robot"))


def test_a_planned_run_has_no_slowdowns_in_its_record_or_model(fetch_policy):
    run = AdaptiveRun(RunConfig(human="slow-middle", cycles=1, seed=5, **SMALL), fetch_policy)
    rec = run.run()[0]
    assert rec.slowdowns is None and "slowdowns" not in rec.to_json()
    assert run.model.slowdowns is None
    assert not json.dumps(rec.to_json()).count("hold")


def test_a_resumed_run_learns_its_slowdowns_as_an_uninterrupted_one(tmp_path):
    from record_helpers import decided

    from rapidds.store import RunStore

    # painting: its arm passes the person's reach, so holds are predicted and learned
    cfg = RunConfig(world="painting", cycles=2, seed=2, execution="reactive", reacts=True,
                    population=8, generations=2, samples=8, patience=2, particles=1,
                    candidates=2)
    with RunStore(tmp_path / "a.sqlite") as store:
        whole = AdaptiveRun(cfg, store=store).run()
        state = store.state(cfg.resolved(make_world("painting")).run_id, 1)
    with RunStore(tmp_path / "b.sqlite") as store:
        AdaptiveRun(cfg, store=store).step()  # then the process dies
    with RunStore(tmp_path / "b.sqlite") as store:
        resumed = AdaptiveRun(cfg, store=store)
        assert resumed.next_cycle == 1 and resumed.model.slowdowns is not None
        rest = resumed.run()
        assert store.state(resumed.config.run_id, 1) == state

    assert [decided(r) for r in whole[1:]] == [decided(r) for r in rest]
    assert all(r.slowdowns is not None for r in whole)
