"""settings_dataclass: classes that are more than their settings (worlds, priors, teammates)
declare their bounds on the fields and fail like every Settings model, with one ConfigError line
naming the class and the field."""

from __future__ import annotations

import dataclasses
import math
import pickle
import re
from typing import Annotated

import pytest
from pydantic import Field

from rapidds.errors import ConfigError
from rapidds.human.temporal import NIGPrior
from rapidds.settings import Int, Positive, settings_dataclass
from rapidds.worlds.changes import ChangingTeammate
from rapidds.worlds.fetch import FetchWorld
from rapidds.worlds.geometry import Rect


@settings_dataclass("Box")
class Box:
    width: Positive
    count: Annotated[Int, Field(ge=1)] = 1

    def __post_init__(self) -> None:
        if self.width * self.count > 10:
            raise ValueError("width x count must be at most 10")


def test_bounds_are_one_config_error_line_naming_the_field() -> None:
    assert Box(2.0, 3) == Box(width=2, count=3)  # positional or by name, ints as floats
    with pytest.raises(ConfigError, match=r"^Box\.width: Input should be greater than 0 "
                                          r"\(got -1\.0\)$"):
        Box(-1.0)  # positional: still named by its field
    with pytest.raises(ConfigError, match=r"^Box\.width: Input should be a finite number"):
        Box(math.nan)
    with pytest.raises(ConfigError, match=r"^Box\.count: must be an integer \(got 2\.0\)$"):
        Box(1.0, 2.0)  # strict Int, as in Settings
    with pytest.raises(ConfigError, match=r"^Box\.width: must be a number \(got True\)$"):
        Box(True)
    with pytest.raises(ConfigError, match=r"^Box: width x count must be at most 10$"):
        Box(5.0, 3)  # a check across fields, from __post_init__


def test_frozen_replace_and_call_errors_stay_as_python_says() -> None:
    box = Box(1.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        box.width = 2.0  # type: ignore[misc]
    assert dataclasses.replace(box, count=4).count == 4
    with pytest.raises(ConfigError, match=r"Box\.count"):
        dataclasses.replace(box, count=0)
    with pytest.raises(TypeError, match="multiple values for width"):
        Box(1.0, width=2.0)  # type: ignore[misc]
    with pytest.raises(TypeError, match="at most 2 positional"):
        Box(1.0, 1, 1)  # type: ignore[call-arg]


def test_nig_prior_and_changing_teammate_declare_their_bounds() -> None:
    with pytest.raises(ConfigError, match=r"^NIGPrior\.nu: .*greater than 0 \(got 0\.0\)$"):
        NIGPrior(1.0, 0.0, 1.0, 1.0)
    with pytest.raises(ConfigError, match=r"^NIGPrior\.beta: .*greater than or equal to 0"):
        NIGPrior(1.0, 1.0, 1.0, -0.5)
    with pytest.raises(ConfigError, match=r"^NIGPrior\.mu: Input should be a finite number"):
        NIGPrior(math.inf, 1.0, 1.0, 1.0)
    person = FetchWorld().teammate("fast-outside")
    assert ChangingTeammate(((0, person),), drift=0.1).drift == 0.1
    with pytest.raises(ConfigError, match=r"^ChangingTeammate\.drift: .*less than 0\.5"):
        ChangingTeammate(((0, person),), drift=0.5)
    with pytest.raises(ConfigError, match=r"^ChangingTeammate: the first phase .* cycle 0$"):
        ChangingTeammate(((2, person),))
    with pytest.raises(ConfigError, match=r"^ChangingTeammate\.phases\[0\]\[1\]: .*instance of "
                                          r"SimulatedTeammate"):
        ChangingTeammate(((0, "somebody"),))  # type: ignore[arg-type]


def test_rect_declares_finite_corners_in_order() -> None:
    assert Rect(0, 0, 1, 2).as_array().tolist() == [0.0, 0.0, 1.0, 2.0]
    with pytest.raises(ConfigError, match=r"^Rect: needs xmin < xmax and ymin < ymax"):
        Rect(1.0, 0.0, 0.0, 1.0)
    with pytest.raises(ConfigError, match=r"^Rect\.ymax: Input should be a finite number"):
        Rect(0.0, 0.0, 1.0, math.nan)


def test_declared_classes_travel_to_workers() -> None:
    """Worlds and priors are pickled to Dask and process-pool workers (ablation, study simulate)."""
    world = FetchWorld(prior_people=3)
    again = pickle.loads(pickle.dumps(world))
    assert again.prior_people == 3 and again.problem() == world.problem()
    prior = NIGPrior(1.0, 2.0, 3.0, 4.0)
    assert pickle.loads(pickle.dumps(prior)) == prior


def test_the_one_yaml_reader_says_what_is_wrong_in_one_line(tmp_path):
    from rapidds.errors import ProblemError
    from rapidds.settings import read_yaml

    path = tmp_path / "run.yaml"
    path.write_text("cycles: 4\nlam: 1e1\nratio: 1.5E-3\n")
    assert read_yaml(path) == {"cycles": 4, "lam": 10.0, "ratio": 0.0015}  # YAML 1.2 floats
    for text, says in [("cycles: [4\n", "not valid YAML (line 2: "), ("- 4\n", "not a mapping"),
                       ("x: !!python/object:os.system {}\n", "not valid YAML")]:
        path.write_text(text)
        with pytest.raises(ConfigError) as err:
            read_yaml(path, "--config")
        assert str(err.value).startswith(f"--config {path}: ") and says in str(err.value)
        assert "\n" not in str(err.value)
    with pytest.raises(ProblemError, match=r"nowhere\.yaml: no such file$"):
        read_yaml(tmp_path / "nowhere.yaml", error=ProblemError)
    path.write_text("- 1\n")
    assert read_yaml(path, mapping=False) == [1]  # a problem file's own check names it
    path.write_text('{\n\t"steps": 6,\n\t"lr": 1e-4\n}\n')  # JSON indented with tabs
    assert read_yaml(path) == {"steps": 6, "lr": 1e-4}
    path.write_text("{steps: 6, lr: 1e-4}\n")  # flow-style YAML, not JSON
    assert read_yaml(path) == {"steps": 6, "lr": 1e-4}


def test_a_duration_belief_declares_its_bounds_and_still_learns_in_place():
    from rapidds.errors import StateError
    from rapidds.human.temporal import DurationModel, TemporalModel

    prior = NIGPrior.from_moments(5.0, 1.0)
    for bad, says in [({"forgetting": 0.0}, "DurationModel.forgetting"),
                      ({"forgetting": 1.5}, "DurationModel.forgetting"),
                      ({"start": -1}, "DurationModel.start"),
                      ({"observations": [2.0, "x"]}, "DurationModel.observations[1]"),
                      ({"observations": [2.0], "start": 2}, "start 2 outside 0..1")]:
        with pytest.raises(ConfigError, match=re.escape(says)):
            DurationModel(prior, **bad)
    m = DurationModel(prior, [4.0], 0.9)
    m.observe(6.0)  # not frozen: a belief learns
    assert m.observations == [4.0, 6.0] and m == DurationModel.from_dict(m.to_dict())
    with pytest.raises(StateError, match="corrupt temporal model: tasks"):
        TemporalModel.from_dict({"format": "rapidds.temporal", "version": 1,
                                 "sampling": "predictive", "tasks": [1], "models": {}})
