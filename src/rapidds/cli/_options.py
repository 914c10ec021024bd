"""Command options written from the run settings: each option's name, type, default and help
come from its :class:`~rapidds.loop.config.RunConfig` field (:func:`rapidds.settings.cli_field`),
so a setting is described once and every command that takes it says the same.

``@run_settings(*names)`` adds an option per named setting to a command and hands the command
the values given as one flat ``settings`` mapping (``RunConfig(**settings)``); a setting added
to :class:`RunConfig` is one more name here. Old spellings (a field's ``aliases``, or a
command's own) are accepted hidden and print one deprecation line on stderr.
"""

from __future__ import annotations

import functools
import inspect
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar, get_args, get_origin

import typer
from pydantic import BaseModel, TypeAdapter

from rapidds.errors import ConfigError
from rapidds.loop.config import RunConfig
from rapidds.settings import option_name

__all__ = [
    "AS_JSON",
    "HOST_HELP",
    "JSON_HELP",
    "POLICY",
    "PORT_HELP",
    "ROBOT",
    "RUN_ID",
    "RUN_OUT_HELP",
    "RUN_PANEL",
    "SCHEDULER",
    "SEARCH",
    "THREADS",
    "THREADS_HELP",
    "WORKERS",
    "deprecated",
    "describe",
    "gamma_settings",
    "run_settings",
    "study_checkpoint",
]

F = TypeVar("F", bound=Callable[..., Any])

SEARCH: tuple[str, ...] = ("population", "generations", "samples", "particles", "candidates")
"""The search options every command that plans shares."""
THREADS_HELP = "Torch CPU threads (1 is fastest on small machines)."
JSON_HELP = "Print one JSON object instead of text."
HOST_HELP = ("Address to listen on. Anything but a loopback address lets other machines connect; "
             "a wildcard (0.0.0.0, ::) listens on every interface and answers to this machine's "
             "own names and addresses (bind one address to be reached by it).")
RUN_OUT_HELP = "Folder for run.sqlite and the pictures."
PORT_HELP = "Port (0: any free one)."
AS_JSON: Any = typer.Option(False, "--json", help=JSON_HELP)
"""``as_json: bool = AS_JSON``: one JSON object on stdout instead of the text."""
RUN_PANEL = "Run settings"
POLICY: Any = typer.Option(
    None, help="Policy checkpoint: a directory, or one the world ships by name ('paper'; "
    "painting also 'distilled', a smaller network distilled from it: half the CPU per cycle, "
    "plans as well over the painting benchmark, docs/benchmarks.md 'Painting loop'). A stored "
    "run resumes only with the network it began with.",
    show_default="the world's bundled one: paper")
"""``policy: Path | None = POLICY``: the checkpoint of every command that loads a policy."""


def study_checkpoint(world: str, policy: Path | None) -> Path | None:
    """A study's ``--policy`` as the absolute directory its workers load (None: each worker
    loads the world's bundled one, as on a cluster whose machines install their own), loaded
    here once so that a bad checkpoint is one line before any worker starts."""
    if policy is None:
        return None
    from rapidds.experiments.ablation import network_fingerprint
    from rapidds.loop.context import policy_dir
    from rapidds.worlds.registry import make_world

    directory = policy_dir(make_world(world), policy).resolve()
    network_fingerprint(world, directory)
    return directory


THREADS: Any = typer.Option(1, min=1, max=256, help=THREADS_HELP)
"""``threads: int = THREADS``."""
ROBOT: Any = typer.Option("reference", "--robot", help="Robot profile: the driver's joint names, "
                          "offsets, limits and controller topic (reference, franka-panda, "
                          "franka-fr3).")
"""``robot: str = ROBOT``: the robot profile of every command that talks to a driver."""
RUN_ID: Any = typer.Option(None, "--run", help="Run id, when the store holds several.")
"""``run: str | None = RUN_ID``: which run of a store a command means."""
WORKERS: Any = typer.Option(None, help="Local Dask worker processes.",
                           show_default="one per CPU")
SCHEDULER: Any = typer.Option(None, help="Address of an existing Dask scheduler, e.g. "
                             "tcp://host:8786, instead of a local cluster.")
"""``workers``, ``scheduler``: where a study's trials run (ablation, study simulate)."""
_PANELS = {"objective": "Objective", "search": "Search", "spatial": "Spatial model",
           "teammate": "Simulated teammate", "changes": "Teammates who change",
           "learning": "Learning gamma"}


def describe(name: str) -> str:
    """The description of the run setting ``name``: the help of an option that takes it but
    checks its own bounds (``rapidds plan``'s search, on a problem file)."""
    return str(RunConfig.flat_fields()[name].description)


def deprecated(old: str, new: str) -> None:
    """One line on stderr for an old spelling that still works (for one release)."""
    typer.echo(f"rapidds: note: {old} is deprecated and will be removed; use {new}", err=True)


def gamma_settings(text: str | None) -> dict[str, Any]:
    """``--gamma``'s settings: 'learn' learns it, a number fixes it (its range is RunConfig's);
    anything else one line and exit 2."""
    if text is None:
        return {"gamma": None, "gamma_learn": False}
    if text.strip().lower() == "learn":
        return {"gamma": None, "gamma_learn": True}
    try:
        return {"gamma": float(text), "gamma_learn": False}
    except ValueError:
        raise ConfigError(f"--gamma is a number >= 0 or 'learn', got {text!r}") from None


_PARSE: dict[str, Callable[[Any], dict[str, Any]]] = {"gamma": gamma_settings}


def _option_type(annotation: Any, text: bool) -> Any:
    """The type typer parses an option as: the field's, without bounds; a choice as text."""
    if text:
        return str | None
    args = [a for a in get_args(annotation) if a is not type(None)]
    optional = get_origin(annotation) in (typing.Union, type(int | None)) and len(args) == 1
    base = args[0] if optional else annotation
    if get_origin(base) is Annotated:
        base = get_args(base)[0]
    if get_origin(base) is Literal:
        base = str
    return base | None if optional else base


def _group_of(name: str) -> str | None:
    for group, field in RunConfig.model_fields.items():
        ann = field.annotation
        if isinstance(ann, type) and name in getattr(ann, "model_fields", {}):
            return group
    return None


def _parameter(name: str, default: Any, panel: str | None) -> inspect.Parameter:
    """The typer parameter of the setting ``name``, its default ``default``."""
    field = RunConfig.flat_fields()[name]
    if isinstance(default, BaseModel):  # a typed setting (an execution entry): its stored form
        default = TypeAdapter(Annotated[(field.annotation, *field.metadata)]).dump_python(default)
    extra = field.json_schema_extra if isinstance(field.json_schema_extra, dict) else {}
    show = extra.get("show", True) if default == field.default else True  # a command's own
    kind = _option_type(field.annotation, bool(extra.get("text")))
    panel = panel or _PANELS.get(_group_of(name) or "", RUN_PANEL)
    if extra.get("argument"):
        info: Any = typer.Argument(help=field.description, show_default=show)
    else:
        decls = () if kind is bool else (option_name(name, field),)
        callback = None
        if name == "device":
            from rapidds.cli._device import check_device

            callback = check_device
        info = typer.Option(*decls, help=field.description, show_default=show,
                            rich_help_panel=panel, callback=callback)
    return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default,
                             annotation=Annotated[kind, info])


def _alias(key: str, old: str, kind: Any) -> inspect.Parameter:
    """A hidden option ``old`` for an old spelling; None (not given) unless typed."""
    return inspect.Parameter(key, inspect.Parameter.KEYWORD_ONLY, default=None,
                             annotation=Annotated[kind | None, typer.Option(old, hidden=True)])


def run_settings(*names: str, defaults: Mapping[str, Any] | None = None,
                 aliases: Mapping[str, str] | None = None, panel: str | None = None
                 ) -> Callable[[F], F]:
    """Give a command an option per run setting in ``names`` (flat names; defaults RunConfig's
    or ``defaults``'), plus hidden old spellings: each field's own and ``aliases`` (old option
    -> setting). The command takes the values as ``settings: dict[str, Any]``, flat, with
    ``--gamma`` already split into ``gamma`` and ``gamma_learn``."""
    fields = RunConfig.flat_fields()
    given = dict(defaults or {})
    olds: dict[str, tuple[str, str]] = {}  # parameter -> (old spelling, setting)
    for name in names:
        extra = fields[name].json_schema_extra
        for old in (extra.get("aliases", ()) if isinstance(extra, dict) else ()):
            olds[f"old_{len(olds)}"] = (old, name)
    for old, name in (aliases or {}).items():
        olds[f"old_{len(olds)}"] = (old, name)

    def wrap(func: F) -> F:
        hints = typing.get_type_hints(func, include_extras=True)
        own = [p.replace(annotation=hints.get(p.name, p.annotation))
               for p in inspect.signature(func).parameters.values() if p.name != "settings"]
        made = [_parameter(n, given.get(n, fields[n].default), panel) for n in names]
        extra = [_alias(key, old, _option_type(fields[name].annotation,
                                                _is_text(fields[name])))
                 for key, (old, name) in olds.items()]
        arguments = [p for p in made if _is_argument(p)]
        params = [*arguments, *own, *(p for p in made if not _is_argument(p)), *extra]
        params = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in params]

        @functools.wraps(func)
        def command(**kwargs: Any) -> Any:
            settings = {n: kwargs.pop(n) for n in names}
            for key, (old, name) in olds.items():
                value = kwargs.pop(key)
                if value is not None:
                    deprecated(old, _spelling(name, fields))
                    settings[name] = value
            for name, parse in _PARSE.items():
                if name in settings:
                    settings.update(parse(settings[name]))
            return func(**kwargs, settings=settings)

        command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
        command.__annotations__ = {p.name: p.annotation for p in params}
        return command  # type: ignore[return-value]

    return wrap


def _is_text(field: Any) -> bool:
    extra = field.json_schema_extra
    return isinstance(extra, dict) and bool(extra.get("text"))


def _is_argument(p: inspect.Parameter) -> bool:
    return any(isinstance(m, typer.models.ArgumentInfo) for m in get_args(p.annotation)[1:])


def _spelling(name: str, fields: Mapping[str, Any]) -> str:
    extra = fields[name].json_schema_extra
    if isinstance(extra, dict) and extra.get("argument"):
        return f"the {name.upper()} argument"
    return option_name(name, fields[name])
