"""One person's spatial models, one grid belief per human task, and how they are saved."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from numpy.typing import ArrayLike
from pydantic import BaseModel, StrictStr, ValidationError

from rapidds.errors import StateError
from rapidds.fileio import atomic_write_text
from rapidds.human.spatial.config import SpatialConfig
from rapidds.human.spatial.grid import Points, SpatialCostModel, grid_trajectory_costs
from rapidds.human.spatial.surrogate import FitReport
from rapidds.settings import error_line

__all__ = ["FORMAT", "FORMAT_VERSION", "SpatialModel"]

FORMAT = "rapidds.spatial-model"
FORMAT_VERSION = 1


class _SpatialFile(BaseModel):
    """The stored form of a :class:`SpatialModel` (:meth:`SpatialModel.to_dict`); the config
    and each task's belief are checked by their own ``from_dict``."""

    format: Literal["rapidds.spatial-model"]
    version: Literal[1]
    config: dict[str, Any]
    tasks: dict[StrictStr, Any]


class SpatialModel:
    """One person's spatial models, one :class:`SpatialCostModel` per human task id."""

    def __init__(self, config: SpatialConfig, models: Mapping[str, SpatialCostModel]):
        for tid, m in models.items():
            if m.config != config:
                raise ValueError(f"task '{tid}' has a different SpatialConfig than the model")
        self.config = config
        self._models = dict(models)

    @classmethod
    def from_population(
        cls, config: SpatialConfig, trajectories: Mapping[str, Sequence[ArrayLike]]
    ) -> SpatialModel:
        """Prior models from population paths: task id -> list of (T, d) or (T, K, d) arrays
        (Eq. 9)."""
        return cls(config, {tid: SpatialCostModel.from_population(config, trajs)
                            for tid, trajs in trajectories.items()})

    @property
    def tasks(self) -> tuple[str, ...]:
        """Task ids with a model, in insertion order."""
        return tuple(self._models)

    def __getitem__(self, task_id: str) -> SpatialCostModel:
        try:
            return self._models[task_id]
        except KeyError:
            raise KeyError(f"no spatial model for task '{task_id}'; known: "
                           f"{list(self._models)}") from None

    def __contains__(self, task_id: object) -> bool:
        return task_id in self._models

    def __iter__(self) -> Iterator[str]:
        return iter(self._models)

    def __len__(self) -> int:
        return len(self._models)

    def observe(self, task_id: str, traj: ArrayLike,
                device: str | torch.device | None = None) -> None:
        """Update task ``task_id`` with one observed path (T, d) or (T, K, d) of this person;
        ``device``: where the update's distances are found (numpy's operations in numpy's
        order; None: the host)."""
        self[task_id].observe(traj, device)

    def refit(self, tasks: Iterable[str] | None = None) -> dict[str, FitReport]:
        """Refit the stale MLPs of ``tasks`` (default: all). Does nothing when
        ``config.use_surrogate`` is False, since then nothing evaluates the MLP."""
        if not self.config.use_surrogate:
            return {}
        ids = self.tasks if tasks is None else tuple(tasks)
        return {tid: self[tid].fit_surrogate() for tid in ids if self[tid].surrogate_stale}

    def cost(self, task_ids: Iterable[str], xi: Points) -> Points:
        """max_{i in task_ids} S_i(xi) for trajectories xi (N, H, d) -> (N,); 0 for no tasks."""
        ids = list(dict.fromkeys(task_ids))
        if not ids:
            arr = xi if isinstance(xi, torch.Tensor) else np.asarray(xi, dtype=np.float64)
            if arr.ndim != 3 or arr.shape[1] == 0 or arr.shape[-1] != self.config.dim:
                raise ValueError(f"trajectories must have shape (N, H, {self.config.dim}) with "
                                 f"H >= 1, got {tuple(arr.shape)}")
            if isinstance(arr, torch.Tensor):
                dtype = arr.dtype if arr.is_floating_point() else torch.float32
                return torch.zeros(arr.shape[0], dtype=dtype, device=arr.device)
            return np.zeros(arr.shape[0])
        models = [self[tid] for tid in ids]
        if not self.config.use_surrogate:
            costs = grid_trajectory_costs(models, xi)
        else:
            costs = [m.trajectory_cost(xi) for m in models]
        if isinstance(costs[0], torch.Tensor):
            return torch.stack(costs).amax(dim=0)
        return np.max(np.stack(costs), axis=0)

    # ----------------------------------------------------------------------- persistence
    def to_dict(self) -> dict[str, Any]:
        """JSON-safe: format tag and version, config, and each task's model dict."""
        return {"format": FORMAT, "version": FORMAT_VERSION, "config": self.config.to_dict(),
                "tasks": {tid: m.to_dict() for tid, m in self._models.items()}}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SpatialModel:
        """Inverse of :meth:`to_dict`; StateError on a wrong format, version or content."""
        try:
            doc = _SpatialFile.model_validate(data)
        except ValidationError as exc:
            raise StateError(f"spatial model: {error_line(exc, with_input=True)} (a "
                             f"{FORMAT} document of version {FORMAT_VERSION})") from None
        try:
            config = SpatialConfig.from_dict(doc.config)
        except (KeyError, TypeError, ValueError) as e:
            raise StateError(f"spatial model: bad config ({e})") from None
        models = {}
        for tid, entry in doc.tasks.items():
            m = SpatialCostModel.from_dict(entry)
            if m.config != config:
                raise StateError(f"spatial model: task '{tid}' was stored with another config")
            models[str(tid)] = m
        return cls(config, models)

    def save(self, path: str | Path) -> Path:
        """Write JSON {format, version, sha256, body} atomically (temp file + os.replace)."""
        body = self.to_dict()
        text = json.dumps(body, sort_keys=True, separators=(",", ":"))
        digest = hashlib.sha256(text.encode()).hexdigest()
        path = Path(path)
        atomic_write_text(path, f'{{"sha256":"{digest}","body":{text}}}')
        return path

    @classmethod
    def load(cls, path: str | Path, config: SpatialConfig | None = None) -> SpatialModel:
        """Read a file written by :meth:`save`. StateError when it is missing, unreadable,
        corrupt (checksum), of another format, or, given ``config``, saved with another one."""
        path = Path(path)
        try:
            raw = json.loads(path.read_text())
            body = raw["body"]
            digest = raw["sha256"]
        except FileNotFoundError:
            raise StateError(f"no spatial model at {path}") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as e:
            raise StateError(f"spatial model {path} is unreadable or corrupt ({e})") from None
        text = json.dumps(body, sort_keys=True, separators=(",", ":"))
        if hashlib.sha256(text.encode()).hexdigest() != digest:
            raise StateError(f"spatial model {path} is corrupt (checksum mismatch)")
        model = cls.from_dict(body)
        if config is not None and model.config != config:
            raise StateError(f"spatial model {path} was saved with a different SpatialConfig")
        return model
