"""The painting world supports the paper's four behaviours. From the world alone (population
prior, a person's learned spatial model, the robot's two demonstrated modes per mix and their
completion times) the best of all schedules of the job, scored by the library's Algorithm 2
with the mode the steering value prefers, behaves as the paper says, for a left-handed person
and, mirrored, for a right-handed one (docs/design-notes.md, "The painting cell"). These are
the world's numbers, not the loop's outcomes: nothing here samples the diffusion policy."""

from __future__ import annotations

import pytest
import torch

from rapidds.worlds.painting import PaintingWorld
from rapidds.worlds.painting.calibration import calibrate, enumerate_schedules, prior_model

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def setting():
    world = PaintingWorld()
    return world, prior_model(world)


@pytest.mark.slow
@pytest.mark.parametrize("teammate", ["left-fast", "right-fast"])
def test_every_behaviour_holds_for_the_best_schedule(setting, teammate: str) -> None:
    world, prior = setting
    c = calibrate(world, teammate=teammate, prior=prior)
    assert c.near == ("mix_l" if teammate.startswith("left") else "mix_r")
    assert len(c.behaviours) == 8
    assert all(b.holds and b.margin > 0.2 for b in c.behaviours), "\n" + c.table()
    s = c.spatial
    for task in ("mix_l", "mix_r"):
        # before learning both mixes look alike (the prior is half left-, half right-handed)
        # and the avoidant mode is much the safer one while Secure Piece runs
        assert s["prior", task, "direct", "secure_piece"] > 2.5 * s["prior", task, "avoidant",
                                                                    "secure_piece"]
    assert abs(s["prior", "mix_l", "direct", "secure_piece"]
               - s["prior", "mix_r", "direct", "secure_piece"]) < 0.03
    # learning the person's hand moves the near mix's cost up and the far mix's down
    assert s["learned", c.near, "direct", "secure_piece"] > 1.5 * s["prior", c.near, "direct",
                                                                     "secure_piece"]
    assert s["learned", c.far, "direct", "secure_piece"] < 0.5 * s["prior", c.far, "direct",
                                                                    "secure_piece"]
    # the mixes hardly disturb Prep Vise: both hands are at the vise, far from the trays
    assert max(v for k, v in s.items() if k[3] == "prep_vise") < 0.05
    # the avoidant mode is the slower one, and a direct mix fits within Prep Vise
    assert c.durations["mix_l", "direct"] < c.prep < c.durations["mix_l", "avoidant"]


@pytest.mark.slow
def test_mirror_twins_get_mirror_numbers(setting) -> None:
    world, prior = setting
    left = calibrate(world, teammate="left-fast", prior=prior)
    right = calibrate(world, teammate="right-fast", prior=prior)
    swap = {"mix_l": "mix_r", "mix_r": "mix_l"}
    for (belief, task, mode, human), v in left.spatial.items():
        if belief != "prior":  # the population itself is a finite, random half-and-half
            assert right.spatial[belief, swap[task], mode, human] == pytest.approx(v, abs=0.01)


def test_every_schedule_shape_is_enumerated() -> None:
    world = PaintingWorld(prior_people=4)
    free = enumerate_schedules(world.problem())
    fixed = enumerate_schedules(PaintingWorld(variant="constrained", prior_people=4).problem())
    assert len(free) == 2 * len(fixed) == 252
    assert len(set(free)) == len(free)
    assert all(s.robot.index("mix_r") < s.robot.index("mix_l") for s in fixed)
