"""One population prior per world and settings for the whole test session, its processes too.

``prior_model`` fits the spatial prior's surrogate MLPs (2-3 CPU s for painting) from the
world's population; it is deterministic (seeded, ``fork_rng``), and the in-process tests build
hundreds of runs, players and studies on the same few worlds and settings. The suite computes
each distinct prior once, with the real function, and hands every caller its own copy through
``HumanModel.to_bytes``/``from_bytes``: the copy ``AdaptiveRun(prior=...)`` and ``--resume``
already make, so a run learns into its own model exactly as from a fresh fit. The priors are
kept as files in the session's folder ``$RAPIDDS_TEST_PRIORS``, so the CLI processes the tests
start (a hub, ``rapidds run``) through :data:`CLI` read the prior the session already fitted
instead of fitting it again (written atomically: two processes may fit the same one at once)."""

from __future__ import annotations

import hashlib
import importlib
import importlib.abc
import importlib.util
import os
import pickle
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

USERS = ("rapidds.loop.model", "rapidds.loop.run", "rapidds.cli.run", "rapidds.cli.motion",
         "rapidds.web.study.runner", "rapidds.experiments.ablation")
"""Modules that call ``prior_model`` by a name of their own (``from ... import prior_model``)."""
ENV = "RAPIDDS_TEST_PRIORS"
"""The session's folder of fitted priors, inherited by the processes the tests start."""
CLI = [sys.executable, "-c", f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); "
       "import prior_cache; prior_cache.main()"]
"""``rapidds`` in a new process, on this interpreter, reading the session's priors."""


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
            store[key] = _load(key) or _save(key, real(world, cfg).to_bytes())
        return HumanModel.from_bytes(store[key])

    prior_model.__doc__ = real.__doc__
    prior_model.__wrapped__ = real  # type: ignore[attr-defined]
    return prior_model


def _load(key: str) -> bytes | None:
    folder = os.environ.get(ENV)
    path = Path(folder, f"{key}.prior") if folder else None
    return path.read_bytes() if path is not None and path.exists() else None


def _save(key: str, data: bytes) -> bytes:
    folder = os.environ.get(ENV)
    if folder:
        fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, Path(folder, f"{key}.prior"))
    return data


class _Hook(importlib.abc.MetaPathFinder):
    """Swaps in the cached ``prior_model`` once ``rapidds.loop.model`` is executed, before any
    module imports it by name; a process that never plans imports nothing more for it."""

    NAME = "rapidds.loop.model"

    def find_spec(self, name: str, path: Any, target: Any = None) -> Any:
        if name != self.NAME:
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return spec
        loader, run = spec.loader, spec.loader.exec_module

        def exec_module(module: Any) -> None:
            run(module)
            if callable(getattr(module, "prior_model", None)):
                module.prior_model = cached(module.prior_model)

        loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


def main() -> None:
    """``rapidds`` with the session's priors (:data:`CLI`); a plain ``rapidds`` without it."""
    if os.environ.get(ENV):
        sys.meta_path.insert(0, _Hook())
    from rapidds.cli import main as rapidds

    rapidds()


def install(folder: Path) -> Iterator[None]:
    """Swap ``prior_model`` for the cached one in every module that calls it, and keep the
    priors in ``folder`` for the processes started meanwhile; restore after."""
    import rapidds.loop.model as model

    old = os.environ.get(ENV)
    os.environ[ENV] = str(folder)

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
        if old is None:
            os.environ.pop(ENV, None)
        else:
            os.environ[ENV] = old
