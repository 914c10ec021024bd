"""A typed cycle record for tests that need only a few of its parts: the parts a test names,
the rest neutral. Built from the record's own classes (not a dict), so a test's record is one
the readers accept from a store (store ``rec.to_json()`` to plant it)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from rapidds.record import CycleRecord, Execution, InCycle, PlanPart, Predicted, Realised
from rapidds.schedule import parse_item


def _overlaps(d: Mapping[str, Sequence[str]] | None) -> dict[str, tuple[str, ...]]:
    return {j: tuple(v) for j, v in (d or {}).items()}


def typed_record(*, cycle: int = 0, human: Sequence[str] = (), robot: Sequence[str] = (),
                 routes: Mapping[str, str] | None = None, lam: float = 0.0,
                 gamma: float = 12.0, expected_overlaps: Mapping[str, Sequence[str]] | None = None,
                 expected_spatial: float = 0.0, expected_makespan: float = 0.0,
                 timeline: Mapping[str, Sequence[float]] | None = None,
                 realised_overlaps: Mapping[str, Sequence[str]] | None = None,
                 spatial: float = 0.0, makespan: float = 0.0, cost: float = 0.0,
                 min_separation: float = 1.0, observed: Mapping[str, float] | None = None,
                 in_cycle: Mapping[str, Any] | None = None,
                 comfort: Mapping[str, Any] | None = None,
                 gamma_belief: Mapping[str, Any] | None = None,
                 run_id: str | None = None) -> CycleRecord:
    """A cycle record with the given parts. ``human``/``robot``: item texts as stored
    (``str(Wait(t))`` for a wait); ``in_cycle``: the stored in-cycle parts (executed, pauses,
    ...); ``comfort``: the evidence of a run that asks (None: it does not ask)."""
    plan = PlanPart(tuple(parse_item(x) for x in human), tuple(parse_item(x) for x in robot),
                    dict(routes or {}), gamma, lam,
                    Predicted(expected_makespan, 0.0, expected_spatial, 0.0, 0.0, True,
                              _overlaps(expected_overlaps)))
    real = Realised(makespan, spatial, cost, min_separation, _overlaps(realised_overlaps),
                    {t: (float(a), float(b)) for t, (a, b) in (timeline or {}).items()})
    return CycleRecord(
        cycle=cycle, plan=plan,
        execution=Execution(real, None if in_cycle is None else InCycle.from_json(in_cycle)),
        observed=dict(observed or {}), belief={"mean_durations": {}}, plan_cost=None,
        search={}, has_comfort=comfort is not None,
        comfort=None if comfort is None else dict(comfort),
        gamma_belief=None if gamma_belief is None else dict(gamma_belief), run_id=run_id)


def stored(rec: CycleRecord | Mapping[str, Any], *drop: str) -> dict[str, Any]:
    """A record as the store holds it (a run's typed record or a stored dict) without its
    wall-clock ``seconds`` and the keys ``drop``: what the same seed must give again."""
    d = rec.to_json() if isinstance(rec, CycleRecord) else rec
    return {k: v for k, v in d.items() if k not in ("seconds", *drop)}


def decided(rec: CycleRecord | Mapping[str, Any]) -> dict[str, Any]:
    """:func:`stored` without anything a clock measures in a reactive record either (each
    re-plan's latency and steering time): what the same seed must decide again."""
    out = stored(rec)
    out["replans"] = [{k: v for k, v in r.items() if k not in ("latency_s", "steer_s")}
                      for r in out.get("replans", [])]
    return out
