"""How a cell's tracker is read into the world: which tracked source (a TF frame, a topic, a
PoseArray's pose) is which body point, and the rigid transform from the tracker's frame into the
world's (a :class:`TrackingMapping`, from YAML). Shared by recorded bags and their readers."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field, field_validator

from rapidds.bridge.boundaries import BoundaryRules
from rapidds.errors import ConfigError
from rapidds.settings import Settings, read_yaml
from rapidds.worlds.base import World, body_point_names
from rapidds.worlds.capabilities import capability

__all__ = ["RigidTransform", "TrackingMapping", "default_mapping", "load_mapping"]


class RigidTransform(Settings):
    """Tracker frame -> world frame: p_world = R(rotation) p + translation (metres; rotation a
    unit quaternion [x, y, z, w], normalised here)."""

    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    @field_validator("rotation")
    @classmethod
    def _unit(cls, v: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        n = math.sqrt(sum(c * c for c in v))
        if n < 1e-9:
            raise ValueError("a rotation quaternion cannot be zero")
        return (v[0] / n, v[1] / n, v[2] / n, v[3] / n)

    def matrix(self) -> np.ndarray:
        x, y, z, w = self.rotation
        return np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])

    def apply(self, p: np.ndarray) -> np.ndarray:
        return self.matrix() @ np.asarray(p, float) + np.asarray(self.translation)


class TrackingMapping(Settings):
    """Which tracked source is which body point (source: a TF child frame, a topic, or
    ``TOPIC/i`` for a PoseArray's i-th pose), and how the tracker's frame sits in the world.

    root_frame: TF frames are composed up to this frame, then ``transform`` takes them into
    the world. body_id: the ROS4HRI body whose frames fill ``{body}`` in the sources (None:
    the first tracked). boundaries: task boundaries from the cell's own signals."""

    points: Annotated[dict[str, str], Field(min_length=1)]
    transform: RigidTransform = RigidTransform()
    transforms: dict[str, RigidTransform] = Field(default_factory=dict)
    root_frame: Annotated[str, Field(min_length=1)] = "world"
    body_id: Annotated[str, Field(min_length=1)] | None = None
    boundaries: BoundaryRules | None = None

    def check(self, world: World) -> TrackingMapping:
        """This mapping, if it names only and every body point of ``world``; ConfigError else."""
        names = body_point_names(world)
        if unknown := sorted(set(self.points.values()) - set(names)):
            raise ConfigError(f"mapping: {unknown[0]!r} is not a body point of {world.name} "
                              f"({', '.join(names)})")
        if missing := [n for n in names if n not in self.points.values()]:
            raise ConfigError(f"mapping: no source for body point {missing[0]!r} of "
                              f"{world.name}")
        if stray := sorted(set(self.transforms) - set(self.points)):
            raise ConfigError(f"mapping: a transform for {stray[0]!r}, which is not a source")
        if self.boundaries is not None and (bad := self.boundaries.check(world.task_ids)):
            raise ConfigError(f"mapping: boundaries.order names {bad!r}, not a task of "
                              f"{world.name}")
        return self

    def to_world(self, source: str, p: np.ndarray, dim: int) -> np.ndarray:
        return self.transforms.get(source, self.transform).apply(p)[:dim]


def load_mapping(path: str | Path) -> TrackingMapping:
    """A mapping from YAML; ConfigError (one line) for a missing file, bad YAML or bad fields."""
    path = Path(path)
    raw = read_yaml(path, "mapping")
    try:
        return TrackingMapping(**raw)
    except ConfigError as exc:
        raise ConfigError(f"mapping {path}: {exc}") from None


def default_mapping(world: World) -> TrackingMapping:
    """The mapping the world ships (its ``tracking_mapping`` capability), else each body point
    tracked as the TF frame of its own name in the world frame."""
    ships = capability(world, "tracking_mapping")
    if ships is not None and ships.tracking_mapping.is_file():
        return load_mapping(ships.tracking_mapping).check(world)
    return TrackingMapping(points={n: n for n in body_point_names(world)}).check(world)
