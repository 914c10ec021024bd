"""Temporal model: NIG updates, predictive and plug-in sampling, persistence."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from rapidds.errors import StateError
from rapidds.human.temporal import (
    MIN_DURATION,
    DurationModel,
    NIGPrior,
    TemporalModel,
)
from rapidds.problem import load_problem

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture
def fetch():
    return load_problem(EXAMPLES.parent / "tests" / "data" / "four-fetch.yaml")


@pytest.fixture
def random8():
    return load_problem(EXAMPLES / "random-8.yaml")


# Prior mu0=10, nu=1, alpha=2, beta=4 (std 2), then observations 12, 9, 11. By hand:
#   x=12: mu=(10+12)/2=11,     nu=2, alpha=2.5, beta=4+1*(2)^2/(2*2)=5
#   x=9:  mu=(2*11+9)/3=31/3,  nu=3, alpha=3,   beta=5+2*(9-11)^2/(2*3)=19/3
#   x=11: mu=(31+11)/4=10.5,   nu=4, alpha=3.5, beta=19/3+3*(11-31/3)^2/(2*4)=39/6
HAND = [
    (12.0, (11.0, 2.0, 2.5, 5.0)),
    (9.0, (31 / 3, 3.0, 3.0, 19 / 3)),
    (11.0, (10.5, 4.0, 3.5, 6.5)),
]


def _params(p: NIGPrior) -> tuple[float, float, float, float]:
    return (p.mu, p.nu, p.alpha, p.beta)


def test_from_moments_sets_expected_variance():
    p = NIGPrior.from_moments(10.0, 2.0)
    assert _params(p) == (10.0, 1.0, 2.0, 4.0)
    assert p.expected_variance == pytest.approx(4.0)
    q = NIGPrior.from_moments(10.0, 2.0, nu=3.0, alpha=5.0)
    assert q.expected_variance == pytest.approx(4.0)
    # predictive variance = std^2 (1 + 1/nu): the person's spread plus uncertainty of the mean
    assert q.std() ** 2 == pytest.approx(4.0 * (1 + 1 / 3))
    with pytest.raises(ValueError, match="alpha"):
        NIGPrior.from_moments(10.0, 2.0, alpha=1.0)


def test_sequential_update_matches_hand_computation():
    post = NIGPrior(10.0, 1.0, 2.0, 4.0)
    for x, expected in HAND:
        post = post.update(x)
        assert _params(post) == pytest.approx(expected, rel=1e-12)


def test_batch_update_matches_sequential():
    prior = NIGPrior(10.0, 1.0, 2.0, 4.0)
    xs = [x for x, _ in HAND]
    assert _params(prior.update_many(xs)) == pytest.approx(HAND[-1][1], rel=1e-12)
    rng = np.random.default_rng(3)
    xs = list(rng.normal(7.0, 1.5, size=25).clip(0.1))
    seq = prior
    for x in xs:
        seq = seq.update(x)
    assert _params(prior.update_many(xs)) == pytest.approx(_params(seq), rel=1e-10)
    assert prior.update_many([]) == prior


def test_duration_model_keeps_posterior_in_step():
    m = DurationModel(NIGPrior(10.0, 1.0, 2.0, 4.0))
    for x, _ in HAND:
        m.observe(x)
    assert m.observations == [12.0, 9.0, 11.0]
    assert _params(m.posterior) == pytest.approx(HAND[-1][1])
    assert m.mean() == pytest.approx(10.5)
    assert _params(m.prior) == (10.0, 1.0, 2.0, 4.0)


def test_predictive_sampling_has_student_t_moments():
    post = NIGPrior(10.5, 4.0, 3.5, 6.5)  # the hand example's posterior
    dof, scale = 7.0, math.sqrt(6.5 * 5 / (3.5 * 4))
    assert post.predictive_dof == dof
    assert post.predictive_scale == pytest.approx(scale)
    variance = scale**2 * dof / (dof - 2)  # = beta (nu+1) / (nu (alpha-1)) = 3.25
    assert variance == pytest.approx(3.25)
    assert post.std() == pytest.approx(math.sqrt(3.25))
    x = post.sample(200_000, np.random.default_rng(0))
    assert x.mean() == pytest.approx(10.5, abs=0.02)
    assert x.var() == pytest.approx(3.25, rel=0.03)
    # heavier tails than a Normal: t_7 has excess kurtosis 6/(7-4) = 2
    assert stats.kurtosis(x) == pytest.approx(2.0, abs=0.5)
    assert stats.kstest(x, stats.t(df=dof, loc=10.5, scale=scale).cdf).pvalue > 1e-3


def test_plugin_sampling_is_the_papers_normal():
    post = NIGPrior(10.5, 4.0, 3.5, 6.5)
    e_var = 6.5 / 2.5  # E[sigma^2] = beta / (alpha - 1)
    assert post.std("plugin") == pytest.approx(math.sqrt(e_var))
    x = post.sample(200_000, np.random.default_rng(1), "plugin")
    assert x.mean() == pytest.approx(10.5, abs=0.02)
    assert x.var() == pytest.approx(e_var, rel=0.03)
    assert abs(stats.kurtosis(x)) < 0.1
    # the predictive is wider: it adds the uncertainty about mu and sigma^2
    assert post.std("predictive") > post.std("plugin")


def test_model_sampling_option(fetch):
    pred = TemporalModel.from_problem(fetch)
    plug = TemporalModel.from_problem(fetch, sampling="plugin")
    assert pred.sampling == "predictive"
    # fetch t0: mean 12, std 2 -> plug-in sd 2, predictive sd 2*sqrt(2) (nu = 1)
    assert plug.std()[0] == pytest.approx(2.0)
    assert pred.std()[0] == pytest.approx(2.0 * math.sqrt(2.0))
    xs = plug.sample(50_000, np.random.default_rng(2))
    assert xs.std(axis=0) == pytest.approx(plug.std(), rel=0.03)
    with pytest.raises(ValueError, match="sampling"):
        TemporalModel.from_problem(fetch, sampling="gaussian")  # type: ignore[arg-type]


def test_samples_are_positive_even_with_a_wide_prior():
    p = NIGPrior.from_moments(1.0, 5.0)  # most of the mass below zero without the floor
    for method in ("predictive", "plugin"):
        x = p.sample(10_000, np.random.default_rng(4), method)  # type: ignore[arg-type]
        assert x.min() >= MIN_DURATION
        assert (x == MIN_DURATION).mean() > 0.3


def test_deterministic_task_samples_exactly_its_mean(random8):
    p = NIGPrior.from_moments(3.0, 0.0)
    for method in ("predictive", "plugin"):
        assert np.all(p.sample(100, np.random.default_rng(5), method) == 3.0)  # type: ignore[arg-type]
    model = TemporalModel.from_problem(random8)
    x = model.sample(500, np.random.default_rng(6))
    e = random8.index["e"]  # human mean 3.0, std 0
    assert np.all(x[:, e] == 3.0)
    assert model.std()[e] == 0.0
    # one observation that contradicts it makes it uncertain, as the update formula says
    model.observe("e", 4.0)
    assert model.mean()[e] == pytest.approx(3.5)
    assert model.std()[e] > 0


def test_sample_layout_follows_problem_order(random8):
    model = TemporalModel.from_problem(random8)
    x = model.sample(4000, np.random.default_rng(7))
    assert x.shape == (4000, 8)
    robot_only = [random8.index[t] for t in ("c", "f")]
    assert np.all(np.isnan(x[:, robot_only]))
    assert np.all(np.isnan(model.mean()[robot_only]))
    human = [i for i in range(8) if i not in robot_only]
    expected = np.array([t.human_mean for t in random8.tasks])[human]
    assert np.array_equal(model.mean()[human], expected)
    assert x[:, human].mean(axis=0) == pytest.approx(expected, rel=0.05)
    # same seed, same samples
    again = model.sample(4000, np.random.default_rng(7))
    assert np.array_equal(x, again, equal_nan=True)
    with pytest.raises(ValueError):
        model.sample(0, np.random.default_rng(0))


def test_posterior_converges_to_a_persons_true_duration(fetch):
    model = TemporalModel.from_problem(fetch)  # t2 prior: mean 8, std 1.5
    col = fetch.index["t2"]
    rng = np.random.default_rng(8)
    true_mean, true_sd = 11.0, 0.8
    errors = []
    for n in range(1, 61):
        model.observe("t2", float(rng.normal(true_mean, true_sd)))
        if n in (3, 60):
            errors.append(abs(model.mean()[col] - true_mean))
    assert errors[1] < 0.3
    assert errors[1] < errors[0]
    # with many cycles the predictive spread approaches the person's own spread
    assert model.std()[col] == pytest.approx(true_sd, rel=0.35)
    x = model.sample(20_000, np.random.default_rng(9))[:, col]
    assert x.mean() == pytest.approx(true_mean, abs=0.3)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 0.0, -2.0])
def test_observe_rejects_non_durations(fetch, bad):
    model = TemporalModel.from_problem(fetch)
    before = model.to_dict()
    with pytest.raises(ValueError, match="duration"):
        model.observe("t0", bad)
    assert model.to_dict() == before


def test_observe_unknown_or_robot_only_task(random8):
    model = TemporalModel.from_problem(random8)
    with pytest.raises(KeyError):
        model.observe("zz", 3.0)
    with pytest.raises(KeyError):
        model.observe("c", 3.0)  # robot-only


def test_from_population_sets_priors_from_statistics(fetch):
    pop = {"t0": [10.0, 14.0, 12.0, 16.0], "t3": [5.0, 7.0]}
    model = TemporalModel.from_population(fetch, pop, nu=2.0, alpha=3.0)
    t0 = model.models["t0"].prior
    assert t0.mu == pytest.approx(13.0)
    assert t0.expected_variance == pytest.approx(np.var(pop["t0"], ddof=1))
    assert (t0.nu, t0.alpha) == (2.0, 3.0)
    assert model.models["t3"].prior.expected_variance == pytest.approx(2.0)
    # a task without population data keeps the problem file's prior
    assert model.models["t1"].prior.mu == 12.0
    assert model.models["t1"].prior.expected_variance == pytest.approx(4.0)
    with pytest.raises(ValueError, match="at least 2"):
        TemporalModel.from_population(fetch, {"t0": [10.0]})
    with pytest.raises(ValueError, match="cannot do"):
        TemporalModel.from_population(fetch, {"nope": [1.0, 2.0]})
    with pytest.raises(ValueError, match="duration"):
        TemporalModel.from_population(fetch, {"t0": [1.0, math.nan]})


def test_save_load_round_trip(fetch, tmp_path):
    model = TemporalModel.from_problem(fetch, sampling="plugin")
    for x in (7.0, 9.5, 8.2):
        model.observe("t2", x)
    model.observe("t0", 13.0)
    path = tmp_path / "temporal.json"
    model.save(path)
    assert json.loads(path.read_text())["format"] == "rapidds.temporal"
    loaded = TemporalModel.load(path)
    assert loaded.to_dict() == model.to_dict()
    assert loaded.sampling == "plugin"
    assert loaded.task_ids == fetch.ids
    a = model.sample(10, np.random.default_rng(1))
    b = loaded.sample(10, np.random.default_rng(1))
    assert np.array_equal(a, b)
    assert TemporalModel.from_dict(json.loads(json.dumps(model.to_dict()))).to_dict() == (
        model.to_dict()
    )
    assert [p.name for p in tmp_path.iterdir()] == ["temporal.json"]  # no temp file left


def test_save_is_atomic(fetch, tmp_path, monkeypatch):
    path = tmp_path / "temporal.json"
    model = TemporalModel.from_problem(fetch)
    model.save(path)
    before = path.read_text()
    model.observe("t1", 20.0)

    def boom(src, dst):
        raise OSError("disk gone")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk gone"):
        model.save(path)
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["temporal.json"]


@pytest.mark.parametrize(
    "content",
    [
        "",
        "{not json",
        "[1, 2, 3]",
        '{"format": "something else"}',
        '{"format": "rapidds.temporal", "version": 99}',
    ],
)
def test_corrupt_file_is_a_state_error(tmp_path, content):
    path = tmp_path / "t.json"
    path.write_text(content)
    with pytest.raises(StateError, match=r"t\.json"):
        TemporalModel.load(path)


def test_tampered_state_is_a_state_error(fetch, tmp_path):
    model = TemporalModel.from_problem(fetch)
    model.observe("t0", 11.0)
    good = model.to_dict()
    cases = []
    d = json.loads(json.dumps(good))
    d["models"]["t0"]["posterior"]["mu"] = 99.0  # disagrees with prior + observations
    cases.append(d)
    d = json.loads(json.dumps(good))
    d["models"]["t0"]["observations"] = [-1.0]
    cases.append(d)
    d = json.loads(json.dumps(good))
    d["models"]["t0"]["prior"]["nu"] = "NaN"
    cases.append(d)
    d = json.loads(json.dumps(good))
    d["models"]["unknown"] = d["models"]["t0"]
    cases.append(d)
    d = json.loads(json.dumps(good))
    d["sampling"] = "magic"
    cases.append(d)
    d = json.loads(json.dumps(good))
    del d["models"]["t1"]["prior"]
    cases.append(d)
    for case in cases:
        path = tmp_path / "t.json"
        path.write_text(json.dumps(case))
        with pytest.raises(StateError):
            TemporalModel.load(path)
    with pytest.raises(StateError, match="no such file"):
        TemporalModel.load(tmp_path / "missing.json")
