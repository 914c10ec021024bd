"""Learning a person's gamma from what they DO: their reactions to the robot (slowing or pausing
near it) as evidence, and a simulated person whose reaction distances follow their own gamma."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import SMALL_SEARCH as SMALL
from record_helpers import stored

from rapidds.human.gamma import GammaBelief, GammaEvidence
from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.loop.comfort import SimulatedComfort, reaction_anchor
from rapidds.store import RunStore
from rapidds.worlds.reactions import Reaction
from rapidds.worlds.registry import make_world

G_REF = 1.75
ANCHOR = 0.22  # fetch: exp(-1 * 1.5), its people's mean comfort distance


def _did(reactions=(), calm: float | None = None) -> GammaEvidence:
    """A cycle where the person said nothing (was not asked) and did ``reactions``."""
    return GammaEvidence(None, (), (), 0.9, 3.0, tuple(reactions), calm, ANCHOR, asked=False)


def _after(*evidence: GammaEvidence) -> GammaBelief:
    b = GammaBelief(G_REF, 4.0, G_REF)
    for ev in evidence:
        b.observe(ev)
    return b


def test_a_silent_person_who_reacts_moves_the_belief_the_right_way():
    early = _after(_did([(0.05, 0.08)]))  # reacted with the robot still far: nervous
    late = _after(_did([(0.6, 0.95)]))    # let it come right beside them first: relaxed
    calm = _after(_did(calm=0.9))         # it came close and they went on: relaxed
    assert early.evidence == late.evidence == calm.evidence == 1
    # one episode, weighed with its lapse: a factor 1.5 at least
    assert early.mean() > 1.5 * G_REF and late.mean() < G_REF / 1.5 and calm.mean() < G_REF / 2
    # calm while the robot stayed far says little
    far = _after(_did(calm=0.01))
    assert abs(math.log(far.mean() / G_REF)) < abs(math.log(calm.mean() / G_REF)) / 4
    # the threshold lay between the two samples: a person who reacted between 0.1 and 0.3
    # is believed between the gammas that put a reference threshold there
    mid = _after(*[_did([(0.1, 0.3)])] * 6)
    assert ANCHOR / 0.3 * G_REF < mid.mean() < ANCHOR / 0.1 * G_REF, mid.summary()


def test_a_person_not_asked_is_not_heard_from_their_silence():
    """Not asked, no reactions watched: no evidence (the exposure's zero signals would say
    'low gamma' for a person who was asked); asked, the same silence does move it."""
    unheard = _after(GammaEvidence(None, (), (), 0.9, 3.0, asked=False))
    assert unheard.evidence == 0 and unheard.mean() == G_REF
    heard = _after(GammaEvidence(None, (), (), 0.9, 3.0))
    assert heard.evidence == 1 and heard.mean() < G_REF
    with pytest.raises(ValueError, match="not asked"):
        GammaEvidence(5, (), (), 0.9, 3.0, asked=False)
    with pytest.raises(ValueError, match="anchor"):
        GammaEvidence(None, (), (), 0.9, 3.0, calm_peak=0.5)


def test_evidence_round_trips_and_old_records_read_unchanged():
    old = {"answer": 3, "too_close": [1.0], "closeness_at": [0.4], "peak": 0.5, "exposure": 2.0}
    ev = GammaEvidence.from_dict(old)
    assert not ev.watched and ev.asked and ev.to_dict() == old  # no new keys in such records
    new = GammaEvidence(None, (), (), 0.9, 3.0, ((0.1, 0.3), (0.2, 0.25)), 0.7, ANCHOR,
                        asked=False)
    again = GammaEvidence.from_dict(json.loads(json.dumps(new.to_dict())))
    assert again == new
    assert np.array_equal(_after(again).log_post, _after(new).log_post)


def test_a_simulated_persons_reaction_distances_grow_with_their_gamma():
    drawn = Reaction(1.5, 0.7, 0.4)
    dist = [SimulatedComfort(g, G_REF).reaction(drawn, 1.0) for g in (0.05, 0.3, G_REF, 10.0)]
    assert dist[2] == drawn  # the reference person reacts as drawn
    assert [r.comfort for r in dist] == sorted(r.comfort for r in dist)
    assert dist[1].comfort < 1.5 < dist[3].comfort
    assert dist[3].comfort == pytest.approx(1.5 + math.log(10 / G_REF) / 2)
    for r in dist:  # kept a reaction: positive, the stop inside the comfort
        assert 0 < r.stop < r.comfort and r.slow == drawn.slow
    assert dist[0].comfort == pytest.approx(0.25 * 1.5)  # floored, not negative


@pytest.fixture(scope="module")
def policy(fetch_policy):
    return fetch_policy


def test_the_runs_simulated_person_reacts_by_their_comfort(policy):
    runs = [AdaptiveRun(RunConfig(cycles=1, comfort=g, reacts=True, **SMALL), policy)
            for g in (0.3, 10.0)]
    relaxed, nervous = (r.context.reaction for r in runs)
    assert relaxed is not None and nervous is not None
    assert relaxed.comfort < nervous.comfort and relaxed.stop < nervous.stop
    plain = AdaptiveRun(RunConfig(cycles=1, reacts=True, **SMALL), policy).context.reaction
    assert plain is not None and relaxed.comfort < plain.comfort < nervous.comfort


def test_a_person_who_says_nothing_but_reacts_is_learned_from(policy):
    world = make_world("fetch")
    person = world.teammate("fast-middle")  # injected: no comfort_report, says nothing
    cfg = dict(human="fast-middle", cycles=3, gamma_learn=True, reacts=True, **SMALL)
    run = AdaptiveRun(RunConfig(**cfg), policy, teammate=person)
    records = run.run()
    assert run.model.gamma is not None and run.model.gamma.evidence == 3
    assert all(r.comfort["asked"] is False and r.comfort["answer"] is None
               and r.comfort["reactions"]["anchor"] == pytest.approx(
                   reaction_anchor(world, 1.0)) for r in records)
    assert records[-1].gamma_belief["mean"] != G_REF
    assert [r.plan.gamma for r in records[1:]] == [
        pytest.approx(r.gamma_belief["mean"]) for r in records[:-1]]
    # the same person with reactions not counted: no evidence, the prior stays
    off = AdaptiveRun(RunConfig(**cfg, gamma_reactions=False), policy, teammate=person)
    assert off.config.run_id.endswith("-glearn-saidonly-reacts-s0")
    off_records = off.run()
    assert off.model.gamma is not None and off.model.gamma.evidence == 0
    assert [r.plan.gamma for r in off_records] == [G_REF] * 3


def test_a_resumed_run_learning_from_reactions_matches_an_uninterrupted_one(policy, tmp_path):
    cfg = RunConfig(cycles=3, seed=2, gamma_learn=True, comfort=6.0, reacts=True, **SMALL)
    whole = AdaptiveRun(cfg, policy).run()
    assert any(r.comfort["reactions"]["onsets"] for r in whole)  # reactions were learned
    with RunStore(tmp_path / "run.sqlite") as store:
        first = AdaptiveRun(cfg, policy, store=store)
        first.step()
        first.step()
    with RunStore(tmp_path / "run.sqlite") as store:
        rest = AdaptiveRun(cfg, policy, store=store)
        assert rest.next_cycle == 2
        (last,) = rest.run()
    assert stored(last) == stored(whole[2])
