"""What the planner believes about the person (temporal + spatial models and past allocations),
how that belief starts (the world's population prior), and what an oracle knows instead."""

from __future__ import annotations

import json
import zlib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from rapidds.errors import RapiddsError, StateError
from rapidds.human.gamma import DEFAULT_SPREAD, GammaBelief, parse_gamma_prior
from rapidds.human.slowdowns import SlowdownBelief
from rapidds.human.spatial import SpatialConfig, SpatialModel
from rapidds.human.temporal import TemporalModel
from rapidds.loop.carry import Stamped, decode_plans, encode_plans
from rapidds.loop.config import RunConfig
from rapidds.motion.diffusion_motion import (
    DeviceHold,
    DeviceTermsFactory,
    HoldTime,
    HostTerms,
    ValueTerms,
)
from rapidds.motion.interface import MotionKey
from rapidds.scheduler import AllocationHistory
from rapidds.worlds.base import SimulatedTeammate, Teammate, World
from rapidds.worlds.capabilities import capability, robot_duration
from rapidds.worlds.changes import changing_teammate


@dataclass
class ChangeLog:
    """What change detection needs beyond the models: the cycle of every observation of each
    task (index-aligned with the temporal model's observations), the index up to which the
    person confirmed they had not changed (a denied question), and the last cycle a change was
    acted on."""

    cycles: dict[str, list[int]] = field(default_factory=dict)
    unchanged_until: dict[str, int] = field(default_factory=dict)
    last_change: int | None = None

    def to_dict(self) -> dict[str, object]:
        return {"cycles": self.cycles, "unchanged_until": self.unchanged_until,
                "last_change": self.last_change}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ChangeLog:
        cycles = {str(k): [int(c) for c in v] for k, v in d["cycles"].items()}
        until = {str(k): int(v) for k, v in d["unchanged_until"].items()}
        last = d.get("last_change")
        return cls(cycles, until, None if last is None else int(last))

__all__ = [
    "ChangeLog",
    "HumanModel",
    "check_teammate",
    "gamma_prior",
    "oracle_spatial",
    "prior_model",
    "spatial_config",
    "workspace_cost",
]


@dataclass
class HumanModel:
    """What the planner believes about the person, with the past allocations and the steered
    motions carried to the next cycle (:mod:`rapidds.loop.carry`); serialised after every
    cycle."""

    temporal: TemporalModel
    spatial: SpatialModel
    history: AllocationHistory = field(default_factory=AllocationHistory)
    motions: dict[MotionKey, Stamped] = field(default_factory=dict)
    changes: ChangeLog = field(default_factory=ChangeLog)
    gamma: GammaBelief | None = None  # only when the run learns gamma
    slowdowns: SlowdownBelief | None = None  # only when the run learns the monitor's holds

    def to_bytes(self) -> bytes:
        doc = {"temporal": self.temporal.to_dict(), "spatial": self.spatial.to_dict(),
               "history": self.history.to_dict(), "motions": encode_plans(self.motions),
               "changes": self.changes.to_dict()}
        if self.gamma is not None:  # absent otherwise: models of fixed-gamma runs unchanged
            doc["gamma"] = self.gamma.to_dict()
        if self.slowdowns is not None:  # likewise
            doc["slowdowns"] = self.slowdowns.to_dict()
        return zlib.compress(json.dumps(doc, allow_nan=False).encode())

    @classmethod
    def from_bytes(cls, data: bytes) -> HumanModel:
        try:
            doc = json.loads(zlib.decompress(data))
            return cls(TemporalModel.from_dict(doc["temporal"]),
                       SpatialModel.from_dict(doc["spatial"]),
                       AllocationHistory.from_dict(doc["history"]),
                       decode_plans(doc.get("motions", [])),
                       ChangeLog.from_dict(doc["changes"]) if "changes" in doc else ChangeLog(),
                       GammaBelief.from_dict(doc["gamma"]) if "gamma" in doc else None,
                       SlowdownBelief.from_dict(doc["slowdowns"]) if "slowdowns" in doc
                       else None)
        except (zlib.error, ValueError, TypeError, KeyError) as exc:
            raise StateError(f"stored human model is corrupt ({exc})") from None


def spatial_config(world: World, cfg: RunConfig) -> SpatialConfig:
    """The spatial model's grid over the world's shared workspace (``cfg`` resolved)."""
    lo, hi = world.workspace_bounds
    assert cfg.beta is not None and cfg.grid_points is not None, "resolve the config first"
    return SpatialConfig.from_box(lo, hi, beta=cfg.beta, rho=cfg.rho,
                                  grid_points=cfg.grid_points, use_surrogate=cfg.surrogate,
                                  seed=cfg.seed, forgetting=cfg.forgetting)


def prior_model(world: World, cfg: RunConfig) -> HumanModel:
    """A new teammate's model: temporal and spatial priors from the world's population
    (paper Eq. 9 for the spatial one)."""
    prior = world.prior()
    spatial = SpatialModel.from_population(spatial_config(world, cfg), prior.paths)
    spatial.refit()
    return HumanModel(TemporalModel.from_population(world.problem(), prior.durations,
                                                    forgetting=cfg.forgetting), spatial)


def gamma_prior(world: World, cfg: RunConfig) -> GammaBelief:
    """The belief over a new person's gamma: ``cfg.gamma_prior`` or the world's gamma (spread
    :data:`~rapidds.human.gamma.DEFAULT_SPREAD`); the likelihood's reference is the world's."""
    g_ref = world.problem().objective.gamma
    g0, spread = (parse_gamma_prior(cfg.gamma_prior) if cfg.gamma_prior is not None
                  else (g_ref, DEFAULT_SPREAD))
    return GammaBelief(g0, spread, g_ref)


def oracle_spatial(world: World, cfg: RunConfig, teammate: SimulatedTeammate,
                   n: int = 24) -> SpatialModel:
    """The person's true expected spatial cost: Eq. 9 over ``n`` of their own paths per task."""
    rng = np.random.default_rng([cfg.seed, 7919])
    tasks = [t.id for t in world.problem().tasks if t.can("human")]
    own = {t: [teammate.perform(t, rng)[1] for _ in range(n)] for t in tasks}
    model = SpatialModel.from_population(spatial_config(world, cfg), own)
    model.refit()
    return model


def workspace_cost(
    world: World, spatial: SpatialModel
) -> Callable[[Iterable[str], np.ndarray], np.ndarray]:
    """max_{i in C_j} S_i of robot trajectories (N, H, d), taken over the robot's workspace
    points (identity for a mobile robot, forward kinematics for an arm)."""

    def cost(tasks: Iterable[str], xi: np.ndarray) -> np.ndarray:
        return _points_cost(spatial, tasks, world.robot_points(xi))

    return cost


def _points_cost(spatial: SpatialModel, tasks: Iterable[str], points: Any) -> Any:
    """max_{i in tasks} S_i of the workspace points (N, H, P, w) of N trajectories."""
    return spatial.cost(tasks, points.reshape(points.shape[0], -1, points.shape[-1]))


def value_terms(world: World, spatial: SpatialModel, hold: HoldTime | None = None,
                device_hold: DeviceHold | None = None) -> ValueTerms:
    """What ``world`` adds to a run's steering value: its robot's timed duration, its terms
    on a device and on the host where it has them, and ``hold``, the safety monitor's (with
    ``device_hold``, the same as tensor operations, so that a GPU scores it)."""
    return ValueTerms(duration=robot_duration(world), hold=hold, device_hold=device_hold,
                      device_terms=device_terms(world, spatial),
                      host_terms=host_terms(world, spatial))


def host_terms(world: World, spatial: SpatialModel) -> HostTerms | None:
    """The host's steering value from arm points computed once per denoising step, for a
    world whose completion time takes them (the ``point_values`` capability); None for the
    others. The same V, to the bit, as ``world.completion_time`` and :func:`workspace_cost`."""
    values = capability(world, "point_values")
    return (None if values is None else
            _WorkspaceTerms(values.robot_points, values.completion_time_from_points, spatial))


class _SpatialTerm:
    """The spatial model's cost of workspace points (N, H, P, w), arrays or tensors."""

    def __init__(self, spatial: SpatialModel):
        self.spatial = spatial

    def spatial_cost(self, tasks: Iterable[str], points: Any) -> Any:
        return _points_cost(self.spatial, tasks, points)


class _WorkspaceTerms(_SpatialTerm):
    """:class:`~rapidds.motion.diffusion_motion.HostTerms` (arrays): a world's workspace
    points and completion time from them, and the spatial model's cost of the points."""

    def __init__(self, points: Callable[[Any], Any],
                 completion_time: Callable[[str, Any, Any], Any], spatial: SpatialModel):
        super().__init__(spatial)
        self.points, self.completion_time = points, completion_time


class _TensorWorkspaceTerms(_SpatialTerm):
    """:class:`~rapidds.motion.diffusion_motion.DeviceTerms`: the same on tensors, the
    completion time of a whole batch at once."""

    def __init__(self, terms: Any, spatial: SpatialModel):
        super().__init__(spatial)
        self.points, self.completion_times = terms.points, terms.completion_times


def device_terms(world: World, spatial: SpatialModel) -> DeviceTermsFactory | None:
    """The steering value's terms on a device, for a world that has them as tensor operations
    (the ``tensor_values`` capability); None for the others, whose value stays on the host.
    The same V as :func:`workspace_cost` with the world's completion time."""
    tensors = capability(world, "tensor_values")
    if tensors is None:
        return None

    def on(device: torch.device) -> _TensorWorkspaceTerms:
        return _TensorWorkspaceTerms(tensors.tensor_terms(device), spatial)

    return on


def check_teammate(world: World, cfg: RunConfig, teammate: Teammate | None) -> Teammate:
    """The run's teammate: the injected one (a live person) or the world's simulated one,
    changing as ``cfg.change`` and ``cfg.drift`` say."""
    if teammate is not None:
        return teammate
    assert cfg.human is not None
    if cfg.human not in world.teammate_names:
        raise RapiddsError(f"unknown human '{cfg.human}' for world {world.name}; one of "
                           f"{', '.join(world.teammate_names)}")
    try:
        return changing_teammate(world, cfg.human, cfg.change, cfg.drift, cfg.drift_from)
    except ValueError as exc:
        raise RapiddsError(str(exc)) from None
