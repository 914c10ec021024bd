"""Declarative settings: pydantic models whose validation errors are one readable line.

Every user-facing configuration (a run, a study, a world's options) derives from
:class:`Settings`: fields declare their bounds, and a bad value raises
:class:`~rapidds.errors.ConfigError` naming the option as the CLI spells it.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, ValidationError

from rapidds.errors import ConfigError

__all__ = ["Settings", "first_error"]


def first_error(exc: ValidationError) -> str:
    """``--option: what is wrong`` for the first error of a pydantic validation."""
    err = exc.errors()[0]
    loc = ".".join(str(x) for x in err["loc"])
    name = f"--{loc.replace('_', '-')}" if loc else "settings"
    msg = err["msg"]
    if err["type"] == "extra_forbidden":
        msg = "unknown setting"
    return f"{name}: {msg}" + (f" (got {err['input']!r})" if "input" in err and loc else "")


class Settings(BaseModel):
    """Frozen, no unknown fields, NaN and infinity refused; errors as one line."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    def __init__(self, **data: Any) -> None:
        try:
            super().__init__(**data)
        except ValidationError as exc:
            raise ConfigError(first_error(exc)) from None

    def replace(self, **changes: Any) -> Any:
        """A validated copy with ``changes`` applied."""
        return type(self)(**{**self.model_dump(), **changes})
