"""Steered motions carried across cycles: reused exactly while the spatial models they were
steered against are unchanged, steered again as soon as one of them moves."""

from __future__ import annotations

import numpy as np
import pytest
from record_helpers import stored

from rapidds.loop import AdaptiveRun, HumanModel, RunConfig
from rapidds.loop.carry import CarriedMotions, spatial_stamps
from rapidds.loop.model import prior_model, workspace_cost
from rapidds.motion.diffusion_motion import DiffusionMotion, SteeringConfig


@pytest.fixture()
def belief(fetch_world):
    return prior_model(fetch_world, RunConfig().resolved(fetch_world)).spatial


def _motion(world, policy, spatial):
    return DiffusionMotion(policy, world.completion_time, workspace_cost(world, spatial), 1.75,
                           SteeringConfig(particles=2, candidates=2, seed=0))


def test_unchanged_models_reuse_and_a_moved_model_steers_again(fetch_world, fetch_policy, belief):
    keys = [("t3", frozenset({"t2"})), ("t1", frozenset({"t0"})), ("t0", frozenset())]
    carried: dict = {}
    first = CarriedMotions(_motion(fetch_world, fetch_policy, belief), carried,
                           spatial_stamps(belief))
    plans = first.plan(keys)
    assert first.inner.calls == 1 and first.reused == 0 and set(carried) == set(keys)

    again = CarriedMotions(_motion(fetch_world, fetch_policy, belief), carried,
                           spatial_stamps(belief))
    assert again.plan(keys) == plans and again.inner.calls == 0 and again.reused == 3

    belief.observe("t2", fetch_world.teammate("fast-middle").perform("t2",
                                                                    np.random.default_rng(0))[1])
    moved = CarriedMotions(_motion(fetch_world, fetch_policy, belief), carried,
                           spatial_stamps(belief))
    replanned = moved.plan(keys)
    assert moved.inner.calls == 1 and moved.reused == 2  # only the request beside t2 is new
    assert replanned[1:] == plans[1:] and replanned[0] is not plans[0]


def test_presteering_answers_every_moved_request_in_the_cycles_first_batch(
        fetch_world, fetch_policy, belief):
    """On a device the moved carried requests join the first request's steering batch, so a
    later ask for one is answered from it: one steering call for the cycle."""
    keys = [("t3", frozenset({"t2"})), ("t1", frozenset({"t2"})), ("t0", frozenset())]
    carried: dict = {}
    CarriedMotions(_motion(fetch_world, fetch_policy, belief), carried,
                   spatial_stamps(belief)).plan(keys)
    belief.observe("t2", fetch_world.teammate("fast-middle").perform("t2",
                                                                    np.random.default_rng(0))[1])
    old = dict(carried)
    on_host = CarriedMotions(_motion(fetch_world, fetch_policy, belief), dict(carried),
                             spatial_stamps(belief))
    assert not on_host.presteer  # the CPU keeps the stored records' batches
    first = CarriedMotions(_motion(fetch_world, fetch_policy, belief), carried,
                           spatial_stamps(belief), presteer=True)
    assert first.plan([keys[0]])[0] is carried[keys[0]][0]
    assert first.inner.calls == 1 and first.inner.rows == 2 * 2 * 2  # both moved requests
    assert carried[keys[1]][0] is not old[keys[1]][0]                  # steered again
    assert first.plan(keys)[1] is carried[keys[1]][0] and first.inner.calls == 1
    assert first.reused == 3  # the second ask: every plan is current
    device = _motion(fetch_world, fetch_policy, belief)
    device.on_device = True
    assert CarriedMotions(device, {}, spatial_stamps(belief)).presteer


def test_runs_without_spatial_learning_steer_only_new_requests_after_cycle_0(fetch_policy, small):
    run = AdaptiveRun(RunConfig(human="slow-middle", adapt="none", cycles=4, seed=2, **small),
                      fetch_policy)
    recs = run.run()
    assert recs[0].search["motions_reused"] == 0
    assert sum(r.search["motions_reused"] for r in recs[1:]) > 0
    fresh = AdaptiveRun(RunConfig(human="slow-middle", adapt="none", cycles=4, seed=2,
                                  reuse_motions=False, **small), fetch_policy).run()
    assert all(r.search["motions_reused"] == 0 for r in fresh)
    assert stored(recs[0]) == stored(fresh[0])  # cycle 0 is the same


def test_carried_motions_survive_a_round_trip_of_the_state(fetch_policy, small):
    run = AdaptiveRun(RunConfig(human="fast-outside", cycles=2, seed=1, **small), fetch_policy)
    run.run()
    back = HumanModel.from_bytes(run.model.to_bytes())
    assert set(back.motions) == set(run.model.motions) and back.motions
    for key, (plan, stamps) in run.model.motions.items():
        got, got_stamps = back.motions[key]
        assert got_stamps == stamps and got.duration == plan.duration
        np.testing.assert_array_equal(got.trajectory, plan.trajectory)


def test_carried_trajectories_use_the_model_codec_and_old_lists_still_read() -> None:
    """One codec for a model's arrays (rapidds.codec), bit-exact; a state stored before it
    (trajectories as lists of floats) reads back the same."""
    from rapidds.loop.carry import decode_plans, encode_plans
    from rapidds.motion.interface import MotionPlan

    traj = np.random.default_rng(0).normal(size=(16, 2))
    carried = {("t3", frozenset({"t2"})): (MotionPlan("t3", frozenset({"t2"}), 4.25, 0.125, traj),
                                          {"t2": "abc"})}
    items = encode_plans(carried)
    assert set(items[0]["trajectory"]) == {"dtype", "shape", "data"}
    old = [{**items[0], "trajectory": traj.tolist()}]
    for kept in (items, old):
        (plan, stamps), = decode_plans(kept).values()
        assert stamps == {"t2": "abc"} and plan.duration == 4.25
        assert plan.trajectory.dtype == np.float64
        np.testing.assert_array_equal(plan.trajectory, traj)
