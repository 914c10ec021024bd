"""The user study's forms: the survey items and what a participant submits, validated with
pydantic before the store sees it.

* :class:`SurveyItems` (:class:`SurveyItem` each): the post-system survey, from YAML
  (``SurveyItems.load``) or the packaged ``items.yaml`` (:func:`default_items`).
* :func:`survey_answers` (every item answered once, Likert 1..7), :func:`demographic_fields`
  (free text fields), :func:`validate_durations` (a person's seconds per task): each raises
  StudyDataError with one line naming the participant and the field.

The store (:mod:`~rapidds.experiments.study.store`) keeps the answers and decides whether a
submit is the participant's next step; this module only says whether a form is well formed.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from rapidds.errors import StudyDataError, StudyDesignError
from rapidds.experiments.study.design import MAX_TASK_S_LIMIT
from rapidds.settings import Place, error_line, parse_yaml, read_yaml

__all__ = [
    "LIKERT",
    "SurveyItem",
    "SurveyItems",
    "default_items",
    "demographic_fields",
    "survey_answers",
    "validate_durations",
]

LIKERT: tuple[int, int] = (1, 7)
"""The survey's scale: 1 = strongly disagree ... 7 = strongly agree."""
_NAME = r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$"


# -- survey items ----------------------------------------------------------------------------
class SurveyItem(BaseModel):
    """One Likert statement. id: a short name (letters, digits, ``_.+-``), the key of answers
    and of the analysis; text: as shown; scale: the construct it belongs to; reverse: agreeing
    is the worse answer."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    id: str = Field(pattern=_NAME, max_length=64)
    text: str = Field(min_length=1, max_length=500)
    scale: str = ""
    reverse: bool = False


class SurveyItems(BaseModel):
    """The post-system survey: its items, in the order asked."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    items: tuple[SurveyItem, ...] = Field(min_length=1)

    @field_validator("items")
    @classmethod
    def _ids_once(cls, v: tuple[SurveyItem, ...]) -> tuple[SurveyItem, ...]:
        ids = [i.id for i in v]
        dupes = sorted({i for i in ids if ids.count(i) > 1})
        if dupes:
            raise ValueError(f"item id named twice: {', '.join(dupes)}")
        return v

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(i.id for i in self.items)

    @classmethod
    def parse(cls, data: Any, where: str) -> SurveyItems:
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            raise StudyDesignError(f"{where}: {error_line(exc)}") from None

    @classmethod
    def load(cls, path: str | Path) -> SurveyItems:
        """A YAML (or JSON, which is YAML) file ``{items: [{id, text, scale?, reverse?}, ...]}``."""
        return cls.parse(read_yaml(path, error=StudyDesignError, mapping=False), str(path))


def default_items() -> SurveyItems:
    """The packaged survey: Hoffman's fluency measures and the paper's interference item."""
    text = resources.files("rapidds.experiments.study").joinpath("items.yaml").read_text()
    return SurveyItems.parse(parse_yaml(text, "items.yaml", StudyDesignError), "items.yaml")


# -- submissions -------------------------------------------------------------------------------
Likert = Annotated[int, Field(ge=LIKERT[0], le=LIKERT[1])]
_Duration = Annotated[float, Field(gt=0, allow_inf_nan=False)]  # at most: validate_durations


class _Survey(BaseModel):
    model_config = ConfigDict(extra="forbid")
    answers: dict[str, Likert]


class _Durations(BaseModel):
    model_config = ConfigDict(extra="forbid")
    durations: dict[str, _Duration]


class _Demographics(BaseModel):
    model_config = ConfigDict(extra="forbid")
    fields: dict[Annotated[str, Field(min_length=1, max_length=64)],
                 Annotated[str, Field(max_length=2000)]]


def _validated(model: type[BaseModel], what: str, **data: Any) -> Any:
    try:
        return model(**data)
    except ValidationError as exc:
        line = error_line(exc, prefix=f"{what} ", with_input=True,
                          place=Place(skip=1, quote=True))
        raise StudyDataError(line) from None


def validate_durations(durations: Mapping[str, Any], tasks: Iterable[str],
                       at_most: float = MAX_TASK_S_LIMIT) -> dict[str, float]:
    """Seconds per task: every task of ``tasks`` once, each positive, finite, at most ``at_most``
    (``StudyDesign.task_bound``; a string of a number is accepted). StudyDataError otherwise."""
    want = list(tasks)
    got = _validated(_Durations, "duration of task", durations=dict(durations)).durations
    missing = [t for t in want if t not in got]
    extra = sorted(set(got) - set(want))
    if missing or extra:
        raise StudyDataError(
            "durations must name exactly the person's tasks " + ", ".join(want)
            + (f"; missing {', '.join(missing)}" if missing else "")
            + (f"; not the person's: {', '.join(extra)}" if extra else ""))
    if long := [t for t in want if got[t] > at_most]:
        raise StudyDataError(f"duration of task '{long[0]}': {got[long[0]]:g} s is longer than "
                             f"any task of this study ({at_most:g} s; the design's max_task_s)")
    return {t: float(got[t]) for t in want}


def survey_answers(answers: Mapping[str, Any], ids: Iterable[str], where: str) -> dict[str, int]:
    """Item -> answer, in the order of ``ids``: every item answered once, each on the Likert
    scale. ``where`` names the form in the error (``P01 survey about 'full'``)."""
    want = list(ids)
    got = _validated(_Survey, f"{where}: item", answers=dict(answers)).answers
    missing = [i for i in want if i not in got]
    unknown = sorted(set(got) - set(want))
    if missing or unknown:
        raise StudyDataError(f"{where}: "
                             + (f"unanswered: {', '.join(missing)}" if missing else "")
                             + ("; " if missing and unknown else "")
                             + (f"unknown items: {', '.join(unknown)}" if unknown else ""))
    return {i: int(got[i]) for i in want}


def demographic_fields(fields: Mapping[Any, Any], where: str) -> dict[str, str]:
    """Field -> text, sorted by field; an empty form is a valid answer."""
    got = _validated(_Demographics, f"{where}: field",
                     fields={str(k): v for k, v in fields.items()}).fields
    return dict(sorted(got.items()))
