"""The collaborative job: tasks, who may do them, their durations, and precedence.

A problem file is YAML validated by pydantic; :func:`load_problem` turns it into an immutable
:class:`Problem` or raises :class:`~rapidds.errors.ProblemError` with one line that names what is
wrong and where.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from rapidds.errors import ProblemError
from rapidds.settings import Place, error_line, read_yaml

Agent = Literal["human", "robot"]
AGENTS: tuple[Agent, Agent] = ("human", "robot")

MAX_DURATION = 1e7
"""Longest duration a problem may state, seconds (115 days): sums, squares and Monte-Carlo
samples of durations stay far from overflow, and no real task cycle comes near it."""


def _finite(value: float, what: str) -> float:
    if not math.isfinite(value):
        raise ValueError(f"{what} must be a finite number, got {value}")
    if abs(value) > MAX_DURATION:
        raise ValueError(f"{what} must be at most {MAX_DURATION:g} s, got {value:g}")
    return value


class _HumanPriorSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    mean: float = Field(strict=True, description="prior mean of the human's duration, seconds")
    std: float = Field(
        0.0, strict=True, description="prior standard deviation, seconds; 0 = deterministic"
    )

    @field_validator("mean")
    @classmethod
    def _mean_positive(cls, v: float) -> float:
        if _finite(v, "mean") <= 0:
            raise ValueError(f"mean must be > 0, got {v}")
        return v

    @field_validator("std")
    @classmethod
    def _std_nonnegative(cls, v: float) -> float:
        if _finite(v, "std") < 0:
            raise ValueError(f"std must be >= 0, got {v}")
        return v


class _RobotSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    duration: float = Field(strict=True, description="nominal robot duration, seconds")

    @field_validator("duration")
    @classmethod
    def _duration_positive(cls, v: float) -> float:
        if _finite(v, "duration") <= 0:
            raise ValueError(f"duration must be > 0, got {v}")
        return v


class _TaskSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    id: str = Field(min_length=1)
    allowed: list[Agent] = Field(default_factory=lambda: ["human", "robot"], min_length=1)
    human: _HumanPriorSpec | None = None
    robot: _RobotSpec | None = None
    description: str = ""


class _ObjectiveSpec(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)
    gamma: float = Field(1.75, ge=0, strict=True, description="weight of expected proximity")
    lam: float = Field(
        0.0, ge=0, strict=True, alias="lambda", description="weight of allocation diversity"
    )

    @field_validator("gamma", "lam")
    @classmethod
    def _weights_finite(cls, v: float) -> float:
        return _finite(v, "objective weight")


class _ProblemSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = "problem"
    tasks: list[_TaskSpec] = Field(min_length=1)
    precedence: list[tuple[str, str]] = Field(default_factory=list)
    objective: _ObjectiveSpec = Field(default_factory=_ObjectiveSpec)


@dataclass(frozen=True)
class Task:
    """One task of the job. ``human_mean``/``human_std`` is the prior on the human's duration."""

    id: str
    allowed: frozenset[Agent]
    human_mean: float | None = None
    human_std: float | None = None
    robot_duration: float | None = None
    description: str = ""

    def can(self, agent: Agent) -> bool:
        return agent in self.allowed


@dataclass(frozen=True)
class Objective:
    """Weights of z_t + gamma * z_s + lam * z_d (paper eq. 2)."""

    gamma: float = 1.75
    lam: float = 0.0


@dataclass(frozen=True)
class Problem:
    """An immutable, validated job. Tasks keep file order; ``index`` maps id -> column."""

    name: str
    tasks: tuple[Task, ...]
    precedence: tuple[tuple[str, str], ...] = ()
    objective: Objective = field(default_factory=Objective)

    def __post_init__(self) -> None:
        _check_consistent(self)

    # Cached: the scheduler asks for these for every candidate it evaluates. Do not mutate.
    @cached_property
    def ids(self) -> tuple[str, ...]:
        return tuple(t.id for t in self.tasks)

    @cached_property
    def index(self) -> dict[str, int]:
        return {t.id: i for i, t in enumerate(self.tasks)}

    @cached_property
    def preceding(self) -> dict[str, tuple[str, ...]]:
        """Direct precedence predecessors of every task."""
        return {t: tuple(a for a, b in self.precedence if b == t) for t in self.ids}

    @cached_property
    def following(self) -> dict[str, tuple[str, ...]]:
        """Direct precedence successors of every task."""
        return {t: tuple(b for a, b in self.precedence if a == t) for t in self.ids}

    def task(self, task_id: str) -> Task:
        return self.tasks[self.index[task_id]]

    def predecessors(self, task_id: str) -> tuple[str, ...]:
        return self.preceding[task_id]

    @property
    def shared_tasks(self) -> tuple[str, ...]:
        """Tasks both agents may do: the only ones the diversity term counts."""
        return tuple(t.id for t in self.tasks if len(t.allowed) == 2)

    def with_objective(self, gamma: float | None = None, lam: float | None = None) -> Problem:
        o = self.objective
        return Problem(
            self.name,
            self.tasks,
            self.precedence,
            Objective(o.gamma if gamma is None else gamma, o.lam if lam is None else lam),
        )

    def to_dict(self) -> dict[str, Any]:
        tasks = []
        for t in self.tasks:
            d: dict[str, Any] = {"id": t.id, "allowed": sorted(t.allowed)}
            if t.human_mean is not None:
                d["human"] = {"mean": t.human_mean, "std": t.human_std}
            if t.robot_duration is not None:
                d["robot"] = {"duration": t.robot_duration}
            if t.description:
                d["description"] = t.description
            tasks.append(d)
        return {
            "name": self.name,
            "tasks": tasks,
            "precedence": [list(p) for p in self.precedence],
            "objective": {"gamma": self.objective.gamma, "lambda": self.objective.lam},
        }


def _find_cycle(ids: tuple[str, ...], edges: tuple[tuple[str, str], ...]) -> list[str] | None:
    succ: dict[str, list[str]] = {i: [] for i in ids}
    for a, b in edges:
        succ[a].append(b)
    color = dict.fromkeys(ids, 0)  # 0 new, 1 on stack, 2 done
    stack: list[str] = []

    def visit(u: str) -> list[str] | None:
        color[u] = 1
        stack.append(u)
        for v in succ[u]:
            if color[v] == 1:
                return [*stack[stack.index(v) :], v]
            if color[v] == 0 and (cyc := visit(v)):
                return cyc
        stack.pop()
        color[u] = 2
        return None

    for i in ids:
        if color[i] == 0 and (cyc := visit(i)):
            return cyc
    return None


def _check_consistent(p: Problem) -> None:
    if not p.tasks:
        raise ProblemError("the problem has no tasks")
    seen: set[str] = set()
    for t in p.tasks:
        if t.id in seen:
            raise ProblemError(f"duplicate task id '{t.id}'")
        seen.add(t.id)
        if not t.allowed:
            raise ProblemError(f"task '{t.id}': no agent may do it")
        if "human" in t.allowed and t.human_mean is None:
            raise ProblemError(f"task '{t.id}': allowed to the human but has no 'human' prior")
        if "robot" in t.allowed and t.robot_duration is None:
            raise ProblemError(f"task '{t.id}': allowed to the robot but has no 'robot' duration")
    for k, (a, b) in enumerate(p.precedence):
        for x in (a, b):
            if x not in seen:
                raise ProblemError(f"precedence[{k}] names unknown task '{x}'")
        if a == b:
            raise ProblemError(f"precedence[{k}]: task '{a}' cannot precede itself")
    cycle = _find_cycle(p.ids, p.precedence)
    if cycle:
        raise ProblemError("precedence cycle: " + " -> ".join(cycle))


def _location(loc: tuple[Any, ...], raw: Any) -> str:
    """Render a pydantic error location, naming tasks by id where possible."""
    parts: list[str] = []
    node = raw
    for step in loc:
        if isinstance(step, int) and isinstance(node, list) and step < len(node):
            item = node[step]
            tid = item.get("id") if isinstance(item, dict) else None
            parts.append(f"[{step}]" + (f" (id '{tid}')" if tid else ""))
            node = item
        else:
            parts.append(f".{step}" if parts else str(step))
            node = node.get(step) if isinstance(node, dict) else None
    return "".join(parts)


def problem_from_dict(raw: Any, source: str = "problem") -> Problem:
    """Validate a parsed YAML/JSON document. Raises ProblemError with one readable line."""
    if not isinstance(raw, dict):
        raise ProblemError(f"{source}: expected a mapping with 'tasks', got {type(raw).__name__}")
    try:
        spec = _ProblemSpec.model_validate(raw)
    except ValidationError as exc:
        line = error_line(exc, place=Place(locate=lambda loc: _location(loc, raw)))
        raise ProblemError(f"{source}: {line}") from None
    tasks = tuple(
        Task(
            id=t.id,
            allowed=frozenset(t.allowed),
            human_mean=t.human.mean if t.human else None,
            human_std=t.human.std if t.human else None,
            robot_duration=t.robot.duration if t.robot else None,
            description=t.description,
        )
        for t in spec.tasks
    )
    try:
        return Problem(
            name=spec.name,
            tasks=tasks,
            precedence=tuple((a, b) for a, b in spec.precedence),
            objective=Objective(spec.objective.gamma, spec.objective.lam),
        )
    except ProblemError as exc:
        raise ProblemError(f"{source}: {exc}") from None


def load_problem(path: str | Path) -> Problem:
    """Read and validate a YAML problem file."""
    return problem_from_dict(read_yaml(path, error=ProblemError, mapping=False), str(path))
