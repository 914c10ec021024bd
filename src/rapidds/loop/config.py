"""What determines a run: world, teammate, adaptation level, cycles, objective and search."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field, ValidationInfo, field_validator

from rapidds.settings import Settings

if TYPE_CHECKING:  # a type only: `rapidds --help` must not pay for numpy
    from rapidds.worlds.base import World

__all__ = ["ADAPT_LEVELS", "DEVICE_HELP", "EXECUTIONS", "Adapt", "Device", "Execution",
           "RunConfig", "Slowdowns"]

Adapt = Literal["full", "spatial", "temporal", "none", "oracle", "exact"]
Execution = Literal["planned", "reactive"]
Slowdowns = Literal["learned", "predicted", "off"]
EXECUTIONS: tuple[str, ...] = ("planned", "reactive")
ADAPT_LEVELS: tuple[str, ...] = ("full", "spatial", "temporal", "none", "oracle", "exact")

_Count = Annotated[int, Field(ge=1)]
_Weight = Annotated[float, Field(ge=0)]

Device = Literal["auto", "cpu", "cuda"]
Sampler = Literal["ddim", "ddpm", "dpm"]
DEVICE_HELP = ("Where the policy, the steering and the re-plans run: auto (a CUDA GPU when one "
               "is available, else the CPU), cpu or cuda.")


class RunConfig(Settings):
    """Everything that determines a run. Stored with the run, so ``--resume`` under other
    settings is refused rather than mixing two experiments in one record.

    world, variant: the registered world and its variant (None: its default).
    human: the simulated teammate, by the world's name for it (None: the world's first one);
        a run with a live person names them here.
    adapt: which models learn: ``full`` (both), ``spatial``, ``temporal``, ``none``; ``oracle``
        plans with the teammate's true model (the floor); ``exact`` is what a user of a
        constraint scheduler would run: a CP-SAT schedule on the prior mean durations, the
        robot's fastest motions (no proximity term, no waits), nothing learned.
    cycles: I, cycles in the run. gamma: proximity weight, lam: diversity weight for the first
        half of the cycles (then 0, as in the paper's ablation); None takes the world's.
    seed: cycle c draws every random number from (seed, c).
    population, generations, samples, patience: genetic search (C, G, K, early stop).
    particles, candidates: steered samples per motion request (B) and SVDD candidates (M).
    steps: reverse diffusion steps per motion (None: the policy's own).
    sampler: the reverse kernel of every steered motion, "ddim", "ddpm" or "dpm" (DPM-Solver++
        2M, for few steps: ``--sampler dpm --steps 5``); None: the policy's own (the paper's
        DDIM). Stored only when set, so records of runs without it are unchanged.
    beta, rho: spatial distance decay (1 / workspace unit; None: the world's) and observation
        noise variance. grid_points: spatial grid points per axis (None: the world's).
    surrogate: evaluate spatial costs with the MLP surrogate (the paper) instead of exact grid
        interpolation; costs a refit per cycle.
    reuse_motions: answer a motion request from the plan steered for it in an earlier cycle
        while the spatial models it was steered against are unchanged (:mod:`.carry`); False
        empties the memory every cycle as Algorithm 1 does.

    Teammates who change (docs/design-notes.md "Teammates who change"):
    change: the simulated teammate becomes another one at a cycle, ``NAME@CYCLE[,...]``.
    drift, drift_from: their durations grow by a factor (1 + drift) per cycle from cycle
        ``drift_from`` on (negative: practice).
    forgetting: factor in (0, 1] of the temporal and spatial models' stabilised forgetting;
        1 (default) is the paper's models.
    detect: Bayesian online change-point detection on every observed task's durations; a
        change resets the task's beliefs to the observations since it. hazard: prior
        probability of a change at one observation; detect_threshold: posterior probability
        of a change that raises an alarm.
    ask: on an alarm, ask the person whether they changed; a denial keeps the old belief.
    whole_person: (with detect) a change acted on in some tasks is the whole person's: the
        other tasks' beliefs move by the same duration ratio (with ask: if the person says so).
    reexplore: cycles after a detected change planned with the exploration weight lambda again.

    Learning each person's gamma (docs/design-notes.md "Learning each person's gamma"):
    gamma_learn: plan every cycle with the belief's gamma (``--gamma learn``) instead of the
        fixed ``gamma``; gamma_prior: that belief's prior ``G[:SPREAD]`` (None: the world's
        gamma, spread 4); gamma_plan: ``mean`` or ``cautious`` (an upper quantile).
    comfort: the SIMULATED teammate's true gamma (None: drawn from a population when learning).
        With it (or when learning) the simulated teammate answers a comfort question and
        signals "too close" every cycle, stored in the record; with ``reacts`` their comfort
        and stop distances follow it too.
    gamma_reactions: with ``reacts``, the person's reactions (slowing or pausing near the robot)
        are evidence about their gamma too (stored with the comfort evidence); False: only
        what they say (run id ``-saidonly`` when learning).
    Inside the cycle (docs/design-notes.md "Reacting inside the cycle"):
    execution: ``planned`` (the paper: the robot follows its plan whatever happens) or
        ``reactive`` (speed and separation monitoring, and re-planning the rest of the cycle
        when the person deviates).
    reacts: the simulated person slows down or pauses when the moving robot comes close.
    deviate: probability per cycle that the simulated person deviates from the plan (another
        order, a pause, or taking a robot task).

    device: where the policy's network, the steering and the re-plans run (see
        :data:`DEVICE_HELP`). Not stored with the run and not compared on ``--resume``: a run
        may continue on another device; records, models and checkpoints hold no device.
    slowdowns: whether the plan expects the safety monitor (only under reactive execution,
        where it runs; docs/design-notes.md "Plans that expect the safety monitor"):
        ``learned`` (the default there) adds to every robot motion the time the monitor is
        predicted to slow or hold it, corrected per (robot task, person's task) by what it
        really lost in earlier cycles; ``predicted`` the prediction alone; ``off`` plans for an
        open-loop robot as the paper does. slowdown_mean, slowdown_sd: the prior of that
        correction (a factor on the prediction; 1 trusts it).
    """

    world: str = "fetch"
    variant: str | None = None
    human: str | None = None
    adapt: Adapt = "full"
    cycles: Annotated[int, Field(ge=1, le=100_000)] = 16
    gamma: _Weight | None = None
    lam: _Weight | None = None
    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0
    population: Annotated[int, Field(ge=2, le=100_000)] = 24
    generations: Annotated[int, Field(ge=1, le=1_000_000)] = 40
    samples: Annotated[int, Field(ge=1, le=100_000)] = 32
    patience: Annotated[int, Field(ge=0)] = 8
    particles: Annotated[int, Field(ge=1, le=4096)] = 4
    candidates: Annotated[int, Field(ge=1, le=4096)] = 8
    steps: Annotated[int, Field(ge=1, le=1000)] | None = None
    sampler: Sampler | None = Field(None, exclude_if=lambda v: v is None)
    beta: Annotated[float, Field(gt=0)] | None = None
    rho: Annotated[float, Field(gt=0)] = 0.05
    grid_points: Annotated[int, Field(ge=2, le=512)] | None = None
    surrogate: bool = False
    reuse_motions: bool = True
    change: str | None = None
    drift: Annotated[float, Field(gt=-0.5, lt=0.5)] = 0.0
    drift_from: Annotated[int, Field(ge=0)] = 0
    forgetting: Annotated[float, Field(gt=0, le=1)] = 1.0
    detect: bool = False
    hazard: Annotated[float, Field(gt=0, lt=1)] = 0.05
    detect_threshold: Annotated[float, Field(gt=0, lt=1)] = 0.5
    ask: bool = False
    whole_person: bool = False
    reexplore: Annotated[int, Field(ge=0)] = 0
    gamma_learn: bool = False
    gamma_prior: str | None = None
    gamma_plan: Literal["mean", "cautious"] = "mean"
    comfort: Annotated[float, Field(gt=0)] | None = None
    gamma_reactions: bool = True
    execution: Execution = "planned"
    reacts: bool = False
    deviate: Annotated[float, Field(ge=0, le=1)] = 0.0
    device: Device = Field("auto", exclude=True, description=DEVICE_HELP)
    slowdowns: Slowdowns | None = None
    slowdown_mean: Annotated[float, Field(gt=0, le=1000)] = 1.0
    slowdown_sd: Annotated[float, Field(gt=0, le=1000)] = 1.0

    @field_validator("change")
    @classmethod
    def _check_change(cls, v: str | None) -> str | None:
        if v is not None:
            from rapidds.worlds.changes import parse_changes  # numpy: not at `--help`

            parse_changes(v)
        return v

    @field_validator("whole_person")
    @classmethod
    def _check_whole_person(cls, v: bool, info: ValidationInfo) -> bool:
        if v and not info.data.get("detect"):
            raise ValueError("needs --detect (it acts on detected changes)")
        return v

    @field_validator("slowdowns")
    @classmethod
    def _check_slowdowns(cls, v: str | None, info: ValidationInfo) -> str | None:
        if v in ("learned", "predicted") and info.data.get("execution") != "reactive":
            raise ValueError("needs --execution reactive (only there does a monitor slow the "
                             "robot)")
        return v

    @field_validator("gamma_prior")
    @classmethod
    def _check_gamma_prior(cls, v: str | None, info: ValidationInfo) -> str | None:
        if v is not None:
            if not info.data.get("gamma_learn"):
                raise ValueError("needs --gamma learn (it is the prior of the learned gamma)")
            from rapidds.human.gamma import parse_gamma_prior  # numpy: not at `--help`

            parse_gamma_prior(v)
        return v

    @property
    def slowdown_mode(self) -> Slowdowns:
        """What the plan expects of the monitor, ``slowdowns`` with its default filled in."""
        if self.execution != "reactive":
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
            slowdowns=self.slowdowns or ("learned" if self.execution == "reactive" else None),
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
        return ("-reactive" * (self.execution == "reactive") + slow * (self.execution ==
                "reactive") + "-reacts" * self.reacts
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
