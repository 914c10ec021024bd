"""The user study with simulated participants, on Dask: objective measures only.

Every participant of the stored design is one simulated person, drawn around their priming group
by the world (its ``participants`` capability: the painting world's
:func:`~rapidds.worlds.painting.teammates.individual`, with their own durations and hand paths)
from ``(study seed, position)``, so the same person uses every system. Each participant x system
is one Dask task: an :class:`~rapidds.loop.run.AdaptiveRun` of the study's rounds with the
system's adaptation level, starting from the population prior, on a worker without a store; the
client writes each finished run whole (:meth:`~rapidds.store.RunStore.record_trial`), so a rerun
skips the stored ones. Runs use the seed :meth:`.StudyStore.config_for` gives, shared by a
participant's systems (common random numbers within a person).

Simulated people answer no survey and rank nothing: this module writes rounds only.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rapidds.errors import RapiddsError
from rapidds.experiments.ablation import (
    StudyOutcome,
    TrialCallback,
    _worker_fingerprint,
    _worker_policy,
    _worker_world,
    check_network,
    network_fingerprint,
    store_results,
    worker_prior,
)
from rapidds.experiments.study.store import StudyStore
from rapidds.loop.config import RunConfig
from rapidds.worlds.capabilities import capability

if TYPE_CHECKING:
    from distributed import Client

    from rapidds.worlds.base import SimulatedTeammate, World

__all__ = ["PERSON_STREAM", "Trial", "person_rng", "run_trial",
           "simulate_study", "simulated_participant", "trials_to_run"]

PERSON_STREAM = 7_331
"""Random stream a simulated participant is drawn from: (study seed, position, PERSON_STREAM)."""


def person_rng(study_seed: int, position: int) -> np.random.Generator:
    return np.random.default_rng([study_seed, position, PERSON_STREAM])


def simulated_participant(world: World, name: str, levels: Mapping[str, str], study_seed: int,
                          position: int) -> SimulatedTeammate:
    """The simulated person of a participant: the same for every system."""
    drawn = capability(world, "participants")
    if drawn is None:
        raise RapiddsError(f"world '{world.name}' cannot simulate study participants (it does "
                           "not declare the participants capability)")
    try:
        return drawn.participant(name, dict(levels), person_rng(study_seed, position))
    except ValueError as exc:
        raise RapiddsError(f"world '{world.name}': {exc}") from None


@dataclass(frozen=True)
class Trial:
    """One participant x system: the run's config (resolved), the person's priming levels and
    where their random draw comes from."""

    run_id: str
    participant: str
    system: str
    config: dict[str, Any]
    levels: dict[str, str]
    study_seed: int
    position: int

    @property
    def key(self) -> str:
        """Dask key, unique per trial AND settings (a shared scheduler must not mix studies)."""
        digest = hashlib.sha1(json.dumps(asdict(self), sort_keys=True).encode()).hexdigest()
        return f"rapidds-study-{self.run_id}-{digest[:10]}"


def trials_to_run(store: StudyStore) -> tuple[list[Trial], int]:
    """The trials not yet stored whole, participants in design order and each one's systems in
    their order (a study stopped early is complete for its first participants); and how many
    trials the study has."""
    design = store.design
    out, total = [], 0
    for p in store.participants():
        for system in p.systems:
            total += 1
            if store.rounds_done(p.id, system) >= design.rounds:
                continue
            cfg = store.config_for(p.id, system)
            out.append(Trial(cfg.run_id, p.id, system, cfg.model_dump(), dict(p.factors),
                             design.seed, p.position))
    return out, total


# -- worker side ---------------------------------------------------------------------------------
def run_trial(trial: dict[str, Any], device: str = "auto", policy: Path | None = None
              ) -> dict[str, Any]:
    """Run one participant x system (all rounds) on ``device`` with the checkpoint ``policy``
    (None: the world's bundled one) and return its records and the network's fingerprint;
    the Dask task. Touches no files: the client stores the result."""
    import torch

    from rapidds.loop.run import AdaptiveRun

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    t = Trial(**trial)
    world = _worker_world(t.config["world"], t.config["variant"])
    cfg = RunConfig(**t.config, device=device).resolved(world)
    person = simulated_participant(world, t.participant, t.levels, t.study_seed, t.position)
    prior = worker_prior(cfg)
    run = AdaptiveRun(cfg, _worker_policy(cfg.world, cfg.device, policy), world=world,
                      teammate=person, prior=prior)
    records = [r.to_json() for r in run.run()]  # as stored: they cross to the client
    return {"run_id": run.config.run_id, "config": run.config.model_dump(), "records": records,
            "seconds": time.perf_counter() - t0,
            "policy": _worker_fingerprint(cfg.world, cfg.device, policy)}


# -- client side ---------------------------------------------------------------------------------
def simulate_study(store: StudyStore, client: Client, on_trial: TrialCallback | None = None,
                   on_start: Callable[[int, int], None] | None = None,
                   device: str = "auto", policy: Path | None = None) -> StudyOutcome:
    """Submit every participant x system not yet stored, store each as it finishes. A failed
    trial stops the study (the others are cancelled; what is stored stays). ``policy``: the
    checkpoint directory every run plans with (None: the bundled one); a study holds runs of
    one network (:func:`~rapidds.experiments.ablation.check_network`)."""
    check_network(store, network_fingerprint(store.base_config.world, policy))
    todo, total = trials_to_run(store)
    outcome = StudyOutcome(total=total, skipped=total - len(todo))
    outcome.workers = len(client.scheduler_info().get("workers", {}))
    if on_start is not None:
        on_start(total, outcome.skipped)
    t0 = time.perf_counter()
    futures = {client.submit(run_trial, asdict(t), device, policy, key=t.key, pure=False,
                             retries=0, priority=len(todo) - k): t
               for k, t in enumerate(todo)}
    store_results(client, futures, store, outcome, on_trial, t0, noun="run")
    return outcome
