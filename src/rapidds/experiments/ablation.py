"""The fetch ablation study on Dask: archetypes x adaptation levels x trials, one task per trial.

A trial is one :class:`~rapidds.loop.AdaptiveRun` of all its cycles. It runs inside a Dask
worker WITHOUT a store (a real cluster's workers cannot reach the client's disk) and returns its
cycle records; the client writes each finished trial into ``DIR/study.sqlite`` in one
transaction (:meth:`~rapidds.store.RunStore.record_trial`). So a killed worker or a killed run
loses only the trials in flight, a rerun skips every stored trial, and a trial Dask re-ran after a
worker died is stored once.

Trial ``i`` of study seed ``s`` runs with seed ``s * TRIAL_STRIDE + i`` for every archetype and
level: common random numbers across levels, and trial ``i`` of ``--seed 0`` is exactly
``rapidds run --seed i`` with the same search settings.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, ClassVar

from pydantic import Field, field_validator

from rapidds.errors import RapiddsError, RuntimeFault, StateError
from rapidds.loop.config import ADAPT_LEVELS, Execution, RunConfig, Slowdowns
from rapidds.settings import Flag, Int, Real, Settings
from rapidds.store import RunStore

if TYPE_CHECKING:
    from distributed import Client

    from rapidds.loop.model import HumanModel
    from rapidds.motion.policy import DiffusionPolicy
    from rapidds.worlds.base import World

ARCHETYPES: tuple[str, ...] = ("fast-middle", "fast-outside", "slow-middle", "slow-outside")
"""The fetch world's teammates (the study is the paper's fetch ablation)."""
PAPER_HUMANS: tuple[str, ...] = ("fast-outside", "slow-middle", "fast-middle", "slow-outside")
"""The archetypes in the order of the paper's Figure 5 panels."""
ABLATION: tuple[str, ...] = ("full", "spatial", "temporal", "none")
BASELINES: tuple[str, ...] = ("oracle", "exact")
TRIAL_STRIDE = 10_000  # trial seeds of one study seed never reach the next one's
STORE_NAME = "study.sqlite"
_PER_TRIAL = ("human", "adapt", "seed")  # what differs between the runs of one study


_RUN = RunConfig.flat_fields()


def _levels_field(name: str, known: tuple[str, ...]) -> Callable[[Any], Any]:
    def check(given: tuple[str, ...]) -> tuple[str, ...]:
        if not given:
            raise ValueError(f"is empty; choose from {', '.join(known)}")
        unknown = [g for g in given if g not in known]
        if unknown:
            raise ValueError(f"unknown value '{unknown[0]}'; one of {', '.join(known)}")
        if len(set(given)) != len(given):
            raise ValueError(f"lists a value twice: {','.join(given)}")
        return given
    check.__name__ = f"_check_{name}"
    return check


WORLD = "fetch"
"""The world of the paper's ablation study (its every trial)."""


class AblationConfig(Settings):
    """One ablation study: which cells and how many trials, and the settings every trial shares.

    The search settings are a run's (:class:`~rapidds.loop.config.RunConfig`, their one home)
    except the steering, cheaper here (chosen by measurement, docs/reproduction.md): the full
    study has to fit in 30 minutes on 2 cores. The user study's simulation uses the same.
    """

    options: ClassVar[dict[str, str]] = {"levels": "adapt"}  # the CLI's name for a field

    humans: tuple[str, ...] = PAPER_HUMANS
    levels: tuple[str, ...] = ABLATION + BASELINES
    trials: Annotated[Int, Field(ge=1, le=TRIAL_STRIDE)] = 20
    cycles: Int = _RUN["cycles"].default
    seed: Annotated[Int, Field(ge=0)] = 0
    gamma: Real = 1.75
    lam: Real = 15.0
    population: Int = _RUN["population"].default
    generations: Int = _RUN["generations"].default
    samples: Int = _RUN["samples"].default
    patience: Int = _RUN["patience"].default
    particles: Int = 2
    candidates: Int = 4
    execution: Execution = "planned"  # inside the cycle (RunConfig's)
    reacts: Flag = False
    deviate: Annotated[Real, Field(ge=0, le=1)] = 0.0
    slowdowns: Slowdowns | None = None  # RunConfig's: None is learned under reactive execution

    _humans = field_validator("humans")(_levels_field("humans", ARCHETYPES))
    _levels = field_validator("levels")(_levels_field("levels", ADAPT_LEVELS))

    def __init__(self, **data: Any) -> None:
        super().__init__(**data)
        self._trial(self.humans[0], self.levels[0], 0)  # the shared settings, checked as a run's

    def trial_seed(self, index: int) -> int:
        return self.seed * TRIAL_STRIDE + index

    def _trial(self, human: str, level: str, index: int) -> RunConfig:
        return RunConfig(world=WORLD, human=human, adapt=level, cycles=self.cycles,
                         gamma=self.gamma, lam=self.lam, seed=self.trial_seed(index),
                         population=self.population, generations=self.generations,
                         samples=self.samples, patience=self.patience,
                         particles=self.particles, candidates=self.candidates,
                         execution=self.execution, reacts=self.reacts,  # type: ignore[arg-type]
                         deviate=self.deviate, slowdowns=self.slowdowns)

    def run_config(self, human: str, level: str, index: int) -> RunConfig:
        """The trial's settings, resolved against the fetch world (what is stored)."""
        from rapidds.worlds.registry import make_world

        return self._trial(human, level, index).resolved(make_world(WORLD))

    def trials_in_order(self) -> list[RunConfig]:
        """Every trial, trial index outermost: a study stopped early holds about as many trials
        of every cell, and fast (``exact``) and slow trials interleave across workers."""
        return [self.run_config(h, lv, i) for i in range(self.trials)
                for h in self.humans for lv in self.levels]

    def shared(self) -> dict[str, Any]:
        """The settings every run of this study shares (what a folder may hold only one of)."""
        return shared_settings(self.run_config(self.humans[0], self.levels[0], 0).model_dump())


def shared_settings(run_config: dict[str, Any]) -> dict[str, Any]:
    """A stored run's config without what varies per trial, plus the study seed it came from;
    a setting added after the run was stored counts as its default (what the run ran with)."""
    run_config = {**{k: f.default for k, f in RunConfig.flat_fields().items()
                     if k not in run_config}, **run_config}
    out = {k: v for k, v in run_config.items() if k not in _PER_TRIAL}
    out["study_seed"] = int(run_config["seed"]) // TRIAL_STRIDE
    return out


# --------------------------------------------------------------------------------------------
# worker side


# What a worker process computes once and every trial it runs shares (policy, world, population
# prior): a trial of the fetch study took 2.4 s, 0.2 s of it the prior when every trial made its
# own. The run copies the prior before it learns, so sharing it changes no record.
@lru_cache(maxsize=4)
def _worker_policy(world: str, device: str = "auto", policy: Path | None = None
                   ) -> DiffusionPolicy:
    """Loaded once per worker process, device and checkpoint (``policy``: a directory the
    client resolved; None: the world's bundled one), not once per trial (a load is ~0.3 s)."""
    from rapidds.loop.run import load_policy

    return load_policy(_worker_world(world, None), policy, device=device)


@lru_cache(maxsize=4)
def _worker_fingerprint(world: str, device: str = "auto", policy: Path | None = None) -> str:
    return _worker_policy(world, device, policy).fingerprint()


def network_fingerprint(world: str, policy: Path | None) -> str:
    """The fingerprint of the network a study's trials would plan with (loaded on the CPU:
    it names the weights, not the device), for :func:`check_network` before any trial runs."""
    return _worker_fingerprint(world, "cpu", policy)


def check_network(store: RunStore, fingerprint: str) -> None:
    """A folder's runs all plan with one network: another is refused before a trial runs
    (runs stored before networks were kept take this one, as a resumed run does)."""
    for rid in store.run_ids():
        store.claim_policy(rid, fingerprint)


@lru_cache(maxsize=2)
def _worker_world(name: str, variant: str | None) -> World:
    from rapidds.worlds.registry import make_world

    return make_world(name, variant)


@lru_cache(maxsize=4)
def _worker_prior(name: str, variant: str | None, key: str) -> HumanModel:
    """The population prior, computed once per worker (the painting one takes seconds). ``key``
    is the settings it depends on (:func:`_prior_key`)."""
    from rapidds.loop.model import prior_model

    return prior_model(_worker_world(name, variant), RunConfig(**json.loads(key)))


def _prior_key(cfg: RunConfig) -> str:
    """What :func:`~rapidds.loop.model.prior_model` reads of a resolved config: the world's
    spatial settings, the forgetting factor, and the seed only where the surrogate network,
    which it seeds, is used."""
    keep = {"world": cfg.world, "variant": cfg.variant, "beta": cfg.beta, "rho": cfg.rho,
            "grid_points": cfg.grid_points, "surrogate": cfg.surrogate,
            "forgetting": cfg.forgetting, "seed": cfg.seed if cfg.surrogate else 0}
    return json.dumps(keep, sort_keys=True)


def worker_prior(cfg: RunConfig) -> HumanModel:
    """The population prior of a resolved ``cfg``, shared by the worker's trials."""
    return _worker_prior(cfg.world, cfg.variant, _prior_key(cfg))


def run_trial(config: dict[str, Any], device: str = "auto", policy: Path | None = None
              ) -> dict[str, Any]:
    """Run one trial (all its cycles) on ``device`` with the checkpoint ``policy`` (None: the
    world's bundled one) and return its records and the network's fingerprint; the Dask
    task. Touches no files: the client stores the result."""
    import torch

    from rapidds.loop.run import AdaptiveRun

    torch.set_num_threads(1)  # one task per worker thread; more threads only fight
    t0 = time.perf_counter()
    cfg = RunConfig(**config, device=device)
    world = _worker_world(cfg.world, cfg.variant)
    cfg = cfg.resolved(world)
    run = AdaptiveRun(cfg, _worker_policy(cfg.world, cfg.device, policy), world=world,
                      prior=worker_prior(cfg))
    records = [r.to_json() for r in run.run()]  # as stored: they cross to the client
    return {"run_id": run.config.run_id, "config": run.config.model_dump(), "records": records,
            "seconds": time.perf_counter() - t0, "pid": os.getpid(),
            "policy": _worker_fingerprint(cfg.world, cfg.device, policy)}


# --------------------------------------------------------------------------------------------
# client side


@dataclass
class StudyOutcome:
    """total: trials in the study; skipped: already stored before; ran: stored by this call;
    failed: (run_id, reason) of each trial that failed in this call (kept in the store)."""

    total: int
    skipped: int
    ran: int = 0
    wall_s: float = 0.0
    workers: int = 0
    trial_seconds: list[float] = field(default_factory=list)
    failed: list[tuple[str, str]] = field(default_factory=list)


TrialCallback = Callable[[dict[str, Any], int, int], None]
"""on_trial(result, stored_so_far, total), called after each trial is stored."""


@contextmanager
def ablation_store(out: Path) -> Iterator[RunStore]:
    """``DIR/study.sqlite``, with ``DIR/.lock`` held so two studies never write one folder (the
    lock dies with its process, so a killed run never leaves it behind)."""
    with RunStore(out / STORE_NAME, lock_as="rapidds ablation") as store:
        yield store


def check_settings(study: AblationConfig, store: RunStore) -> None:
    """A folder holds one study: more trials, archetypes or levels may be added to it later,
    other cycles, seeds or search settings may not (their curves could not be compared)."""
    ids = store.run_ids()
    if not ids:
        return
    # every stored run passed this check when it was stored: the first stands for all
    want, have = study.shared(), shared_settings(store.run_config(ids[0]) or {})
    if have != want:
        diff = ", ".join(f"{k}={have.get(k)} (asked {want.get(k)})"
                         for k in sorted(set(have) | set(want)) if have.get(k) != want.get(k))
        raise StateError(f"{store.path.parent} holds a study with other settings: {diff}; "
                         "use another --out or the same settings")


def finished_run_ids(store: RunStore, cycles: int) -> set[str]:
    return {rid for rid in store.run_ids() if store.last_cycle(rid) == cycles - 1}


def _task_key(cfg: RunConfig) -> str:
    """Unique per run AND settings: a shared scheduler must not hand one study another's result."""
    digest = hashlib.sha1(json.dumps(cfg.model_dump(), sort_keys=True).encode()).hexdigest()[:10]
    return f"rapidds-trial-{cfg.run_id}-{digest}"


def run_ablation(
    study: AblationConfig, store: RunStore, client: Client, on_trial: TrialCallback | None = None,
    on_start: Callable[[int, int], None] | None = None, device: str = "auto",
    policy: Path | None = None,
) -> StudyOutcome:
    """Submit every trial not yet stored, store each as it finishes; returns the counts.
    ``on_start(total, already_stored)`` is called once before the first result; every trial
    runs its policy on ``device`` (not part of the stored settings). ``policy``: the
    checkpoint directory every trial plans with (None: the bundled one); a folder holds
    trials of one network (:func:`check_network`).

    A trial that fails (a runtime fault, a bug) is kept as failed with its reason and the
    others run on; a user error raised on a worker (e.g. no bundled policy), which every trial
    would raise, stops the study (see :func:`store_results`). A rerun retries failed trials.
    """
    check_settings(study, store)
    check_network(store, network_fingerprint(WORLD, policy))
    done = finished_run_ids(store, study.cycles)
    todo = [cfg for cfg in study.trials_in_order() if cfg.run_id not in done]
    outcome = StudyOutcome(total=study.trials * len(study.humans) * len(study.levels),
                           skipped=0)
    outcome.skipped = outcome.total - len(todo)
    outcome.workers = len(client.scheduler_info().get("workers", {}))
    if on_start is not None:
        on_start(outcome.total, outcome.skipped)
    t0 = time.perf_counter()
    # priority: in study order (Dask would otherwise pick freely among queued tasks)
    futures = {client.submit(run_trial, cfg.model_dump(), device, policy, key=_task_key(cfg),
                             pure=False,
                             retries=0, priority=len(todo) - k): cfg
               for k, cfg in enumerate(todo)}
    store_results(client, futures, store, outcome, on_trial, t0)
    return outcome


def store_results(client: Client, futures: dict[Any, Any], store: RunStore,
                  outcome: StudyOutcome, on_trial: TrialCallback | None, t0: float,
                  noun: str = "trial") -> None:
    """Store each submitted run as its Dask future finishes (``futures``: future -> its
    :class:`~rapidds.loop.config.RunConfig` or anything with a ``run_id`` and a ``config``
    dict), counting into ``outcome``. A run that failed on its own (a
    :class:`~rapidds.errors.RuntimeFault`, an unexpected exception) is kept as failed with its
    reason (:meth:`~rapidds.store.RunStore.record_failure`) and the others go on; a user error
    raised on a worker (every run would raise it) or a worker killed repeatedly stops
    everything: the runs still in flight are cancelled, what is stored stays. Shared by the
    ablation study and the simulated user study."""
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    stored = outcome.skipped
    try:
        for fut in as_completed(list(futures)):
            item = futures.pop(fut)
            run_id = item.run_id
            if fut.status == "error":
                exc = fut.exception()
                if isinstance(exc, RapiddsError) and not isinstance(exc, RuntimeFault):
                    raise exc
                if isinstance(exc, KilledWorker):
                    raise RapiddsError(f"{noun} {run_id} killed its worker repeatedly "
                                       f"(out of memory?); {stored} {noun}s are stored, "
                                       "rerun to continue") from exc
                reason = (str(exc) if isinstance(exc, RuntimeFault)
                          else f"{type(exc).__name__}: {exc}")
                config = item.model_dump() if hasattr(item, "model_dump") else dict(item.config)
                store.record_failure(run_id, config, reason)
                outcome.failed.append((run_id, reason))
                fut.release()
                continue
            if fut.status == "cancelled":
                raise RapiddsError(f"{noun} {run_id} was cancelled by the Dask scheduler; "
                                   f"{stored} {noun}s are stored, rerun to continue")
            result = fut.result()
            fut.release()
            if result["run_id"] != run_id:  # pragma: no cover - a key collision
                raise StateError(f"task for {run_id} returned {result['run_id']}")
            if "policy" in result:  # refused if the checkpoint changed since the check
                store.claim_policy(run_id, result["policy"])
            if store.record_trial(run_id, result["config"], result["records"]):
                outcome.ran += 1
                stored += 1
                outcome.trial_seconds.append(float(result["seconds"]))
                if on_trial is not None:
                    on_trial(result, stored, outcome.total)
    finally:
        if futures:
            client.cancel(list(futures))
        outcome.wall_s = time.perf_counter() - t0


LOCAL_WORKER_ENV = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
"""Dask starts workers with MALLOC_TRIM_THRESHOLD_=65536; setting it at all switches off glibc's
adaptive mmap threshold, so every torch buffer above 128 KiB is mmapped and unmapped again.
Measured on one trial: 2.2x the wall time of a plain process (sys time 45 % of it, 160x the page
faults); unset, a worker runs a trial as fast as a plain process. Workers of a --scheduler
cluster are started by whoever runs it: give them the same environment."""


def check_scheduler_address(address: str) -> str:
    """``address`` when Dask can read it as a scheduler's (``tcp://host:8786``, ``host:8786``,
    ``tls://...``); otherwise a RapiddsError naming what is wrong, before anything starts."""
    from distributed.comm.addressing import get_address_host_port

    try:
        _, port = get_address_host_port(address)
    except ValueError as exc:
        raise RapiddsError(f"--scheduler {address!r} is not a Dask scheduler address ({exc}); "
                           "expected e.g. tcp://host:8786") from None
    if not 0 < port < 65536:
        raise RapiddsError(f"--scheduler {address!r}: port {port} is not in 1-65535")
    return address


@contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None) -> Iterator[Client]:
    """A client of the Dask cluster at ``scheduler``, or of a local cluster of ``workers``
    single-threaded processes (default: one per CPU). Same work either way."""
    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(check_scheduler_address(scheduler), timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise RapiddsError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        with client:
            yield client
        return
    if workers is not None and workers < 1:
        raise RapiddsError(f"--workers must be >= 1, got {workers}")
    n = workers or os.cpu_count() or 1
    # ":0": the scheduler serves HTTP (health, metrics) even with no dashboard; a free port
    # keeps two studies (or a test beside a study) from fighting over 8787.
    with (
        dask.config.set(LOCAL_WORKER_ENV),
        LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                     dashboard_address=":0", silence_logs=logging.ERROR) as cluster,
        Client(cluster) as client,
    ):
        yield client
