"""Task boundaries from signals a cell already emits, by rules declared in the tracker mapping,
so a lab needs no rapidds JSON on ``/rapidds/events``.

A rule says which topic marks which agent's task starting or ending, optionally only when
fields of the message hold given values::

    boundaries:
      order:                     # the tasks each agent did, in order: the k-th start of an
        robot: [t1, t3]          # agent begins the k-th task of its list
        human: [prep_vise]
      rules:
        - {topic: /fr3_arm_controller/joint_trajectory, agent: robot, event: start}
        - {topic: /traj_complete, agent: robot, event: end, when: {data: true}}
        - {topic: /pedal, agent: human, event: toggle}      # start, then end, then start ...

An ``end`` closes the agent's open task; a ``toggle`` starts the agent's next task when none is
open and ends it otherwise. Signals carry no task id, so the order names them; an agent with
no order takes the cycle's plan's (``observe`` plans the cycle, then binds the signals to its
order; ``train-policy``, with no plan, needs ``order.robot``). A signal that
does not fit (an end with no task open, a start while one is open, a start past the order's
end) is dropped in one line, as a malformed rapidds event is. A message's time is its receive
time (the recorder's clock, the one tracking is timed by).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from rapidds.settings import Settings

__all__ = ["BoundaryRule", "BoundaryRules", "SignalReader"]

Agent = Literal["human", "robot"]
Scalar = bool | int | float | str


class BoundaryRule(Settings):
    """One signal: a message on ``topic`` (where every ``when`` field, dotted into the message,
    equals its value) starts, ends or toggles ``agent``'s task."""

    label = "boundaries.rules[]"
    topic: Annotated[str, Field(pattern=r"^/?[A-Za-z0-9_~/]+$")]
    agent: Agent
    event: Literal["start", "end", "toggle"]
    when: dict[str, Scalar] = Field(default_factory=dict)

    def matches(self, msg: Any) -> bool | None:
        """Whether ``msg`` fires this rule; None when it lacks a ``when`` field."""
        for path, want in self.when.items():
            value = msg
            for part in path.split("."):
                if not hasattr(value, part):
                    return None
                value = getattr(value, part)
            if isinstance(want, bool) != isinstance(value, bool) or value != want:
                return False
        return True


class BoundaryRules(Settings):
    """The rules of a mapping's ``boundaries`` and the order of each agent's tasks."""

    label = "boundaries"
    rules: Annotated[list[BoundaryRule], Field(min_length=1)]
    order: dict[Agent, list[str]] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _ends_need_starts(self) -> BoundaryRules:
        for agent in ("human", "robot"):
            kinds = {r.event for r in self.rules if r.agent == agent}
            if kinds and not kinds - {"end"}:
                raise ValueError(f"the {agent}'s tasks end by a rule but none starts them (a "
                                 "start or toggle rule)")
            if kinds and not kinds & {"end", "toggle"}:
                raise ValueError(f"the {agent}'s tasks start by a rule but none ends them (an "
                                 "end or toggle rule)")
        return self

    def unordered(self) -> set[str]:
        """The agents whose rules wait for an order (the plan's)."""
        return {r.agent for r in self.rules} - set(self.order)

    def ordered(self, order: Mapping[str, tuple[str, ...] | list[str]]) -> BoundaryRules:
        """These rules with ``order`` for the agents that have none."""
        full = {**{a: list(ts) for a, ts in order.items() if a in self.unordered()},
                **self.order}
        return BoundaryRules(rules=[r.model_dump() for r in self.rules], order=full)

    def topics(self) -> set[str]:
        return {"/" + r.topic.lstrip("/") for r in self.rules}

    def check(self, tasks: tuple[str, ...]) -> str | None:
        """The first task of the order that is not one of ``tasks``, or None."""
        return next((t for ts in self.order.values() for t in ts if t not in tasks), None)


class SignalReader:
    """Turns a bag's messages into task events by :class:`BoundaryRules` (module docstring)."""

    def __init__(self, rules: BoundaryRules, agents: set[str] | None = None):
        """Reads the rules of ``agents`` (None: of the agents that have an order)."""
        self.rules = rules
        self.agents = set(rules.order) if agents is None else agents
        self.next: dict[str, int] = {"human": 0, "robot": 0}
        self.open: dict[str, str | None] = {"human": None, "robot": None}
        self.lacking: set[int] = set()

    def feed(self, topic: str, msg: Any, time_ns: int) -> list[tuple[str, str, str] | str]:
        """The events the message fires (task, agent, start|end), or a line saying why a
        signal was dropped."""
        out: list[tuple[str, str, str] | str] = []
        topic = "/" + topic.lstrip("/")
        for k, rule in enumerate(self.rules.rules):
            if "/" + rule.topic.lstrip("/") != topic or rule.agent not in self.agents:
                continue
            fired = rule.matches(msg)
            if fired is None:
                if k not in self.lacking:  # one line per rule, not per message
                    self.lacking.add(k)
                    out.append(f"{topic}: the message lacks a field of the rule's 'when' "
                               f"{dict(rule.when)}")
                continue
            if fired:
                out.append(self._fire(rule, time_ns))
        return out

    def _fire(self, rule: BoundaryRule, time_ns: int) -> tuple[str, str, str] | str:
        agent, is_open = rule.agent, self.open[rule.agent]
        kind = rule.event if rule.event != "toggle" else ("end" if is_open else "start")
        if kind == "end":
            if is_open is None:
                return f"{rule.topic} at {time_ns} ns ends no open {agent} task"
            self.open[agent] = None
            return (is_open, agent, "end")
        if is_open is not None:
            return f"{rule.topic} at {time_ns} ns starts a {agent} task while {is_open!r} runs"
        order: Mapping[str, list[str]] = self.rules.order
        k = self.next[agent]
        if k >= len(order[agent]):
            return (f"{rule.topic} at {time_ns} ns starts {agent} task {k + 1}, past the "
                    f"{len(order[agent])} of boundaries.order.{agent}")
        self.next[agent] = k + 1
        self.open[agent] = order[agent][k]
        return (order[agent][k], agent, "start")
