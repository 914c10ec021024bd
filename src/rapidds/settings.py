"""Declarative settings: pydantic models whose validation errors are one readable line.

Every user-facing configuration (a run, a study, a world's options) derives from
:class:`Settings`: fields declare their bounds, and a bad value raises
:class:`~rapidds.errors.ConfigError` naming the option as the CLI spells it.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, ValidationError

from rapidds.errors import ConfigError

__all__ = ["Settings", "first_error", "memory_bytes", "read_yaml", "require_memory"]


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


def read_yaml(path: Path, what: str) -> dict[str, Any]:
    """The mapping in the YAML (or JSON) file ``path``; ConfigError naming ``what`` in one line
    for a missing file, bad YAML or a document that is not a mapping."""
    import yaml

    try:
        raw = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ConfigError(f"{what} {path}: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{what} {path}: not YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{what} {path}: not a mapping of settings")
    return raw


def memory_bytes() -> int:
    """Physical memory of this machine, bytes (0 where the platform does not say)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return 0


def require_memory(nbytes: float, what: str, share: float = 0.5) -> None:
    """Refuse up front (ConfigError) a request whose working set would need more than ``share``
    of the machine's memory, instead of letting it swap or be killed half-way."""
    total = memory_bytes()
    if total and nbytes > share * total:
        raise ConfigError(f"{what} would need about {nbytes / 2**30:,.1f} GiB of memory; "
                          f"this machine has {total / 2**30:,.1f} GiB")
