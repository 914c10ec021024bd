"""One cycle on its way through the loop, and the run's teammate as a source.

:meth:`~rapidds.loop.run.AdaptiveRun.plan` returns a :class:`Cycle`: the plan (the best
evaluated schedule with its robot motions), the gamma and lambda it was planned with, and the
cycle's own random stream; execute, learn and record then write what they found onto it (the
person's :class:`~rapidds.loop.observation.Observation`, the deviation the simulated person
had, the gamma evidence, the detected changes, the slowdowns, the step timings) instead of
into per-cycle tables of the run. A cycle that is dropped (never recorded) leaves nothing
behind.

:class:`TeammateSource` is the :class:`~rapidds.loop.observation.Source` a run uses when its
driver passes none: a simulated person draws what they do from the cycle's stream; a person at
a screen (:class:`LiveTeammate`) is shown the plan first, may take their own order
(:class:`FreeOrderTeammate`), plays the cycle live on the loop's executor under reactive
execution (:class:`ReactiveTeammate`) and is asked what they felt (:class:`Says`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from rapidds.execution import CycleExecutor, HumanSource
from rapidds.execution.deployment import Deployment
from rapidds.loop.carry import Stamped
from rapidds.loop.observation import Observation, Said
from rapidds.motion.interface import MotionKey
from rapidds.scheduler import Evaluation
from rapidds.worlds.base import Teammate

if TYPE_CHECKING:
    from rapidds.record import CycleRecord, SlowdownRecord
    from rapidds.worlds.reactions import Deviation

__all__ = ["Cycle", "CyclePlan", "CycleResult", "FreeOrderTeammate", "LiveTeammate",
           "ReactiveTeammate", "Says", "TeammateSource"]

ExecutorFactory = Callable[[HumanSource], CycleExecutor]


@dataclass
class Cycle:
    """One cycle: its plan, and what execute, learn and record found.

    ``best``: the evaluated schedule with its robot motions; ``lam``: the diversity weight and
    ``gamma`` the proximity weight it was planned with (gamma: the person's, as believed when
    planning; None only for a cycle built by hand, which takes the problem's). ``rng``: the
    cycle's random stream after planning; a simulated person continues from it, so a cycle draws
    the same numbers whether run in one call or step by step. ``motions``: the steered plans to
    carry into the next cycle once this one is recorded. ``live_executor``: builds the executor
    a live person plays this cycle on (set by the run that planned it).
    """

    cycle: int
    best: Evaluation
    lam: float
    search: dict[str, Any]
    rng: np.random.Generator = field(repr=False)
    seconds: float = 0.0
    motions: dict[MotionKey, Stamped] = field(default_factory=dict, repr=False)
    gamma: float | None = None
    live_executor: Callable[[], ExecutorFactory] | None = field(default=None, repr=False)
    # found on the way (execute, learn), recorded with the cycle
    observation: Observation | None = field(default=None, repr=False)
    deviation: Deviation | None = None
    evidence: dict[str, Any] | None = None
    changes: list[dict[str, Any]] = field(default_factory=list)
    slowed: SlowdownRecord | None = None
    timing: dict[str, float] = field(default_factory=dict)

    def as_executed(self, robot: dict[str, float]) -> None:
        """Each robot motion's duration becomes the one the robot took (a live cell's), so the
        realised timeline is the cycle that happened; the trajectories stay the planned ones."""
        motions = {t: replace(m, duration=robot.get(t, m.duration))
                   for t, m in self.best.motions.items()}
        self.best = replace(self.best, motions=motions)


CyclePlan = Cycle
"""The name a cycle had while it carried only its plan (kept for callers that build one)."""


@dataclass
class CycleResult:
    """A finished cycle: its record (typed; its ``to_json`` is what was stored), the cycle
    (``plan``, with what the person did) and the realised deployment."""

    record: CycleRecord
    plan: Cycle
    deployment: Deployment


@runtime_checkable
class LiveTeammate(Teammate, Protocol):
    """A teammate who has to see the plan before doing their part: a person at a screen (the
    browser game's player), a person told by an experimenter; :class:`TeammateSource` shows
    them the plan right before asking what they did."""

    def show(self, plan: Cycle) -> None:
        """Present ``plan`` (its schedule, the robot's motions); called once per cycle, in the
        thread that then calls :meth:`~rapidds.worlds.base.Teammate.execute`."""
        ...


@runtime_checkable
class FreeOrderTeammate(Teammate, Protocol):
    """A live teammate who may do their tasks in another order than the plan's (any that
    precedence allows: the browser game's player); the executor replays the order they took."""

    def played_order(self, cycle: int) -> list[str] | None:
        """The person's tasks of cycle ``cycle`` in the order they did them (None: unknown)."""
        ...


@runtime_checkable
class ReactiveTeammate(LiveTeammate, Protocol):
    """A live teammate the robot reacts to while the cycle runs (the browser game's player
    under reactive execution): the cycle runs live on the loop's executor, built around the
    person's own :class:`~rapidds.execution.HumanSource`."""

    def play(self, plan: Cycle, executor: ExecutorFactory) -> Deployment:
        """Show ``plan`` and run it live with the executor ``executor`` builds around the
        person; block until the cycle is over; what happened."""
        ...


@runtime_checkable
class Says(Protocol):
    """A live teammate who can be asked about a cycle once it is over (the browser player)."""

    def comfort_report(self, cycle: int) -> tuple[int | None, list[float]] | None:
        """(comfort answer 1-7, "too close" times) of cycle ``cycle``; None: not asked."""
        ...


@dataclass
class TeammateSource:
    """The run's own teammate as a :class:`~rapidds.loop.observation.Source`. ``executor``:
    under reactive execution, what builds a cycle's live executor (the run's
    :meth:`~rapidds.loop.run.AdaptiveRun.live_executor`), on which a :class:`ReactiveTeammate`
    plays the cycle; ``ask``: a teammate who :class:`Says` is asked about the cycle (off when
    the run simulates the person's comfort itself)."""

    teammate: Teammate
    executor: Callable[[Cycle], ExecutorFactory] | None = None
    ask: bool = True

    def observe(self, cycle: Cycle) -> Observation:
        mate = self.teammate
        if self.executor is not None and isinstance(mate, ReactiveTeammate):
            played = mate.play(cycle, self.executor(cycle))
            return Observation(played=played, said=self._said(cycle.cycle))
        if isinstance(mate, LiveTeammate):
            mate.show(cycle)
        human = mate.execute(cycle.cycle, cycle.best.schedule.tasks("human"), cycle.rng)
        order = mate.played_order(cycle.cycle) if isinstance(mate, FreeOrderTeammate) else None
        return Observation(human=human, order=order, said=self._said(cycle.cycle))

    def _said(self, cycle: int) -> Said | None:
        if not (self.ask and isinstance(self.teammate, Says)):
            return None
        said = self.teammate.comfort_report(cycle)
        return None if said is None else Said(said[0], tuple(said[1]))
