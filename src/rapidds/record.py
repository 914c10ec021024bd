"""The typed cycle record: what one cycle of a run planned, did, saw and learned.

The store keeps each cycle as JSON (the dict :meth:`CycleRecord.to_json` gives, written by
:meth:`rapidds.loop.run.AdaptiveRun.record`); :meth:`CycleRecord.from_json` reads it back, also
records stored before a part existed (the part is then ``None``). ``to_json`` gives back the
stored dict exactly, keys in the order the loop writes them, so typing the record changes no
stored byte. Values are kept as stored (an int stays an int): coercing would change the JSON.

Free-form parts whose keys vary by planner or executor (search statistics, pauses, re-plans,
a deviation, change reports, comfort evidence) stay mappings; every part a reader computes with
is a field. Keys this module does not know survive a round trip in ``extra``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from rapidds.errors import StateError
from rapidds.problem import Agent
from rapidds.schedule import Item, Schedule, parse_item

__all__ = ["CycleRecord", "Execution", "InCycle", "PlanCost", "PlanPart", "Predicted",
           "Realised", "Slowdowns", "Yield"]

Json = dict[str, Any]


def _items(seq: Any) -> tuple[Item, ...]:
    return tuple(parse_item(str(x)) for x in seq)


def _overlaps(d: Mapping[str, Any]) -> dict[str, tuple[str, ...]]:
    return {j: tuple(v) for j, v in d.items()}


def _overlaps_json(d: Mapping[str, tuple[str, ...]]) -> Json:
    return {j: list(v) for j, v in d.items()}


@dataclass(frozen=True)
class Predicted:
    """The plan's expected costs (``record["expected"]``)."""

    makespan: float
    makespan_std: float
    spatial: float
    diversity: float
    objective: float
    converged: bool
    overlaps: dict[str, tuple[str, ...]]

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Predicted:
        return cls(d["makespan"], d["makespan_std"], d["spatial"], d["diversity"],
                   d["objective"], d["converged"], _overlaps(d["overlaps"]))

    def to_json(self) -> Json:
        return {"makespan": self.makespan, "makespan_std": self.makespan_std,
                "spatial": self.spatial, "diversity": self.diversity,
                "objective": self.objective, "converged": self.converged,
                "overlaps": _overlaps_json(self.overlaps)}


@dataclass(frozen=True)
class PlanPart:
    """What was planned: each agent's sequence (tasks and :class:`~rapidds.schedule.Wait`
    items), the robot's route label per task, and the weights and costs it was planned with."""

    human: tuple[Item, ...]
    robot: tuple[Item, ...]
    routes: dict[str, str]
    gamma: float
    lam: float
    expected: Predicted

    def tasks(self, agent: str) -> list[str]:
        """The tasks of ``agent``'s planned sequence, its waits left out."""
        return [x for x in getattr(self, agent) if isinstance(x, str)]


@dataclass(frozen=True)
class Realised:
    """What the deployed cycle cost (``record["realised"]``); timeline: task -> (start,
    finish) in seconds from the cycle's start."""

    makespan: float
    spatial: float
    cost: float
    min_separation: float
    overlaps: dict[str, tuple[str, ...]]
    timeline: dict[str, tuple[float, float]]

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Realised:
        return cls(d["makespan"], d["spatial"], d["cost"], d["min_separation"],
                   _overlaps(d["overlaps"]), {t: (a, b) for t, (a, b) in d["timeline"].items()})

    def to_json(self) -> Json:
        return {"makespan": self.makespan, "spatial": self.spatial, "cost": self.cost,
                "min_separation": self.min_separation, "overlaps": _overlaps_json(self.overlaps),
                "timeline": {t: [a, b] for t, (a, b) in self.timeline.items()}}


@dataclass(frozen=True)
class Yield:
    """One time the robot gave way to a person who waited for it (a mutual hold,
    :mod:`rapidds.execution.yielding`): its task, the person's task then (None: they had
    none), when it yielded (s from the cycle's start), how long both had been held, how many
    seconds of its path it backed along, and when it went on (None: the cycle ended first)."""

    task: str
    person_task: str | None
    start: float
    held: float
    retreat: float
    end: float | None

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Yield:
        return cls(d["task"], d["person_task"], d["start"], d["held"], d["retreat"], d["end"])

    def to_json(self) -> Json:
        return {"task": self.task, "person_task": self.person_task, "start": self.start,
                "held": self.held, "retreat": self.retreat, "end": self.end}


@dataclass(frozen=True)
class InCycle:
    """Execution inside the cycle (only for runs whose execution is not the paper's): who did
    what, the person's deviation, the robot's pauses and re-plans, its protective stops, and
    its yields (None: stored before they were kept)."""

    executed: dict[str, tuple[Item, ...]]
    deviation: Json | None
    pauses: tuple[Json, ...]
    replans: tuple[Json, ...]
    protective: Any
    yields: tuple[Yield, ...] | None = None  # None: stored before, or not reactive

    KEYS = ("executed", "deviation", "pauses", "replans", "protective", "yields")

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> InCycle:
        ys = d.get("yields")
        return cls({a: _items(s) for a, s in d["executed"].items()}, d["deviation"],
                   tuple(d["pauses"]), tuple(d["replans"]), d["protective"],
                   None if ys is None else tuple(Yield.from_json(y) for y in ys))

    def to_json(self) -> Json:
        return {"executed": {a: [str(x) for x in s] for a, s in self.executed.items()},
                "deviation": self.deviation, "pauses": list(self.pauses),
                "replans": list(self.replans), "protective": self.protective,
                **({"yields": [y.to_json() for y in self.yields]}
                   if self.yields is not None else {})}

    @property
    def yielded(self) -> float:
        """Seconds the robot spent giving way this cycle (0 where none were kept)."""
        return sum((y.end if y.end is not None else y.start) - y.start
                   for y in self.yields or ())


@dataclass(frozen=True)
class Execution:
    """What happened: the realised costs and timeline, and in-cycle execution when it ran."""

    realised: Realised
    in_cycle: InCycle | None = None


@dataclass(frozen=True)
class PlanCost:
    """The paper's plan cost: the executed plan scored under the teammate's true model."""

    cost: float
    makespan: float
    spatial: float

    def to_json(self) -> Json:
        return {"cost": self.cost, "makespan": self.makespan, "spatial": self.spatial}


@dataclass(frozen=True)
class Slowdowns:
    """A reactive cycle's slowdowns (:mod:`rapidds.loop.slowdowns`). mode: ``learned``,
    ``predicted`` or ``off``; predicted: robot task -> the hold the plan expected (s); lost:
    robot task -> the time the monitor really cost it (s); pairs: ``ROBOT|PERSON`` -> (the
    uncorrected prediction, the lost time put to that pair); belief: the learned correction
    per pair after this cycle ({factor, sd, n}; None unless learned)."""

    mode: str
    predicted: dict[str, float]
    lost: dict[str, float]
    pairs: dict[str, tuple[float, float]]
    belief: Json | None = None

    @property
    def total_lost(self) -> float:
        return float(sum(self.lost.values()))

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Slowdowns:
        return cls(str(d["mode"]), dict(d["predicted"]), dict(d["lost"]),
                   {k: (float(v[0]), float(v[1])) for k, v in d["pairs"].items()},
                   d.get("belief"))

    def to_json(self) -> Json:
        return {"mode": self.mode, "predicted": dict(self.predicted), "lost": dict(self.lost),
                "pairs": {k: list(v) for k, v in self.pairs.items()}, "belief": self.belief}


# the top-level keys in the order the loop writes them; optional parts marked by their field
_KNOWN = ("cycle", "human", "robot", "routes", "gamma", "lambda", "expected", "realised",
          "observed", "belief", "plan_cost", "search", "changes", "comfort", "gamma_belief",
          *InCycle.KEYS, "slowdowns", "live", "seconds", "run_id")


@dataclass(frozen=True)
class CycleRecord:
    """One stored cycle. plan/execution: see their classes; observed: the person's duration
    per task they did; belief: the model snapshot after learning (``mean_durations``);
    plan_cost: None for a live person (``has_plan_cost`` False: stored before it was kept);
    search: the planner's statistics; changes: the change detector's reports
    (None: the run does not detect); comfort: the cycle's comfort evidence
    (``has_comfort`` False: the run does not ask; the evidence may be None when it asked and
    learned nothing); gamma_belief: the gamma posterior's summary when the run learns gamma;
    live: what a live cell saw beyond the deployment (only in a live cell's records);
    slowdowns: what the plan expected of the safety monitor and what it cost (reactive runs
    only, :class:`Slowdowns`; None in every other record and in those stored before it);
    seconds: time per step (None in records stored before it was kept)."""

    cycle: int
    plan: PlanPart
    execution: Execution
    observed: dict[str, float]
    belief: Json
    plan_cost: PlanCost | None
    search: Json
    has_plan_cost: bool = True
    changes: list[Any] | None = None
    has_comfort: bool = False
    comfort: Json | None = None
    gamma_belief: Json | None = None
    slowdowns: Slowdowns | None = None
    live: Json | None = None
    seconds: dict[str, float] | None = None
    run_id: str | None = None
    extra: Json = field(default_factory=dict)

    @property
    def realised(self) -> Realised:
        return self.execution.realised

    @property
    def expected(self) -> Predicted:
        return self.plan.expected

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> CycleRecord:
        """A stored record (any version); StateError naming the missing key if it is not one."""
        try:
            pc = d.get("plan_cost")
            return cls(
                cycle=d["cycle"],
                plan=PlanPart(_items(d["human"]), _items(d["robot"]), dict(d["routes"]),
                              d["gamma"], d["lambda"], Predicted.from_json(d["expected"])),
                execution=Execution(Realised.from_json(d["realised"]),
                                    InCycle.from_json(d) if "executed" in d else None),
                observed=dict(d["observed"]), belief=dict(d["belief"]),
                plan_cost=None if pc is None else PlanCost(pc["cost"], pc["makespan"],
                                                           pc["spatial"]),
                search=dict(d["search"]), has_plan_cost="plan_cost" in d,
                changes=d.get("changes"),
                has_comfort="comfort" in d, comfort=d.get("comfort"),
                gamma_belief=d.get("gamma_belief"), live=d.get("live"),
                slowdowns=Slowdowns.from_json(d["slowdowns"]) if "slowdowns" in d else None,
                seconds=d.get("seconds"),
                run_id=d.get("run_id"),
                extra={k: v for k, v in d.items() if k not in _KNOWN})
        except (KeyError, TypeError, ValueError) as exc:
            raise StateError(f"not a cycle record ({type(exc).__name__}: {exc})") from None

    def to_json(self) -> Json:
        """The stored dict, exactly as the loop writes it (``run_id`` last, as the store adds
        it on reading)."""
        p, ex = self.plan, self.execution
        return {
            "cycle": self.cycle,
            "human": [str(x) for x in p.human], "robot": [str(x) for x in p.robot],
            "routes": dict(p.routes), "gamma": p.gamma, "lambda": p.lam,
            "expected": p.expected.to_json(), "realised": ex.realised.to_json(),
            "observed": dict(self.observed), "belief": self.belief,
            **({"plan_cost": None if self.plan_cost is None else self.plan_cost.to_json()}
               if self.has_plan_cost else {}),
            "search": self.search,
            **({"changes": self.changes} if self.changes is not None else {}),
            **({"comfort": self.comfort} if self.has_comfort else {}),
            **({"gamma_belief": self.gamma_belief} if self.gamma_belief is not None else {}),
            **(ex.in_cycle.to_json() if ex.in_cycle is not None else {}),
            **({"slowdowns": self.slowdowns.to_json()} if self.slowdowns is not None else {}),
            **({"live": self.live} if self.live is not None else {}),
            **({"seconds": self.seconds} if self.seconds is not None else {}),
            **self.extra,
            **({"run_id": self.run_id} if self.run_id is not None else {}),
        }

    @property
    def done(self) -> Schedule:
        """Who did what, in order: as executed where the cycle ran in-cycle execution (the
        person may have deviated, the robot re-planned), else as planned."""
        ex = self.execution.in_cycle
        if ex is not None:
            return Schedule(ex.executed.get("human", ()), ex.executed.get("robot", ()))
        return Schedule(self.plan.human, self.plan.robot)

    def tasks(self, agent: Agent) -> list[str]:
        """The tasks ``agent`` did this cycle."""
        return list(self.done.tasks(agent))
