"""The painting value as tensor operations (issue 36, item 2): the terms a GPU scores the
steering candidates with, checked on the CPU against the world's numpy terms, which stay the
CPU's path and the stored records' reference."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten

from rapidds.execution.slowdowns import HoldModel
from rapidds.human.slowdowns import SlowdownBelief
from rapidds.human.spatial import SpatialConfig, SpatialModel
from rapidds.loop.model import device_terms, host_terms, workspace_cost
from rapidds.loop.run import load_policy
from rapidds.motion.diffusion_motion import DiffusionMotion, SteeringConfig, ValueTerms
from rapidds.motion.steering import TensorValue
from rapidds.worlds.base import World
from rapidds.worlds.painting import PaintingWorld


@pytest.fixture(scope="module")
def world() -> PaintingWorld:
    return PaintingWorld(prior_people=8)


@pytest.fixture(scope="module")
def paths(world: PaintingWorld) -> np.ndarray:
    """Demonstrations, noisy copies (many not executable or never completing) and wild ones."""
    rng = np.random.default_rng(5)
    demos = np.asarray(world.robot_demonstrations(2, rng).trajectories)
    noisy = demos[rng.integers(0, len(demos), 40)] + rng.normal(0.0, 0.2, (40, 64, 7))
    wild = rng.uniform(-3.0, 3.0, (8, 64, 7))
    return np.concatenate([demos, noisy, wild])


def _population_spatial(world: World) -> SpatialModel:
    lo, hi = world.workspace_bounds
    cfg = SpatialConfig.from_box(lo, hi, beta=world.spatial_beta, grid_points=world.spatial_grid)
    return SpatialModel.from_population(cfg, world.prior().paths)


@pytest.fixture(scope="module")
def spatial(world: PaintingWorld) -> SpatialModel:
    return _population_spatial(world)


def _holds(world: PaintingWorld, spatial: SpatialModel,
           belief: SlowdownBelief | None = None) -> HoldModel:
    """The painting cell monitor's predicted hold, at the cell's reaction limits."""
    from rapidds.execution.slowdowns import approach_speeds
    from rapidds.worlds.reactions import cell_reactions

    limits = cell_reactions(world)[1]
    return HoldModel(world, spatial, limits, approach_speeds(world, spatial, limits), belief)


def _device_value(world: World, spatial: SpatialModel, holds: HoldModel | None = None
                  ) -> ValueTerms:
    """The value on the device, with ``holds``' predicted hold when given."""
    return ValueTerms(device_terms=device_terms(world, spatial), on_device=True,
                      hold=None if holds is None else holds.hold,
                      device_hold=None if holds is None else holds.tensor_hold)


def test_tensor_terms_equal_the_worlds_numpy_terms(world: PaintingWorld, paths) -> None:
    terms = world.tensor_terms("cpu")
    assert world.tensor_terms(torch.device("cpu")) is terms  # built once per device
    q = torch.from_numpy(paths)
    pts = terms.points(q)
    np.testing.assert_allclose(pts.numpy(), world.robot_points(paths), rtol=0, atol=1e-12)
    executable = world.executable(paths)
    assert 0 < executable.sum() < len(paths)  # both kinds present
    np.testing.assert_array_equal(terms.executable(q, pts).numpy(), executable)
    np.testing.assert_array_equal(terms.collides(pts).numpy(),
                                  world.collides(world.robot_points(paths)))
    for task in ("mix_l", "mix_r", "brush"):
        host = world.completion_time(task, paths)
        dev = terms.completion_times([task], q, pts).numpy()
        done = host < world.penalty
        assert done.any() and not done.all()
        np.testing.assert_array_equal(dev[done], host[done])  # rows x dt, rounded alike
        np.testing.assert_allclose(dev, host, rtol=1e-12)     # the graded penalty
    with pytest.raises(ValueError, match="not a robot task"):
        terms.completion_times(["secure"], q, pts)
    # a steering batch: rows in blocks, one task each, in one pass
    blocks = ["brush", "mix_l", "mix_r", "mix_l"]
    per = len(paths) // len(blocks)
    rows = slice(0, per * len(blocks))
    want = np.concatenate([world.completion_time(task, paths[k * per:(k + 1) * per])
                           for k, task in enumerate(blocks)])
    got = terms.completion_times(blocks, q[rows], pts[rows]).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-12)
    with pytest.raises(ValueError, match="blocks"):
        terms.completion_times(blocks, q[:per * len(blocks) - 1], pts[:per * len(blocks) - 1])


def test_a_task_with_fewer_goals_is_padded_without_effect(world: PaintingWorld, paths) -> None:
    """A cell whose tasks have different numbers of goals pads the shorter lists with the
    whole space: each block's times are those of a cell where its task is alone."""
    from rapidds.worlds.painting.tensor_value import PaintingTensorValues

    cell = world.tensor_terms("cpu").cell
    goals = {"last": cell.goals["mix_l"][1:], "mix_l": cell.goals["mix_l"]}
    assert len(goals["last"]) == 1 and len(goals["mix_l"]) == 2
    mixed = PaintingTensorValues(dataclasses.replace(cell, goals=goals), torch.device("cpu"))
    half = len(paths) // 2
    q = torch.from_numpy(paths[:2 * half])
    pts = mixed.points(q)
    got = mixed.completion_times(["last", "mix_l"], q, pts)
    for task, rows in (("last", slice(0, half)), ("mix_l", slice(half, 2 * half))):
        alone = PaintingTensorValues(dataclasses.replace(cell, goals={task: goals[task]}),
                                     torch.device("cpu"))
        np.testing.assert_array_equal(got[rows].numpy(),
                                      alone.completion_times([task], q[rows], pts[rows]).numpy())
    assert len(set(got[:half].tolist())) > 1 and not torch.equal(got[:half], got[half:])


def test_a_steering_batch_scores_on_the_device_as_on_the_host(world, paths, spatial) -> None:
    """V of several requests' rows, the forward kinematics done once for all of them, equals
    the per-request numpy V; the host path stays the CPU's default (the stored records)."""
    policy = load_policy(world, device="cpu")
    requests = [("mix_l", frozenset({"secure_piece"})), ("brush", frozenset()),
                ("mix_r", frozenset({"secure_piece", "prep_vise"}))]
    assert all(near <= set(spatial.tasks) for _, near in requests)

    def motion(on_device: bool | None) -> DiffusionMotion:
        return DiffusionMotion(policy, world.completion_time, workspace_cost(world, spatial),
                               12.0, SteeringConfig(particles=2, candidates=3, steps=3),
                               terms=ValueTerms(device_terms=device_terms(world, spatial),
                                                on_device=on_device))

    rows = paths[: 3 * 2 * 3 * 2]  # 3 requests x 2 particles x 3 candidates, twice
    host_value = motion(None).value(requests)
    assert not isinstance(host_value, TensorValue)
    dev_value = motion(True).value(requests)
    assert isinstance(dev_value, TensorValue)
    got = dev_value(torch.from_numpy(rows))
    assert isinstance(got, torch.Tensor) and got.dtype == torch.float64
    np.testing.assert_allclose(got.numpy(), host_value(rows), rtol=1e-12)

    plans = motion(True).plan(requests)
    for (task, near), plan in zip(requests, plans, strict=True):
        assert plan.task == task and plan.concurrent == near
        assert plan.trajectory is not None and np.isfinite(plan.trajectory).all()
        assert plan.spatial_cost == pytest.approx(
            float(workspace_cost(world, spatial)(near, plan.trajectory[None])[0]) if near
            else 0.0)


def test_the_host_value_from_shared_points_is_the_per_request_value(world, paths,
                                                                    spatial) -> None:
    """The CPU's V with the arm points computed once per step for every request and the terms
    grouped by task and by concurrent set (the ``point_values`` capability) is, bit for bit,
    the per-request V the stored records were made with, a hold term added alike; a world
    without the capability keeps the per-request path."""
    from rapidds.worlds.fetch import FetchWorld

    policy = load_policy(world, device="cpu")
    requests = [("mix_l", frozenset({"secure_piece"})), ("brush", frozenset()),
                ("mix_l", frozenset({"prep_vise"})), ("mix_r", frozenset({"secure_piece"})),
                ("brush", frozenset({"secure_piece"}))]
    shared = host_terms(world, spatial)
    assert shared is not None and host_terms(FetchWorld(), spatial) is None

    def hold(task, near, xi):
        return 0.1 * len(near) + 0.01 * np.abs(xi[:, -1, 0])

    def value(terms, held):
        return DiffusionMotion(policy, world.completion_time, workspace_cost(world, spatial),
                               12.0, SteeringConfig(particles=2, candidates=2, steps=3),
                               terms=ValueTerms(host_terms=terms, hold=held)).value(requests)

    rows = paths[: len(requests) * 2 * 2 * 3]  # 5 requests x 2 particles x 2 candidates, x3
    for held in (None, hold):
        got, want = value(shared, held)(rows), value(None, held)(rows)
        assert np.isfinite(got).all() and len(set(got.tolist())) > len(requests)
        np.testing.assert_array_equal(got, want)


def test_fetch_tensor_terms_equal_the_worlds_numpy_terms() -> None:
    from rapidds.worlds.fetch import FetchWorld

    fetch = FetchWorld()
    rng = np.random.default_rng(2)
    demos = np.asarray(fetch.robot_demonstrations(3, rng).trajectories)
    xi = np.concatenate([demos, demos + rng.normal(0.0, 0.4, demos.shape),
                         rng.uniform(-1.0, 11.0, (10, *demos.shape[1:]))])
    xi[0, 5:7] = xi[0, 4]  # a resting row: segments parallel to both axes
    terms = fetch.tensor_terms("cpu")
    t = torch.from_numpy(xi)
    assert torch.equal(terms.points(t)[:, :, 0], t)
    hit = fetch.collides(xi)
    assert 0 < hit.sum() < len(xi)
    np.testing.assert_array_equal(terms.collides(t).numpy(), hit)
    for task in fetch.task_ids:
        if fetch.problem().task(task).can("robot"):
            host = fetch.completion_time(task, xi)
            assert (host < fetch.penalty).any()
            np.testing.assert_array_equal(terms.completion_times([task], t).numpy(), host)


def test_a_hold_term_without_its_tensor_form_keeps_the_value_on_the_host(world,
                                                                        spatial) -> None:
    policy = load_policy(world, device="cpu")

    def hold(task, near, xi):
        return np.zeros(len(xi))

    m = DiffusionMotion(policy, world.completion_time, workspace_cost(world, spatial), 12.0,
                        terms=ValueTerms(device_terms=device_terms(world, spatial), hold=hold,
                                         on_device=True))
    assert not isinstance(m.value([("mix_l", frozenset())]), TensorValue)


def test_the_monitors_predicted_hold_scores_on_the_device_as_on_the_host(world, paths,
                                                                        spatial) -> None:
    """Plans that expect the monitor (issue 36 item 2): the predicted hold as tensor
    operations, from the value's own points and completion times, gives the numpy hold's
    seconds, so a GPU steers a monitored plan without leaving the device; in float32 too,
    to its rounding. A value with the hold is then a tensor value."""
    belief = SlowdownBelief(0.8, 0.2)
    # learned corrections that differ by pair: one person's task beside two robot tasks
    assert belief.observe("mix_l", "secure_piece", 2.0, 0.5)
    assert belief.observe("mix_r", "secure_piece", 2.0, 3.0)
    assert belief.factor("mix_l", "secure_piece") < belief.factor("mix_r", "secure_piece")
    model = _holds(world, spatial, belief)
    terms = world.tensor_terms("cpu")
    near = ["secure_piece", "prep_vise"]
    for task in ("mix_l", "mix_r", "brush"):
        host = model.hold(task, near, paths)
        assert (host > 0).all() and len(np.unique(host.round(6))) > 20  # held, by varying time
        q = torch.from_numpy(paths)
        pts = terms.points(q)
        done = terms.completion_times([task], q, pts)
        # the painting terms are float64; a world's float32 points give a float32 hold
        key = [(task, frozenset(near))]
        for dtype, rtol, atol in ((torch.float64, 1e-9, 1e-9), (torch.float32, 2e-3, 2e-3)):
            got = model.tensor_hold(key, len(q), q.to(dtype), pts.to(dtype), done.to(dtype))
            assert got.dtype == dtype
            np.testing.assert_allclose(got.numpy(), host, rtol=rtol, atol=atol)
        assert not model.tensor_hold([(task, frozenset())], len(q), q, pts, done).any()

    policy = load_policy(world, device="cpu")
    requests = [("mix_l", frozenset({"secure_piece"})), ("brush", frozenset()),
                ("mix_r", frozenset({"secure_piece", "prep_vise"}))]

    def value(terms: ValueTerms):
        return DiffusionMotion(policy, world.completion_time, workspace_cost(world, spatial),
                               12.0, SteeringConfig(particles=2, candidates=3, steps=3),
                               terms=terms).value(requests)

    rows = paths[: 3 * 2 * 3 * 2]
    dev_value = value(ValueTerms(device_terms=device_terms(world, spatial), hold=model.hold,
                                 device_hold=model.tensor_hold, on_device=True))
    assert isinstance(dev_value, TensorValue)
    want = value(ValueTerms(hold=model.hold))(rows)
    np.testing.assert_allclose(dev_value(torch.from_numpy(rows)).numpy(), want, rtol=1e-9)
    assert (want > value(ValueTerms())(rows)).any()  # the hold is in the value


def test_interpolating_every_point_gives_the_skipping_row_max(world, paths, spatial) -> None:
    """Off the CPU the grid interpolates every point (no nonzero to wait for); the row maxima
    are those of the CPU's skipping evaluation, bit for bit."""
    pts = torch.from_numpy(world.robot_points(paths[:20]).reshape(20, -1, 3))
    model = spatial[spatial.tasks[0]]
    base, weights = model._stencil(pts.reshape(-1, 3))
    dense = model._interpolate(base, weights).view(20, -1).amax(dim=1)
    assert torch.equal(dense, model._row_max(base, weights, rows=20))


@pytest.mark.parametrize("held", [False, True], ids=["value", "value + hold"])
def test_a_diverged_policy_stops_the_device_path_cleanly(world, spatial, monkeypatch,
                                                         held) -> None:
    """Steering on a GPU with a network gone NaN: the candidates' points are NaN, the grid
    (which on a device reads nothing back) must not turn them into cell indices out of its
    table, a device-side assertion on CUDA; the steering ends with the diverged-policy error,
    with the monitor's predicted hold in the value too. Run here as a device runs it
    (``grid.reads_back`` off)."""
    import copy

    from rapidds.errors import CheckpointError
    from rapidds.human.spatial import grid

    broken = copy.deepcopy(load_policy(world, device="cpu"))
    with torch.no_grad():
        next(iter(broken.model.parameters())).fill_(float("nan"))
    monkeypatch.setattr(grid, "reads_back", lambda t: False)
    terms = _device_value(world, spatial, _holds(world, spatial) if held else None)
    motion = DiffusionMotion(broken, world.completion_time, workspace_cost(world, spatial), 12.0,
                             SteeringConfig(particles=2, candidates=2, steps=2), terms=terms)
    assert isinstance(motion.value([("mix_l", frozenset({"secure_piece"}))]), TensorValue)
    with pytest.raises(CheckpointError, match="non-finite"):
        motion.plan([("mix_l", frozenset({"secure_piece", "prep_vise"}))])


class _HostData(TorchDispatchMode):
    """The operations that take a tensor on the CPU: inside a value on another device, data
    from the host (a copy a CUDA graph's capture cannot hold)."""

    def __init__(self) -> None:
        super().__init__()
        self.ops: list[str] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # type: ignore[override]
        flat, _ = tree_flatten((args, kwargs or {}))
        if any(isinstance(a, torch.Tensor) and a.device.type == "cpu" for a in flat):
            self.ops.append(func.__name__)
        return func(*args, **(kwargs or {}))


@pytest.mark.parametrize("which", ["painting", "painting + hold", "fetch"])
def test_the_device_value_is_one_a_cuda_graph_can_capture(world, spatial, which) -> None:
    """What replaying the steering's value from a CUDA graph needs (``cuda_graphs``), checked
    where there is no GPU: on the meta device (shapes, no data), after a first call has made
    its tables, a call of the value reads nothing back to the host (that fails on meta) and
    takes no data from it."""
    from rapidds.worlds.fetch import FetchWorld

    w, sp, hold = world, spatial, None
    if which == "fetch":
        w = FetchWorld()
        sp = _population_spatial(w)
    elif which == "painting + hold":
        hold = _holds(w, sp)
    tasks = [t.id for t in w.problem().tasks if t.can("robot")]
    people = [t.id for t in w.problem().tasks if t.can("human")]
    requests = [(tasks[0], frozenset(people[:1])), (tasks[-1], frozenset()),
                (tasks[1 % len(tasks)], frozenset(people[:2]))]
    m = DiffusionMotion(load_policy(w, device="cpu"), w.completion_time, workspace_cost(w, sp),
                        12.0, terms=_device_value(w, sp, hold))
    terms = m.device_terms(torch.device("meta"))
    cfg = m.policy.config
    shape = (len(requests) * 6, cfg.horizon, cfg.state_dim)
    xi = torch.empty(shape, dtype=torch.float64, device="meta")
    first = m._term_values(terms, requests, xi, m.device_hold if hold else None)
    assert first.shape == (len(requests) * 6,) and first.device.type == "meta"
    with _HostData() as seen:
        again = m._term_values(terms, requests, xi, m.device_hold if hold else None)
    assert again.shape == first.shape and seen.ops == []
