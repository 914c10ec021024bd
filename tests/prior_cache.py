"""One population prior per world and settings for the whole test session.

``prior_model`` fits the spatial prior's surrogate MLPs (2-3 CPU s for painting) from the
world's population; it is deterministic (seeded, ``fork_rng``), and the in-process tests build
hundreds of runs, players and studies on the same few worlds and settings. The suite computes
each distinct prior once, with the real function, and hands every caller its own copy through
``HumanModel.to_bytes``/``from_bytes``: the copy ``AdaptiveRun(prior=...)`` and ``--resume``
already make, so a run learns into its own model exactly as from a fresh fit."""

from __future__ import annotations

import hashlib
import importlib
import pickle
import sys
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

USERS = ("rapidds.loop.model", "rapidds.loop.run", "rapidds.cli.run", "rapidds.cli.motion",
         "rapidds.web.study.runner", "rapidds.experiments.ablation")
"""Modules that call ``prior_model`` by a name of their own (``from ... import prior_model``)."""


def _key(world: Any, cfg: Any) -> str:
    """Everything ``prior_model`` reads: the world's population (durations and paths), its
    problem's tasks, the spatial model's settings and the forgetting factor."""
    from rapidds.loop.model import spatial_config

    prior = world.prior()
    h = hashlib.sha256()
    h.update(spatial_config(world, cfg).model_dump_json().encode())
    h.update(repr((cfg.forgetting, type(world).__qualname__, world.problem().ids)).encode())
    for task in sorted(prior.durations):
        h.update(task.encode())
        h.update(np.asarray(prior.durations[task], float).tobytes())
    for task in sorted(prior.paths):
        h.update(task.encode())
        for path in prior.paths[task]:
            a = np.ascontiguousarray(path, dtype=float)
            h.update(pickle.dumps(a.shape))
            h.update(a.tobytes())
    return h.hexdigest()


def cached(real: Callable[[Any, Any], Any]) -> Callable[[Any, Any], Any]:
    """``real`` (``prior_model``) computed once per distinct input; each call gets a copy."""
    from rapidds.loop.model import HumanModel

    store: dict[str, bytes] = {}

    def prior_model(world: Any, cfg: Any) -> Any:
        key = _key(world, cfg)
        if key not in store:
            store[key] = real(world, cfg).to_bytes()
        return HumanModel.from_bytes(store[key])

    prior_model.__doc__ = real.__doc__
    prior_model.__wrapped__ = real  # type: ignore[attr-defined]
    return prior_model


def install() -> Iterator[None]:
    """Swap ``prior_model`` for the cached one in every module that calls it; restore after."""
    import rapidds.loop.model as model

    real = model.prior_model
    fast = cached(real)
    swapped = []
    for name in USERS:
        try:
            mod = importlib.import_module(name)
        except ImportError:  # a module moved by a refactor: its runs just fit their own prior
            continue
        if getattr(mod, "prior_model", None) is real:
            mod.prior_model = fast  # type: ignore[attr-defined]
            swapped.append(mod)
    for mod in list(sys.modules.values()):  # any other rapidds module that imported it
        if getattr(mod, "__name__", "").startswith("rapidds.") and \
                getattr(mod, "prior_model", None) is real:
            mod.prior_model = fast  # type: ignore[attr-defined]
            swapped.append(mod)
    try:
        yield
    finally:
        for mod in swapped:
            mod.prior_model = real  # type: ignore[attr-defined]
