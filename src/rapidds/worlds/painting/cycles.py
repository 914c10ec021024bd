"""The paper's painting behaviours read off whole runs of the loop: each stored cycle record (as
:meth:`~rapidds.loop.run.AdaptiveRun.record` writes it) becomes a :class:`CycleSummary`, and a
run's records are tested against :func:`~rapidds.worlds.painting.calibration.behaviours` (the
same tests the plan-level calibration uses) plus Brush going to the faster agent.

The paper's first-cycle behaviours are tested on cycle 0 (the population prior); its "after
learning" ones on every cycle after exploration (lambda = 0), when the plan answers to the
learned model alone. While lambda is on, the diversity term makes the plan try the other brusher
and the other mix order on purpose (docs/design-notes.md, "lambda = 10"): those cycles test
nothing. Which mix "overlaps Secure Piece" is the planner's expected overlap set, the C_j the
robot's motion was steered for; the realised overlaps are kept for the table.

A wait is idle time on the realised timeline: the person starting Prep Vise late or pausing
between Prep Vise and Secure Piece, the robot starting its first mix late or pausing between its
mixes. A wait token that costs nothing (its task had already ended) is no wait.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from rapidds.record import CycleRecord
from rapidds.worlds.painting.calibration import BehaviourSpec, PlanSummary, behaviours

__all__ = [
    "CycleSummary",
    "LoopBehaviour",
    "faster_brusher",
    "loop_behaviours",
    "summarize_record",
]

_MIXES = ("mix_l", "mix_r")
_WAIT_TOL = 0.05  # s of idle time below which a pause is rounding, not a wait


@dataclass(frozen=True)
class CycleSummary:
    """What one cycle of the painting loop did, in the paper's terms.

    plan: the :class:`PlanSummary` the behaviour tests read (first mix, mode of each mix the
    planner expected during Secure Piece, idle). modes: mode of every robot motion.
    durations: realised duration of every robot motion (s). during_realised: the mixes that
    did overlap Secure Piece. brusher: "human" or "robot".
    """

    cycle: int
    lam: float
    plan: PlanSummary
    modes: dict[str, str]
    durations: dict[str, float]
    during_realised: tuple[str, ...]
    waits: tuple[str, ...]
    brusher: str
    expected_spatial: float
    realised_spatial: float
    min_separation: float
    makespan: float

    @property
    def explores(self) -> bool:
        return self.lam > 0.0


def summarize_record(record: CycleRecord) -> CycleSummary:
    """The :class:`CycleSummary` of one stored cycle record of the painting world."""
    robot = tuple(str(x) for x in record.plan.robot)
    human = tuple(str(x) for x in record.plan.human)
    real = record.realised
    times = {t: (float(a), float(b)) for t, (a, b) in real.timeline.items()}
    order = [x for x in robot if x in _MIXES]
    first, second = order[0], order[1]
    waits = []
    if times["prep_vise"][0] > _WAIT_TOL:
        waits.append(f"person {times['prep_vise'][0]:.1f} s before prep_vise")
    gap = times["secure_piece"][0] - times["prep_vise"][1]
    if gap > _WAIT_TOL:
        waits.append(f"person {gap:.1f} s before secure_piece")
    if times[first][0] > _WAIT_TOL:
        waits.append(f"robot {times[first][0]:.1f} s before {first}")
    gap = times[second][0] - times[first][1]
    if gap > _WAIT_TOL:
        waits.append(f"robot {gap:.1f} s before {second}")
    modes = {str(j): str(m) for j, m in record.plan.routes.items()}
    expected = record.expected.overlaps
    during = {j: modes[j] for j in order if "secure_piece" in expected.get(j, ())}
    plan = PlanSummary(robot, human, first, during, bool(waits))
    return CycleSummary(
        cycle=int(record.cycle), lam=float(record.plan.lam), plan=plan, modes=modes,
        durations={j: times[j][1] - times[j][0] for j in modes if j in times},
        during_realised=tuple(j for j in order if "secure_piece" in real.overlaps.get(j, ())),
        waits=tuple(waits), brusher="human" if "brush" in human else "robot",
        expected_spatial=float(record.expected.spatial),
        realised_spatial=float(real.spatial),
        min_separation=float(real.min_separation),
        makespan=float(real.makespan),
    )


def faster_brusher(person_brush_mean: float, robot_brush: float) -> str:
    """"human" when the person's true mean brushing time is below the robot's, else "robot"."""
    return "human" if person_brush_mean < robot_brush else "robot"


@dataclass(frozen=True)
class LoopBehaviour:
    """One behaviour tested on a run: the cycles it was tested on and those that showed it."""

    name: str
    belief: str
    cycles: tuple[int, ...]
    shown: tuple[int, ...]

    @property
    def holds(self) -> bool:
        """Shown in every cycle it was tested on (and tested on at least one)."""
        return bool(self.cycles) and self.shown == self.cycles


def loop_behaviours(records: Sequence[CycleRecord], variant: str, gamma: float,
                    near: str, brusher: str | None = None) -> list[LoopBehaviour]:
    """The paper's behaviours of the setting (``variant``, ``gamma``) tested on a run's records
    (cycle 0 for the prior's, every cycle after exploration for the learned ones), for a person
    whose hand works near ``near``'s tray. ``brusher``: the faster agent ("human"/"robot"), when
    Brush going to it should be tested too."""
    far = next(m for m in _MIXES if m != near)
    summaries = [summarize_record(r) for r in records]
    specs: list[BehaviourSpec] = [s for s in behaviours(near, far)
                                  if s.variant == variant and s.gamma == gamma]
    out = []
    for spec in specs:
        tested = [s for s in summaries if (s.cycle == 0 if spec.belief == "prior"
                                           else not s.explores)]
        out.append(LoopBehaviour(spec.name, spec.belief, tuple(s.cycle for s in tested),
                                 tuple(s.cycle for s in tested if spec.test(s.plan))))
    if brusher is not None:
        tested = [s for s in summaries if not s.explores]
        out.append(LoopBehaviour(f"Brush with the faster agent ({brusher})", "learned",
                                 tuple(s.cycle for s in tested),
                                 tuple(s.cycle for s in tested if s.brusher == brusher)))
    return out
