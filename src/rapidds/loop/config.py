"""What determines a run: world, teammate, adaptation level, cycles, objective and search.

The settings are grouped (:class:`SearchSettings`, :class:`SpatialSettings`,
:class:`TeammateSettings`, :class:`ChangeSettings`, :class:`GammaLearning`, the objective's
weights in :class:`ObjectiveSettings`); each field's ``description`` is its one description, the
one ``rapidds --help`` shows (:mod:`rapidds.cli._options` writes the options from them). A run's
stored settings stay one flat mapping, as every run was stored before the groups: ``model_dump``
writes the groups' fields flat, ``RunConfig(**flat)`` puts them back, and ``cfg.population``
reads a grouped field by its flat name.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BeforeValidator,
    Field,
    PlainSerializer,
    SerializationInfo,
    SerializerFunctionWrapHandler,
    ValidationInfo,
    field_validator,
    model_serializer,
    model_validator,
)
from pydantic.fields import FieldInfo

from rapidds.execution.registry import (
    ExecutionSetting,
    Planned,
    execution_names,
    parse_execution,
    stored_execution,
)
from rapidds.settings import Settings, SettingsGroup, cli_field, option_name

if TYPE_CHECKING:  # a type only: `rapidds --help` must not pay for numpy
    from rapidds.worlds.base import World

__all__ = ["ADAPT_LEVELS", "DEVICE_HELP", "Adapt", "ChangeSettings", "Device", "Execution",
           "ExecutionField", "GammaLearning", "ObjectiveSettings", "RunConfig", "Sampler",
           "SearchSettings", "Slowdowns", "SpatialSettings", "TeammateSettings"]

Adapt = Literal["full", "spatial", "temporal", "none", "oracle", "exact"]
Slowdowns = Literal["learned", "predicted", "off"]
Sampler = Literal["ddim", "ddpm", "dpm"]
ADAPT_LEVELS: tuple[str, ...] = ("full", "spatial", "temporal", "none", "oracle", "exact")

_Weight = Annotated[float, Field(ge=0)]


def _registered(name: str) -> str:
    if name not in execution_names():
        raise ValueError(f"must be one of {', '.join(execution_names())}")
    return name


Execution = Annotated[str, AfterValidator(_registered)]
"""A registered execution's name (:mod:`rapidds.execution.registry`), for settings that keep the
name (the ablation's)."""
ExecutionField = Annotated[ExecutionSetting, BeforeValidator(parse_execution),
                           PlainSerializer(stored_execution)]
"""A run's execution: a registered entry, given and stored by its name (or a mapping with its
parameters, where they are not the entry's defaults)."""

Device = Literal["auto", "cpu", "cuda"]
Sampler = Literal["ddim", "ddpm", "dpm"]
DEVICE_HELP = ("Where the policy, the steering and the re-plans run: auto (a CUDA GPU when one "
               "is available, else the CPU), cpu or cuda.")


class ObjectiveSettings(SettingsGroup):
    """The plan's objective weights (None: the world's, filled in by ``resolved``)."""

    gamma: _Weight | None = cli_field(
        None, "Proximity weight, or 'learn' to learn this person's from their comfort answers "
        "and 'too close' signals.", show="the world's", text=True)
    lam: _Weight | None = cli_field(
        None, "Diversity weight for the first half of the cycles (then 0, as in the paper's "
        "ablation).", show="the world's")


class SearchSettings(SettingsGroup):
    """How hard a cycle's plan is searched: the genetic search (C, G, K, early stop) and the
    steered motion sampling (B, M, diffusion steps) every command that plans shares."""

    population: Annotated[int, Field(ge=2, le=100_000)] = cli_field(
        24, "Genetic search population C.")
    generations: Annotated[int, Field(ge=1, le=1_000_000)] = cli_field(
        40, "Genetic search generations G.")
    samples: Annotated[int, Field(ge=1, le=100_000)] = cli_field(
        32, "Monte-Carlo samples K of the person's durations.")
    patience: Annotated[int, Field(ge=0)] = cli_field(
        8, "Stop the genetic search after this many generations without improvement.")
    particles: Annotated[int, Field(ge=1, le=4096)] = cli_field(
        4, "Steered motion samples B per motion request.")
    candidates: Annotated[int, Field(ge=1, le=4096)] = cli_field(
        8, "SVDD-PM candidates M per particle and diffusion step.")
    steps: Annotated[int, Field(ge=1, le=1000)] | None = cli_field(
        None, "Reverse diffusion steps per motion.", show="the policy's own")
    # stored only when set: the stored settings of every run before it stay as they were
    sampler: Annotated[Sampler | None, Field(exclude_if=lambda v: v is None)] = cli_field(
        None, "Reverse kernel of every steered motion: ddim, ddpm or dpm (DPM-Solver++ 2M, for "
        "few steps: --sampler dpm --steps 5).", show="the policy's own")
    reuse_motions: bool = cli_field(
        True, "Answer a motion request from the plan steered for it in an earlier cycle while "
        "the spatial models it was steered against are unchanged (off: every cycle steers "
        "afresh, as Algorithm 1 does).")


class SpatialSettings(SettingsGroup):
    """The spatial model: distance decay, observation noise, grid and cost evaluation."""

    beta: Annotated[float, Field(gt=0)] | None = cli_field(
        None, "Spatial distance decay, 1 per workspace unit.", show="the world's")
    rho: Annotated[float, Field(gt=0)] = cli_field(
        0.05, "Observation noise variance of the spatial model.")
    grid_points: Annotated[int, Field(ge=2, le=512)] | None = cli_field(
        None, "Spatial grid points per axis.", show="the world's")
    surrogate: bool = cli_field(
        False, "Evaluate spatial costs with the MLP surrogate (the paper's; a refit per cycle) "
        "instead of exact grid interpolation.")


class TeammateSettings(SettingsGroup):
    """What the simulated teammate does beyond their archetype (docs/design-notes.md,
    "Teammates who change" and "Reacting inside the cycle")."""

    change: str | None = cli_field(
        None, "The teammate becomes another one at a cycle: NAME@CYCLE[,NAME@CYCLE...], e.g. "
        "slow-outside@12.")
    drift: Annotated[float, Field(gt=-0.5, lt=0.5)] = cli_field(
        0.0, "Fraction by which the teammate's durations grow per cycle (negative: practice).")
    drift_from: Annotated[int, Field(ge=0)] = cli_field(0, "Cycle the drift starts at.")
    comfort: Annotated[float, Field(gt=0)] | None = cli_field(
        None, "The simulated teammate's own gamma, by which they answer the comfort question and "
        "signal 'too close' every cycle (with --reacts also their distances).",
        show="drawn from a population with --gamma learn", option="--teammate-gamma",
        aliases=("--comfort",))
    reacts: bool = cli_field(
        False, "The simulated person slows down or pauses when the moving robot comes close "
        "(with --teammate-gamma or --gamma learn: at distances set by their own gamma).")
    deviate: Annotated[float, Field(ge=0, le=1)] = cli_field(
        0.0, "Probability per cycle that the simulated person deviates from the plan (another "
        "order, a pause, a robot task taken).")

    @field_validator("change")
    @classmethod
    def _check_change(cls, v: str | None) -> str | None:
        if v is not None:
            from rapidds.worlds.changes import parse_changes  # numpy: not at `--help`

            parse_changes(v)
        return v


class ChangeSettings(SettingsGroup):
    """Noticing a teammate who changes: forgetting, change-point detection, asking."""

    forgetting: Annotated[float, Field(gt=0, le=1)] = cli_field(
        1.0, "Stabilised forgetting factor of the temporal and spatial models in (0, 1]; 1 is "
        "the paper's models.")
    detect: bool = cli_field(
        False, "Detect changes of the teammate (Bayesian online change points on each task's "
        "durations) and restart the beliefs of the tasks that changed.")
    hazard: Annotated[float, Field(gt=0, lt=1)] = cli_field(
        0.05, "Prior probability of a change at one observation (with --detect).")
    detect_threshold: Annotated[float, Field(gt=0, lt=1)] = cli_field(
        0.5, "Posterior probability of a change that raises an alarm (with --detect).")
    ask: bool = cli_field(
        False, "On a detected change, ask the teammate (a simulated one answers truthfully); a "
        "denial keeps the belief.")
    whole_person: bool = cli_field(
        False, "With --detect: a change seen on some tasks moves the beliefs of the others by the "
        "same ratio (fatigue, practice); with --ask, if the teammate agrees.")
    reexplore: Annotated[int, Field(ge=0)] = cli_field(
        0, "Cycles planned with lambda again after a detected change.")

    @field_validator("whole_person")
    @classmethod
    def _check_whole_person(cls, v: bool, info: ValidationInfo) -> bool:
        if v and not info.data.get("detect"):
            raise ValueError("needs --detect (it acts on detected changes)")
        return v


class GammaLearning(SettingsGroup):
    """Learning each person's gamma (docs/design-notes.md "Learning each person's gamma")."""

    gamma_learn: bool = cli_field(
        False, "Plan every cycle with the learned belief's gamma instead of a fixed one.",
        cli=False)  # the CLI says it as --gamma learn
    gamma_prior: str | None = cli_field(
        None, "With --gamma learn: the prior G or G:SPREAD (one log-sd is a factor SPREAD).",
        show="the world's gamma, spread 4")
    gamma_plan: Literal["mean", "cautious"] = cli_field(
        "mean", "With --gamma learn: plan with the posterior's mean or an upper quantile "
        "(cautious).")
    gamma_reactions: bool = cli_field(
        True, "With --reacts: the person's reactions are evidence about their gamma too (off: "
        "only what they say).")

    @field_validator("gamma_prior")
    @classmethod
    def _check_gamma_prior(cls, v: str | None, info: ValidationInfo) -> str | None:
        if v is not None:
            if not info.data.get("gamma_learn"):
                raise ValueError("needs --gamma learn (it is the prior of the learned gamma)")
            from rapidds.human.gamma import parse_gamma_prior  # numpy: not at `--help`

            parse_gamma_prior(v)
        return v


_GROUPS: dict[str, type[SettingsGroup]] = {
    "objective": ObjectiveSettings, "search": SearchSettings, "spatial": SpatialSettings,
    "teammate": TeammateSettings, "changes": ChangeSettings, "learning": GammaLearning}
_GROUP_OF: dict[str, str] = {name: group for group, model in _GROUPS.items()
                             for name in model.model_fields}
# the order of a stored run's flat settings, as they were stored before the groups
_STORE_ORDER: tuple[str, ...] = (
    "world", "variant", "human", "adapt", "cycles", "gamma", "lam", "seed", "population",
    "generations", "samples", "patience", "particles", "candidates", "steps", "sampler", "beta",
    "rho", "grid_points", "surrogate", "reuse_motions", "change", "drift", "drift_from",
    "forgetting", "detect", "hazard", "detect_threshold", "ask", "whole_person", "reexplore",
    "gamma_learn", "gamma_prior", "gamma_plan", "comfort", "gamma_reactions", "execution",
    "reacts", "deviate", "device", "slowdowns", "slowdown_mean", "slowdown_sd")


class RunConfig(Settings):
    """Everything that determines a run. Stored with the run (flat, :data:`_STORE_ORDER`), so
    ``--resume`` under other settings is refused rather than mixing two experiments in one
    record. ``device`` is not stored and not compared on ``--resume``: a run may continue on
    another device; records, models and checkpoints hold no device.
    """

    world: str = cli_field("fetch", "World to run in (see 'rapidds worlds').", argument=True)
    variant: str | None = cli_field(None, "Variant of the world's job.",
                                    show="the world's first")
    human: str | None = cli_field(
        None, "The run's teammate: a simulated one by the world's name for it (see 'rapidds "
        "worlds'), or the name of the live person.", show="the world's first")
    adapt: Adapt = cli_field(
        "full", "Which models learn: full (both), spatial, temporal or none; oracle plans with "
        "the teammate's true model (the floor); exact runs a CP-SAT schedule on the prior mean "
        "durations with the robot's fastest motions and learns nothing.")
    cycles: Annotated[int, Field(ge=1, le=100_000)] = cli_field(16, "Cycles I of the run.")
    seed: Annotated[int, Field(ge=0, lt=2**63)] = cli_field(
        0, "Seed: cycle c draws every random number from (seed, c), so the same seed gives the "
        "same run.")
    objective: ObjectiveSettings = ObjectiveSettings()
    search: SearchSettings = SearchSettings()
    spatial: SpatialSettings = SpatialSettings()
    teammate: TeammateSettings = TeammateSettings()
    changes: ChangeSettings = ChangeSettings()
    learning: GammaLearning = GammaLearning()
    execution: ExecutionField = cli_field(
        Planned(), "Inside the cycle, a registered execution: planned (the paper: the robot "
        "follows its plan), monitored (speed and separation monitoring), replanning (the rest "
        "of the cycle re-planned when the person deviates) or reactive (both).", show="planned",
        text=True)
    device: Device = Field("auto", exclude=True, description=DEVICE_HELP)
    slowdowns: Slowdowns | None = cli_field(
        None, "With --execution reactive: plan for the safety monitor's slowdowns, learned (the "
        "prediction corrected by what it really cost), predicted, or off (the paper's "
        "open-loop plan).", show="learned under reactive execution")
    slowdown_mean: Annotated[float, Field(gt=0, le=1000)] = cli_field(
        1.0, "Prior mean of the learned correction of predicted slowdowns (a factor; 1 trusts "
        "the prediction).")
    slowdown_sd: Annotated[float, Field(gt=0, le=1000)] = cli_field(
        1.0, "Prior spread of the learned correction of predicted slowdowns.")

    @model_validator(mode="before")
    @classmethod
    def _grouped(cls, data: Any) -> Any:
        """Flat settings (a stored run's, or keyword arguments) into their groups."""
        if not isinstance(data, dict):
            return data
        out: dict[str, Any] = {}
        groups: dict[str, dict[str, Any]] = {}
        for key, value in data.items():
            group = _GROUP_OF.get(key)
            if group is None:
                out[key] = value
            else:
                groups.setdefault(group, {})[key] = value
        for group, values in groups.items():
            given = out.get(group, {})
            if isinstance(given, SettingsGroup):
                given = given.model_dump()
            out[group] = {**given, **values} if isinstance(given, dict) else given
        return out

    @model_serializer(mode="wrap")
    def _flat(self, handler: SerializerFunctionWrapHandler,
              info: SerializationInfo) -> dict[str, Any]:
        """The stored form: one flat mapping in the order runs were always stored in."""
        nested = handler(self)
        flat: dict[str, Any] = {}
        for key, value in nested.items():
            if key in _GROUPS and isinstance(value, dict):
                flat.update(value)
            else:
                flat[key] = value
        order = {k: i for i, k in enumerate(_STORE_ORDER)}
        return dict(sorted(flat.items(), key=lambda kv: order.get(kv[0], len(order))))

    if not TYPE_CHECKING:  # a grouped setting read by its flat name: cfg.population
        def __getattr__(self, name: str) -> Any:
            values = self.__dict__.get(_GROUP_OF.get(name, ""))
            if values is not None:
                return getattr(values, name)
            return super().__getattr__(name)

    @classmethod
    def flat_fields(cls) -> dict[str, FieldInfo]:
        """Every setting by its flat (stored, CLI) name, grouped ones included."""
        fields = {k: f for k, f in cls.model_fields.items() if k not in _GROUPS}
        for model in _GROUPS.values():
            fields.update(model.model_fields)
        order = {k: i for i, k in enumerate(_STORE_ORDER)}
        return dict(sorted(fields.items(), key=lambda kv: order.get(kv[0], len(order))))

    @classmethod
    def error(cls, exc: Any) -> str:
        """One line naming the CLI option, a grouped setting by its own option (no group)."""
        from rapidds.settings import Place, error_line

        def locate(loc: tuple[Any, ...]) -> str:
            if len(loc) > 1 and loc[0] in _GROUPS:
                loc = loc[1:]
            if not loc:
                return "settings"
            return option_name(str(loc[0]), cls.flat_fields().get(str(loc[0])))

        return error_line(exc, with_input=True, unknown="unknown setting",
                          place=Place(locate=locate))

    @field_validator("slowdowns")
    @classmethod
    def _check_slowdowns(cls, v: str | None, info: ValidationInfo) -> str | None:
        execution = info.data.get("execution")
        if v in ("learned", "predicted") and not (execution is not None and execution.monitor):
            raise ValueError("needs an --execution that monitors, e.g. reactive (only there "
                             "does a monitor slow the robot)")
        return v

    @property
    def slowdown_mode(self) -> Slowdowns:
        """What the plan expects of the monitor, ``slowdowns`` with its default filled in."""
        if not self.execution.monitor:
            return "off"
        return self.slowdowns or "learned"

    @property
    def simulates_comfort(self) -> bool:
        """Whether the simulated teammate answers about their comfort (and records say so)."""
        return self.gamma_learn or self.comfort is not None

    def resolved(self, world: World) -> RunConfig:
        """Every None replaced by the world's value: what is stored, so a resumed run cannot
        pick up a changed default."""
        problem = world.problem()
        return self.replace(
            variant=world.variant,
            human=self.human if self.human is not None else world.teammate_names[0],
            gamma=problem.objective.gamma if self.gamma is None else self.gamma,
            lam=problem.objective.lam if self.lam is None else self.lam,
            beta=world.spatial_beta if self.beta is None else self.beta,
            grid_points=world.spatial_grid if self.grid_points is None else self.grid_points,
            slowdowns=self.slowdowns or ("learned" if self.execution.monitor else None),
        )

    @property
    def run_id(self) -> str:
        world = self.world if self.variant in (None, "default") else f"{self.world}-{self.variant}"
        human = str(self.human)
        if self.change:
            from rapidds.worlds.changes import parse_changes

            human += "-to-" + "-to-".join(f"{n}@{c}" for n, c in parse_changes(self.change))
        if self.drift:
            human += f"-drift{self.drift:+g}@{self.drift_from}"
        if self.comfort is not None:
            human += f"-comfort{self.comfort:g}"
        learn = (f"-glearn{'-cautious' if self.gamma_plan == 'cautious' else ''}"
                 f"{'' if self.gamma_reactions or not self.reacts else '-saidonly'}")
        return (f"{world}-{human}-{self.adapt}{learn if self.gamma_learn else ''}"
                f"{self.cell_suffix}-s{self.seed}")

    @property
    def cell_suffix(self) -> str:
        """What the run id says of execution inside the cycle; empty for the paper's."""
        slow = {"off": "-noslow", "predicted": "-slowpred"}.get(str(self.slowdowns), "")
        return (self.execution.run_suffix + slow * self.execution.monitor
                + "-reacts" * self.reacts
                + (f"-dev{self.deviate:g}" if self.deviate else ""))

    @property
    def in_cycle(self) -> bool:
        """Whether anything happens inside the cycle that the paper's execution lacks."""
        return bool(self.cell_suffix)

    def lam_at(self, cycle: int, last_change: int | None = None) -> float:
        """lambda for ``cycle``: constant for the first half of the cycles, then 0; again for
        ``reexplore`` cycles after a change detected in cycle ``last_change``."""
        lam = self.lam or 0.0
        if last_change is not None and 0 < cycle - last_change <= self.reexplore:
            return lam
        return lam if cycle < self.cycles / 2 else 0.0

    @property
    def exploration_end(self) -> float:
        return self.cycles / 2 - 0.5
