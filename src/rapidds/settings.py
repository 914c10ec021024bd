"""Declarative settings: pydantic models whose validation errors are one readable line.

Every configuration, user-facing (a run, a study, a world's options) or internal (the genetic
search, the spatial model, the diffusion policy, steering), derives from :class:`Settings`:
fields declare their bounds, and a bad value raises :class:`~rapidds.errors.ConfigError` (also a
``ValueError``), one line naming the option. A class that is more than its settings (a world
with its routes and methods, a prior with its arithmetic) stays a dataclass and is declared
with :func:`settings_dataclass`: the same bounds on its fields, the same one ConfigError line.
:func:`error_line` is the one place a pydantic ``ValidationError`` becomes a line of text, here
and for the other validated inputs (problem files, browser messages, study forms).
"""

from __future__ import annotations

import dataclasses
import functools
import numbers
import operator
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any, ClassVar, TypeVar

import pydantic.dataclasses
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError

from rapidds.errors import ConfigError, RapiddsError

__all__ = ["Flag", "Int", "NonNegative", "Positive", "Real", "Settings", "SettingsGroup",
           "cli_field", "error_line", "memory_bytes", "option_name", "parse_yaml", "read_yaml",
           "require_memory", "settings_dataclass"]

C = TypeVar("C", bound=type)


def _bool_like(v: Any) -> bool:
    return isinstance(v, bool) or type(v).__name__ == "bool_"  # numpy's, without importing it


def _int(v: Any) -> int:
    """An int or a numpy integer; never a bool, a float (3.0 included) or a string."""
    if _bool_like(v) or isinstance(v, float | str | bytes):
        raise ValueError("must be an integer")
    try:
        return operator.index(v)
    except TypeError:
        raise ValueError("must be an integer") from None


def _real(v: Any) -> float:
    """An int, a float or a numpy number as a float; never a bool or a string."""
    if _bool_like(v) or not isinstance(v, numbers.Real):
        raise ValueError("must be a number")
    return float(v)


def _flag(v: Any) -> bool:
    """True or False (numpy's included); never 1, 0 or "yes"."""
    if not _bool_like(v):
        raise ValueError("must be true or false")
    return bool(v)


# Strict scalar types: pydantic's lax mode would take True for 1, "1.5" for 1.5 and "yes" for
# True; the hand checks these replace refused all three, and accepted numpy scalars.
Int = Annotated[int, BeforeValidator(_int)]
Real = Annotated[float, BeforeValidator(_real)]
Flag = Annotated[bool, BeforeValidator(_flag)]
Positive = Annotated[Real, Field(gt=0)]
NonNegative = Annotated[Real, Field(ge=0)]


def _loc_text(loc: tuple[Any, ...]) -> str:
    text = ""
    for part in loc:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text


@dataclasses.dataclass(frozen=True)
class Place:
    """How :func:`error_line` words the place of an error, where the default dotted path
    (``search.grid_points``) is not what its reader knows.

    option: name it as a CLI option (``--grid-points``); skip: leading parts to drop (a
    wrapper's field); quote: quote it ('name'); names: another name for a field (the CLI's
    option where it differs from the field's); locate: turns the place into words itself (a
    problem file names a task by its id, not its index).
    """

    option: bool = False
    skip: int = 0
    quote: bool = False
    names: Mapping[str, str] | None = None
    locate: Callable[[tuple[Any, ...]], str] | None = None


def error_line(exc: ValidationError, *, prefix: str = "", with_input: bool = False,
               empty: str = "", unknown: str = "", place: Place = Place()) -> str:
    """One line for the first error of a pydantic validation: ``where: what (got value)``.

    prefix: put before the place (e.g. ``GAConfig.``); with_input: append the offending value;
    empty: the place named when the error is about the whole input; unknown: what an unknown
    field is called instead of pydantic's words; place: how the place is worded.
    """
    err = exc.errors()[0]
    loc = tuple(err["loc"])[place.skip:]
    if place.names and loc and loc[0] in place.names:
        loc = (place.names[loc[0]], *loc[1:])
    msg = str(err["msg"])
    for tag in ("Value error, ", "Assertion failed, "):
        msg = msg.removeprefix(tag)
    if err["type"] == "extra_forbidden" and unknown:
        msg = unknown
    if place.locate is not None:
        where = place.locate(loc)
    elif place.option and loc:
        where = "--" + _loc_text(loc).replace("_", "-")
    else:
        where = _loc_text(loc)
    if where and place.quote:
        where = f"'{where}'"
    where = prefix + where if where else prefix.rstrip(". ") or empty
    got = f" (got {err['input']!r})" if with_input and loc and "input" in err else ""
    return f"{where}: {msg}{got}" if where else f"{msg}{got}"


def cli_field(default: Any, description: str, *, show: str | None = None,
              option: str | None = None, aliases: tuple[str, ...] = (), argument: bool = False,
              cli: bool = True, text: bool = False) -> Any:
    """A setting's field with its one description, the help its CLI option shows.

    show: what ``--help`` says the default is, where the value itself (None) says nothing;
    option: the option's name where it is not the field's (``--teammate-gamma``); aliases: old
    spellings still accepted, hidden, with a deprecation line; argument: the command's
    positional argument; cli: False for a setting no option sets directly; text: the option
    takes text that the command parses (``--gamma 2`` or ``--gamma learn``).
    """
    default_extra: dict[str, Any] = {"show": None, "option": None, "aliases": (),
                                     "argument": False, "cli": True, "text": False}
    extra: dict[str, Any] = {"show": show, "option": option, "aliases": aliases,
                             "argument": argument, "cli": cli, "text": text}
    return Field(default, description=description,
                 json_schema_extra={k: v for k, v in extra.items() if v != default_extra[k]})


def option_name(name: str, field: Any = None) -> str:
    """The CLI option of the setting ``name`` (its :func:`cli_field` ``option``, or the name
    with dashes)."""
    extra = getattr(field, "json_schema_extra", None)
    if isinstance(extra, dict) and extra.get("option"):
        return str(extra["option"])
    return "--" + name.replace("_", "-")


class Settings(BaseModel):
    """Frozen, no unknown fields, NaN and infinity refused; errors as one ConfigError line.

    ``label`` names the model in its errors (``GAConfig.population: ...``); without it the
    fields are named as the CLI's options (``--population: ...``), for the settings a user types.
    """

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)
    label: ClassVar[str | None] = None
    options: ClassVar[dict[str, str]] = {}  # field -> the CLI's option, where they differ

    def __init__(self, **data: Any) -> None:
        try:
            super().__init__(**data)
        except ValidationError as exc:
            raise ConfigError(self.error(exc)) from None

    @classmethod
    def error(cls, exc: ValidationError) -> str:
        """The one line this model's validation error reads as."""
        if cls.label is None:
            return error_line(exc, with_input=True, empty="settings", unknown="unknown setting",
                              place=Place(option=True, names=cls.options))
        return error_line(exc, prefix=f"{cls.label}.", with_input=True, unknown="unknown field")

    def replace(self, **changes: Any) -> Any:
        """A validated copy with ``changes`` applied (fields excluded from dumps kept too)."""
        kept = {k: getattr(self, k) for k, f in type(self).model_fields.items() if f.exclude}
        return type(self)(**{**self.model_dump(), **kept, **changes})


class SettingsGroup(BaseModel):
    """A group of settings inside a :class:`Settings` (a run's search, its teammate, ...):
    checked like its owner, whose one error line names the group's field. No ``__init__`` of
    its own, so that pydantic validates it as a part of its owner (a custom ``__init__`` would
    turn a field's error into one about the whole group)."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


def settings_dataclass(label: str, *, eq: bool = True, frozen: bool = True) -> Callable[[C], C]:
    """A frozen pydantic dataclass checked like :class:`Settings`: bounds declared on the fields
    (``Annotated[Real, Field(gt=0)]``), no unknown fields, NaN and infinity refused, and any
    error, a field's or one its ``__post_init__`` raises as ValueError (a check across
    fields), one :class:`ConfigError` line ``label.field: what (got value)``.

    For classes that are more than their settings (worlds, priors, teammates: methods, cached
    properties, fields computed in ``__post_init__``), which a ``BaseModel`` would not fit.
    ``eq=False``: compared by identity (a world holding arrays). ``frozen=False``: a belief
    that learns in place (checked when built, not on each later assignment).
    """
    config = ConfigDict(extra="forbid", allow_inf_nan=False, arbitrary_types_allowed=True)

    def wrap(cls: C) -> C:
        made: Any = pydantic.dataclasses.dataclass(cls, frozen=frozen, eq=eq, config=config)
        init = made.__init__
        names = [f.name for f in dataclasses.fields(made) if f.init]

        @functools.wraps(init)
        def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
            if len(args) > len(names):
                raise TypeError(f"{label} takes at most {len(names)} positional arguments")
            # by name, so that an error names the field, not the argument's position
            given = dict(zip(names, args, strict=False))
            if twice := sorted(given.keys() & kwargs.keys()):
                raise TypeError(f"{label} got multiple values for {', '.join(twice)}")
            kwargs.update(given)
            try:
                init(self, **kwargs)
            except ValidationError as exc:
                raise ConfigError(error_line(exc, prefix=f"{label}.", with_input=True,
                                             unknown="unknown field")) from None

        made.__init__ = __init__
        return made  # type: ignore[no-any-return]

    return wrap


@functools.cache
def _yaml_loader() -> type:
    """A safe loader (no object construction) with YAML 1.2's floats: ``1e308`` and ``1.5E3``
    are numbers, not strings (PyYAML follows YAML 1.1, which needs a dot and a signed
    exponent). Built on first use: yaml stays out of ``rapidds --help``."""
    import re

    import yaml

    class Loader(yaml.SafeLoader):
        pass

    Loader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
        list("-+0123456789."))
    return Loader


def parse_yaml(text: str, where: str, error: type[RapiddsError] = ConfigError) -> Any:
    """The document in ``text`` (YAML, or JSON, which is YAML); ``error`` in one line
    ``where: not valid YAML (line N: what)`` if it is not."""
    import json

    import yaml

    if text.lstrip()[:1] in ("{", "["):  # JSON read as JSON: YAML refuses its tab indents
        try:
            return json.loads(text)
        except (ValueError, RecursionError):
            pass  # flow-style YAML ({a: 1}) is not JSON
    try:
        return yaml.load(text, Loader=_yaml_loader())  # a SafeLoader: no object construction
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        at = f"line {mark.line + 1}: " if mark is not None else ""
        raise error(f"{where}: not valid YAML ({at}{what})") from None


def read_yaml(path: str | Path, what: str = "", *, error: type[RapiddsError] = ConfigError,
              mapping: bool = True) -> Any:
    """The document in the YAML (or JSON) file ``path``, the one reader of the files a user
    writes (run settings, problems, tracker mappings, survey items). ``error`` in one line
    naming ``what`` and the file for a missing or unreadable file, bad YAML, or (``mapping``)
    a document that is not a mapping."""
    path = Path(path)
    where = f"{what} {path}" if what else str(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise error(f"{where}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{where}: cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    raw = parse_yaml(text, where, error)
    if mapping and not isinstance(raw, dict):
        raise error(f"{where}: not a mapping of settings")
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
