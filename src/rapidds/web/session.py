"""One person's run of the browser game: the adaptive loop in a worker thread, with a
:class:`~rapidds.web.player.BrowserPlayer` as its teammate.

The worker thread owns the :class:`~rapidds.loop.run.AdaptiveRun` and its
:class:`~rapidds.store.RunStore` (an SQLite connection belongs to the thread that opened it) and
calls ``run.step()`` cycle after cycle: plan, show the plan, wait for the person, learn, record
(one store transaction, the same store ``rapidds run`` writes), and straight on to the next
plan, which is therefore computed while the robot finishes and the summary shows (unless the
player is asked the comfort question: then the learn step waits for the answer, see
:mod:`rapidds.web.player`). After each
cycle it publishes a summary for the page: the realised makespan and closest approach, the cost
curve so far, the observed and expected durations and the learned spatial cost of the person's
tasks on the spatial model's grid (the heat map).

The planner shares the process (and the GIL) with the server's 60 Hz tick: measured to hold
60 frames/s while planning on 2 cores (``benchmarks/bench_play.py``, docs/benchmarks.md
"Browser game"), so a thread is enough and the learned models never cross a process boundary.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rapidds.errors import RapiddsError
from rapidds.loop.config import RunConfig
from rapidds.record import CycleRecord
from rapidds.store import RunStore
from rapidds.web.player import BrowserPlayer, PlayerGone
from rapidds.worlds.capabilities import BrowserPlay

if TYPE_CHECKING:
    from rapidds.loop.run import AdaptiveRun, CycleResult
    from rapidds.motion.policy import DiffusionPolicy

__all__ = ["STORE_NAME", "PlaySession", "scene"]

log = logging.getLogger("rapidds.web")
STORE_NAME = "run.sqlite"


def _r(x: float) -> float:
    return round(float(x), 3)


def scene(world: BrowserPlay) -> dict[str, Any]:
    """The static scene the page draws: map size, walls, homes, objects, reach radius."""
    lo, hi = world.bounds
    return {
        "bounds": [lo.tolist(), hi.tolist()],
        "walls": [w.as_array().tolist() for w in world.obstacles()],
        "homes": {a: world.home(a).tolist() for a in ("human", "robot")},
        "objects": {t: world.object_position(t).tolist() for t in world.task_ids},
        "reach": world.reach_radius,
        "dt": world.dt,
    }


class PlaySession:
    """The run a browser plays: ``config`` (its ``human`` names the player) stored in
    ``out/run.sqlite``.

    resume: continue a stored run (refused when there is none to continue, and a stored run is
    not continued without it). on_cycle(run, result) and on_stop(run): called in the worker
    thread after each recorded cycle and when the worker ends (the CLI draws its pictures there).
    """

    def __init__(self, config: RunConfig, out: Path, *, world: BrowserPlay,
                 policy: DiffusionPolicy, player: BrowserPlayer, resume: bool = False,
                 on_cycle: Callable[[AdaptiveRun, CycleResult], None] | None = None,
                 on_stop: Callable[[AdaptiveRun], None] | None = None):
        self.config, self.out, self.world, self.policy = config, out, world, policy
        self.player, self.resume = player, resume
        self._on_cycle, self._on_stop = on_cycle, on_stop
        self._lock = threading.Lock()
        self._opened = threading.Event()
        self._open_error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self.run_id = config.resolved(world).run_id
        self.cycles = config.cycles
        self.summary: dict[str, Any] | None = None
        self.summary_version = 0
        self.stored = 0  # cycles in the store
        self.finished = False
        self.error: str | None = None

    # -- life cycle ---------------------------------------------------------------------------
    def open(self, timeout: float = 600.0) -> None:
        """Start the worker and wait until the run is attached to its store; a
        :class:`~rapidds.errors.RapiddsError` (a run to resume that is not there, other
        settings than the stored ones) is raised here, in the caller's thread."""
        self._thread = threading.Thread(target=self._work, name="rapidds-planner", daemon=True)
        self._thread.start()
        if not self._opened.wait(timeout):
            raise RapiddsError(f"the run did not open within {timeout:.0f} s")
        if self._open_error is not None:
            raise self._open_error

    def stop(self, timeout: float = 30.0) -> None:
        """Stop the worker: a cycle in progress is dropped (never half stored)."""
        self.player.close()
        if self._thread is not None:
            self._thread.join(timeout)

    @property
    def phase(self) -> str:
        """What the page shows: "error", "done", or the player's phase ("waiting" is the
        planner at work)."""
        with self._lock:
            if self.error is not None:
                return "error"
            if self.finished and self.player.phase in ("waiting", "over"):
                return "done"
        return self.player.phase

    def info(self) -> dict[str, Any]:
        return {"run_id": self.run_id, "cycles": self.cycles, "player": self.player.name,
                "adapt": self.config.adapt, "execution": self.config.execution.kind,
                "hz": self.player.hz, "speed": self.player.speed,
                "scene": scene(self.world)}

    # -- the worker ---------------------------------------------------------------------------
    def _work(self) -> None:
        run: AdaptiveRun | None = None
        store: RunStore | None = None
        try:
            from rapidds.loop.run import AdaptiveRun

            store = RunStore(self.out / STORE_NAME, lock_as="rapidds play")
            last = store.last_cycle(self.run_id)  # checked before the run is registered
            if last is not None and not self.resume:
                raise RapiddsError(
                    f"{self.out} already holds run '{self.run_id}' ({last + 1} cycles); "
                    "pass --resume to continue it or choose another --out")
            if self.resume and last is None:
                raise RapiddsError(f"{self.out} holds no cycle of run '{self.run_id}' to "
                                   "resume; start it without --resume")
            run = AdaptiveRun(self.config, self.policy, store, self.world, teammate=self.player)
            if run.finished:
                raise RapiddsError(f"run '{self.run_id}' in {self.out} is finished "
                                   f"({run.config.cycles} cycles)")
        except BaseException as exc:  # handed to open(), in the caller's thread
            self._open_error = exc
            if store is not None:
                store.close()
            self._opened.set()
            return
        self.stored = run.next_cycle
        if run.next_cycle:
            self._publish(self._summary(run, store.cycle_records(self.run_id)[-1]))
        self._opened.set()
        try:
            while not run.finished:
                result = run.step()
                self.stored = run.next_cycle
                self._publish(self._summary(run, result.record))
                if self._on_cycle is not None:
                    self._on_cycle(run, result)
            with self._lock:
                self.finished = True
            log.info("run %s finished: %d cycles", self.run_id, run.next_cycle)
        except PlayerGone:
            log.info("stopped; %d cycles of %s stored", run.next_cycle, self.run_id)
        except Exception as exc:  # the page says so; the CLI logs the traceback
            log.exception("the planner failed")
            with self._lock:
                self.error = f"{type(exc).__name__}: {exc}"
        finally:
            try:
                if self._on_stop is not None:
                    self._on_stop(run)
            finally:
                store.close()

    def _publish(self, summary: dict[str, Any]) -> None:
        with self._lock:
            self.summary = summary
            self.summary_version += 1

    def _summary(self, run: AdaptiveRun, record: CycleRecord) -> dict[str, Any]:
        """What the page shows after a cycle (see the module docstring)."""
        assert run.store is not None
        records = run.store.cycle_records(self.run_id)
        real, exp = record.realised, record.expected
        human = record.tasks("human")  # who did what: a reactive cycle may differ from the plan
        spatial = run.model.spatial
        n = spatial.config.shape
        heat = {t: [_r(v) for v in spatial[t].mean] for t in human if t in spatial}
        prior = {t: [_r(v) for v in spatial[t].prior_mean] for t in human if t in spatial}
        belief = record.belief["mean_durations"]
        return {
            "type": "summary",
            "cycle": record.cycle,
            "cycles": self.cycles,
            "makespan": _r(real.makespan),
            "expected_makespan": _r(exp.makespan),
            "closest": _r(real.min_separation),
            "spatial": _r(real.spatial),
            "cost": _r(real.cost),
            "human": human,
            "robot": record.tasks("robot"),
            "routes": record.plan.routes,
            "observed": {t: _r(d) for t, d in record.observed.items()},
            "timeline": {t: [_r(s), _r(f)] for t, (s, f) in real.timeline.items()},
            "belief": {t: _r(belief[t]) for t in human if t in belief},
            "curve": [{"cycle": r.cycle, "cost": _r(r.realised.cost),
                       "makespan": _r(r.realised.makespan),
                       "closest": _r(r.realised.min_separation)} for r in records],
            "heat": {"shape": list(n), "bounds": [list(b) for b in spatial.config.bounds],
                     "learned": heat, "prior": prior,
                     "max": _r(max((max(v) for v in heat.values()), default=1.0))},
            "finished": record.cycle + 1 >= self.cycles,
        }
