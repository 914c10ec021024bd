"""Worlds by name. Adding a world is adding a folder and one line in :data:`BUILTIN`.

Entries are ``"module:attribute"`` strings, imported only when a world is asked for, so
listing the worlds (``rapidds --help``) never imports a physics engine. The attribute is called
as ``factory(variant=...)`` and must return a :class:`~rapidds.worlds.base.World` (most simply
a :class:`~rapidds.worlds.base.WorldBase` with a spec), whose declared capabilities are checked.

Worlds from other packages join through the ``rapidds.worlds`` entry-point group
(``[project.entry-points."rapidds.worlds"] myworld = "mypkg.world:MyWorld"``), or, for a quick
local experiment, the environment variable ``RAPIDDS_WORLDS="name=module:attribute,..."``.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable
from functools import cache
from importlib.metadata import entry_points

from rapidds.errors import RapiddsError
from rapidds.worlds.base import World
from rapidds.worlds.capabilities import check_capabilities

__all__ = ["BUILTIN", "UnknownWorldError", "make_world", "register", "world_names"]

BUILTIN: dict[str, str] = {
    "fetch": "rapidds.worlds.fetch:FetchWorld",
    "painting": "rapidds.worlds.painting:PaintingWorld",
}

ENV_VAR = "RAPIDDS_WORLDS"
_registered: dict[str, str | Callable[..., World]] = {}


class UnknownWorldError(RapiddsError):
    """No world of that name (or variant) is registered."""


def register(name: str, factory: str | Callable[..., World]) -> None:
    """Make ``factory`` (a callable or a ``"module:attribute"`` string) available as ``name``."""
    if not name or not name.replace("-", "").replace("_", "").isalnum():
        raise ValueError(f"world names are letters, digits, '-' and '_'; got {name!r}")
    _registered[name] = factory
    make_world.cache_clear()


def _entries() -> dict[str, str | Callable[..., World]]:
    out: dict[str, str | Callable[..., World]] = dict(BUILTIN)
    for ep in entry_points(group="rapidds.worlds"):
        out.setdefault(ep.name, ep.value)
    for item in filter(None, (x.strip() for x in os.environ.get(ENV_VAR, "").split(","))):
        name, sep, target = item.partition("=")
        if not sep or ":" not in target:
            raise UnknownWorldError(f"{ENV_VAR}: expected 'name=module:attribute', got {item!r}")
        out[name.strip()] = target.strip()
    out.update(_registered)
    return out


def world_names() -> tuple[str, ...]:
    """Every world that can be made, built-in ones first."""
    return tuple(_entries())


def _resolve(name: str, target: str | Callable[..., World]) -> Callable[..., World]:
    if callable(target):
        return target
    module, _, attr = target.partition(":")
    try:
        return getattr(importlib.import_module(module), attr)  # type: ignore[no-any-return]
    except (ImportError, AttributeError) as exc:
        raise UnknownWorldError(f"world '{name}' ({target}) cannot be loaded: {exc}") from None


@cache
def make_world(name: str, variant: str | None = None) -> World:
    """The world ``name`` in ``variant`` (default: its first). Worlds are immutable, so one
    instance per (name, variant) is shared and its population prior computed once."""
    entries = _entries()
    if name not in entries:
        raise UnknownWorldError(f"unknown world '{name}'; available: {', '.join(entries)}")
    factory = _resolve(name, entries[name])
    world = factory()
    if not isinstance(world, World):
        raise UnknownWorldError(f"world '{name}' does not implement rapidds.worlds.base.World")
    try:
        check_capabilities(world)
    except ValueError as exc:
        raise UnknownWorldError(str(exc)) from None
    if variant is None or variant == world.variant:
        return world
    if variant not in world.variants:
        raise UnknownWorldError(f"world '{name}' has no variant '{variant}'; "
                                f"variants: {', '.join(world.variants)}")
    return factory(variant=variant)
