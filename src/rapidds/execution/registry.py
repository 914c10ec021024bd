"""Execution as a registered, typed setting: how the robot carries out a plan inside a cycle.

Each way is one :class:`ExecutionSetting` subclass, registered under its ``kind`` with
:func:`register_execution` (as LeRobot registers its configs), so that a lab adds one from its
own package and names it in a run's settings (``--execution NAME``) without touching rapidds.
The registered entries form a pydantic discriminated union on ``kind``
(:func:`execution_setting` parses a name or a mapping into the entry). An entry is the one
place that decides what a mode does: it builds the robot's policy (:meth:`~ExecutionSetting.
policy`, None: open loop) and its re-planner (:meth:`~ExecutionSetting.replanner`), for the
simulated executor, the browser game and the live cell's monitor alike; everyone else asks the
entry (``config.execution.monitor``), never its name.

Monitoring and re-planning are separate switches: ``planned`` (neither: the paper),
``monitored`` (speed and separation monitoring), ``replanning`` (re-plans the rest of the cycle
when the person deviates, the robot at full speed), ``reactive`` (both). A run stores its entry
as its name, the form every earlier store holds (a mapping only where a parameter is not the
entry's default).

Light on purpose: ``rapidds --help`` reads the names through :class:`~rapidds.loop.config.
RunConfig`, so the policies and numpy are imported when a policy is built, not here.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal, Union

from pydantic import Field, TypeAdapter, ValidationError

from rapidds.errors import ConfigError
from rapidds.settings import Place, Settings, error_line

if TYPE_CHECKING:
    from rapidds.execution.executor import Replanning
    from rapidds.execution.policies import RobotPolicy
    from rapidds.worlds.reactions import SafetyLimits

__all__ = ["ExecutionSetting", "Monitored", "Planned", "Reactive", "Replanned",
           "execution_names", "execution_setting", "parse_execution", "register_execution",
           "stored_execution"]

_REGISTRY: dict[str, type[ExecutionSetting]] = {}


class ExecutionSetting(Settings):
    """One way of carrying out a plan. ``kind``: its registered name (a ``Literal`` with that
    name as its default in each entry). ``monitor``: whether :meth:`policy` gives the robot a
    policy that may slow or hold it (so the plan may expect the monitor's holds, and a held
    robot may yield); ``replan``: whether the rest of the cycle is re-planned when the person
    deviates."""

    label: ClassVar[str | None] = "execution"
    monitor: ClassVar[bool] = False
    replan: ClassVar[bool] = False
    kind: str

    def policy(self, limits: SafetyLimits) -> RobotPolicy | None:
        """The robot's policy under the safety numbers ``limits`` (the live monitor passes its
        longer reaction time); None: the robot follows its plan open loop. The default: speed
        and separation monitoring (ISO/TS 15066) where the entry monitors."""
        if not self.monitor:
            return None
        from rapidds.execution.policies import SpeedSeparation  # numpy: not at `--help`

        return SpeedSeparation(limits)

    def replanner(self, build: Callable[[], Replanning]) -> Replanning | None:
        """What the cycle's re-plans use, from what ``build`` makes of the learned models as
        they stand (the caller's: the loop, the browser game, the live cell); None: the plan's
        order is kept whatever the person does."""
        return build() if self.replan else None

    def __str__(self) -> str:
        """Its name: what a command line or a message says (``--execution reactive``)."""
        return self.kind

    @property
    def in_cycle(self) -> bool:
        """Whether the robot acts on what it sees while the cycle runs (a live person then
        plays the cycle on the executor, and records say what happened inside it)."""
        return self.monitor or self.replan

    @property
    def replays(self) -> bool:
        """Whether a cycle whose person neither reacts nor deviates is the schedule replayed on
        the durations taken (the paper's closed form, :func:`rapidds.loop.deploy.deploy`)
        rather than run on the executor's clock: so where the robot neither watches nor
        re-plans (the executor gives the same times and costs to the last bit)."""
        return not self.in_cycle

    @property
    def run_suffix(self) -> str:
        """What a run id says of the entry: nothing for the paper's open loop."""
        return f"-{self.kind}" if self.in_cycle else ""


def register_execution(cls: type[ExecutionSetting]) -> type[ExecutionSetting]:
    """Register ``cls`` under its ``kind``'s default (a class decorator); a second class under
    a registered name is refused (registering the same class again is a no-op)."""
    kind = cls.model_fields["kind"].default
    if not isinstance(kind, str) or not kind:
        raise TypeError(f"{cls.__name__}.kind needs its name as default, e.g. "
                        f"kind: Literal['mine'] = 'mine'")
    if _REGISTRY.get(kind, cls) is not cls:
        raise ValueError(f"execution '{kind}' is registered already "
                         f"({_REGISTRY[kind].__qualname__})")
    _REGISTRY[kind] = cls
    _adapter.cache_clear()
    return cls


def execution_names() -> tuple[str, ...]:
    """The registered entries' names, in the order they were registered."""
    return tuple(_REGISTRY)


@functools.cache
def _adapter() -> TypeAdapter[Any]:
    """The discriminated union of the entries registered so far (rebuilt on registration)."""
    union = Union[tuple(_REGISTRY.values())]  # type: ignore[valid-type]  # noqa: UP007
    return TypeAdapter(Annotated[union, Field(discriminator="kind")])


def parse_execution(value: str | Mapping[str, Any] | ExecutionSetting) -> ExecutionSetting:
    """The entry ``value`` names (``"reactive"``) or describes (``{"kind": "reactive", ...}``);
    ValueError (a bare reason, for a settings model's own error line) if there is none."""
    if isinstance(value, ExecutionSetting):
        return value
    data = {"kind": value} if isinstance(value, str) else dict(value)
    if data.get("kind") not in _REGISTRY:
        raise ValueError(f"must be one of {', '.join(_REGISTRY)}")
    try:
        return _adapter().validate_python(data)  # type: ignore[no-any-return]
    except ValidationError as exc:  # the entry's own line (Settings), else pydantic's
        inner = exc.errors()[0].get("ctx", {}).get("error")
        if isinstance(inner, ConfigError):
            raise inner from None
        raise ConfigError(error_line(exc, prefix="execution.", with_input=True,
                                     unknown="unknown field", place=Place(skip=1))) from None


def execution_setting(value: str | Mapping[str, Any] | ExecutionSetting) -> ExecutionSetting:
    """:func:`parse_execution`, with :class:`~rapidds.errors.ConfigError` (one line) for an
    unknown name or a bad parameter."""
    try:
        return parse_execution(value)
    except ConfigError:
        raise
    except ValueError as exc:
        raise ConfigError(f"execution: {exc} (got {value!r})") from None


def stored_execution(setting: ExecutionSetting) -> str | dict[str, Any]:
    """How a run stores ``setting``: its name, unless a parameter differs from the entry's
    default (then every field, ``kind`` included)."""
    if setting == type(setting)():
        return setting.kind
    return setting.model_dump()


@register_execution
class Planned(ExecutionSetting):
    """The paper's execution: the robot follows its plan whatever happens."""

    kind: Literal["planned"] = "planned"


class _Replans(ExecutionSetting):
    """The re-planner's parameters. overrun_z: a running task of the person's overruns (and
    the rest is re-planned) past mean + z std of its belief (1.2816: the 90 % quantile of a
    normal). steer_max: (task, concurrent set) pairs one re-plan may steer anew, which bounds
    its latency."""

    replan: ClassVar[bool] = True
    overrun_z: Annotated[float, Field(gt=0, le=10)] = 1.2816
    steer_max: Annotated[int, Field(ge=0, le=64)] = 1

    def replanner(self, build: Callable[[], Replanning]) -> Replanning | None:
        return dataclasses.replace(build(), z=self.overrun_z, steer_max=self.steer_max)


@register_execution
class Reactive(_Replans):
    """Speed and separation monitoring, and re-planning the rest of the cycle when the person
    deviates (docs/design-notes.md "Reacting inside the cycle")."""

    monitor: ClassVar[bool] = True
    kind: Literal["reactive"] = "reactive"


@register_execution
class Monitored(ExecutionSetting):
    """Speed and separation monitoring alone: the robot slows and holds beside the person but
    keeps the plan's order."""

    monitor: ClassVar[bool] = True
    kind: Literal["monitored"] = "monitored"


@register_execution
class Replanned(_Replans):
    """Re-planning alone: the rest of the cycle is re-planned when the person deviates; the
    robot moves at its planned speed."""

    kind: Literal["replanning"] = "replanning"
