"""The painting world supports the paper's four behaviours: from the world alone (population
prior, a person's learned model, the robot's nominal motions and their durations), every
inequality the planner's choices hinge on holds, for a left-handed person and, mirrored, for a
right-handed one (docs/design-notes.md, "The painting cell"). These are the world's numbers, not
the planner's outcomes: nothing here runs the loop."""

from __future__ import annotations

import pytest
import torch

from rapidds.worlds.painting import PaintingWorld
from rapidds.worlds.painting.calibration import calibrate, prior_model

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def setting():
    world = PaintingWorld()
    return world, prior_model(world)


@pytest.mark.slow
@pytest.mark.parametrize("teammate", ["left-fast", "right-fast"])
def test_every_behaviour_inequality_holds(setting, teammate: str) -> None:
    world, prior = setting
    c = calibrate(world, teammate=teammate, prior=prior)
    assert c.near == ("mix_l" if teammate.startswith("left") else "mix_r")
    failed = [f"{k.behaviour}: {k.statement} ({k.lhs:.2f} vs {k.rhs:.2f})"
              for k in c.checks if not k.holds]
    assert not failed, "\n" + c.table()
    # what the checks rest on, stated plainly
    s = c.spatial
    for role in ("near", "far"):
        # before learning both mixes look alike (the prior is half left-, half right-handed)
        assert s["prior", role, "direct", "secure_piece"] > 2.5 * s["prior", role, "avoidant",
                                                                    "secure_piece"]
    assert abs(s["prior", "near", "direct", "secure_piece"]
               - s["prior", "far", "direct", "secure_piece"]) < 0.02
    # learning the person's hand moves the near mix's cost up and the far mix's down
    assert s["learned", "near", "direct", "secure_piece"] > 1.5 * s["prior", "near", "direct",
                                                                    "secure_piece"]
    assert s["learned", "far", "direct", "secure_piece"] < 0.5 * s["prior", "far", "direct",
                                                                   "secure_piece"]
    # the mixes hardly disturb Prep Vise: both hands are at the vise, far from the trays
    assert max(v for k, v in s.items() if k[3] == "prep_vise") < 0.06


@pytest.mark.slow
def test_mirror_twins_get_mirror_numbers(setting) -> None:
    world, prior = setting
    left = calibrate(world, teammate="left-fast", prior=prior)
    right = calibrate(world, teammate="right-fast", prior=prior)
    assert left.durations == right.durations
    for key in left.spatial:
        if key[0] != "prior":  # the population itself is a finite, random half-and-half
            assert left.spatial[key] == pytest.approx(right.spatial[key], abs=0.01), key
