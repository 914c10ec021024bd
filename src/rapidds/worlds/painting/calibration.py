"""Which of the paper's painting behaviours this world's numbers support, computed from the world
alone: the population prior's spatial model, a person's learned model, the robot's two
demonstrated modes per mix and their completion times (docs/design-notes.md, "The painting
cell"). Nothing here samples the diffusion policy; the robot's motion for a request (j, C_j)
is whichever demonstrated mode the steering value prefers, V = d + gamma * max_{i in C_j} S_i
(the paper's steering target, evaluated on the nominal motions).

With those motions every schedule of the job is scored by the library's Algorithm 2
(:func:`~rapidds.scheduler.evaluate_population`: the overlap loop, expected makespan over the
prior's duration samples + gamma * sum of S) and the best is what a planner that searched the
whole space would pick. The space is small enough to enumerate: who brushes, the mix order, and
every place a wait can go (the robot before either mix, for Prep Vise or Secure Piece to end;
the person before Prep Vise or Secure Piece, for either or both mixes to end). A behaviour
holds when the best schedule has it; its margin is how much worse (objective seconds) the best
schedule without it is.

S values are :class:`~rapidds.human.spatial.SpatialModel` costs (grid interpolation, the loop's
default) of the arm's 12 points over the whole trajectory.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from rapidds.human.spatial import SpatialConfig, SpatialModel
from rapidds.human.temporal import TemporalModel
from rapidds.motion.interface import MotionKey, MotionPlan, TrajectoryCache
from rapidds.problem import Problem
from rapidds.schedule import Item, Schedule, Wait
from rapidds.scheduler import Evaluation, EvaluationContext, evaluate_population
from rapidds.worlds.painting.world import PaintingWorld

__all__ = [
    "Behaviour",
    "BehaviourSpec",
    "Calibration",
    "NominalMotion",
    "PlanSummary",
    "behaviours",
    "calibrate",
    "enumerate_schedules",
    "prior_model",
    "spatial_config",
    "summarize",
]

_HUMAN_SPATIAL = ("prep_vise", "secure_piece")
_MIXES = ("mix_l", "mix_r")


def spatial_config(world: PaintingWorld, rho: float = 0.05) -> SpatialConfig:
    """The spatial model configuration the world asks for (bounds, beta, grid)."""
    lo, hi = world.workspace_bounds
    return SpatialConfig.from_box(lo, hi, beta=world.spatial_beta, grid_points=world.spatial_grid,
                                  rho=rho)


def prior_model(world: PaintingWorld) -> SpatialModel:
    """The spatial prior of Prep Vise and Secure Piece from the world's population (Eq. 9)."""
    paths = {t: world.prior().paths[t] for t in _HUMAN_SPATIAL}
    return SpatialModel.from_population(spatial_config(world), paths)


class NominalMotion:
    """A :class:`~rapidds.motion.interface.MotionModel` whose answer to (j, C_j) is the
    demonstrated mode of j with the lowest V = d + gamma * max_{i in C_j} S_i."""

    def __init__(self, world: PaintingWorld, spatial: SpatialModel, gamma: float):
        self.world, self.gamma = world, float(gamma)
        self.options: dict[str, list[tuple[str, float, np.ndarray]]] = {}
        self._s: dict[tuple[str, str], dict[str, float]] = {}
        for task in ("mix_l", "mix_r", "brush"):
            self.options[task] = []
            for mode in world.modes(task):
                traj = world.robot_trajectory(task, mode)
                d = world.robot_duration(task, traj)
                self.options[task].append((mode, d, traj))
                pts = world.robot_points(traj).reshape(1, -1, 3)
                self._s[task, mode] = {h: float(spatial.cost([h], pts)[0]) for h in spatial}

    def spatial(self, task: str, mode: str, concurrent: Iterable[str]) -> float:
        """max over the concurrent human tasks of S (0 for none)."""
        return max((self._s[task, mode][h] for h in concurrent if h in self._s[task, mode]),
                   default=0.0)

    def choose(self, task: str, concurrent: frozenset[str]) -> tuple[str, float, float]:
        """(mode, duration, S) of the lowest-V demonstrated mode."""
        best = min(self.options[task], key=lambda o: o[1] + self.gamma * self.spatial(
            task, o[0], concurrent))
        return best[0], best[1], self.spatial(task, best[0], concurrent)

    def nominal_durations(self, problem: Problem) -> np.ndarray:
        return np.array([np.nan if t.robot_duration is None else t.robot_duration
                         for t in problem.tasks])

    def plan(self, requests: Sequence[MotionKey]) -> list[MotionPlan]:
        out = []
        for task, concurrent in requests:
            mode, d, s = self.choose(task, concurrent)
            traj = next(o[2] for o in self.options[task] if o[0] == mode)
            out.append(MotionPlan(task, concurrent, d, s, traj))
        return out


def enumerate_schedules(problem: Problem) -> list[Schedule]:
    """Every schedule of the painting job worth planning: who brushes, the mix order (Mix R
    first in the constrained variant), the robot waiting before either mix for Prep Vise or
    Secure Piece to end, the person waiting before Prep Vise for the first or both mixes and
    before Secure Piece for either or both (for mixes not already waited for)."""
    orders = [("mix_r", "mix_l")] if ("mix_r", "mix_l") in problem.precedence else \
        [("mix_l", "mix_r"), ("mix_r", "mix_l")]
    robot_waits: tuple[tuple[str, ...], ...] = ((), ("prep_vise",), ("secure_piece",))
    out = []
    for brusher, (m1, m2), w1, w2 in itertools.product(("robot", "human"), orders, robot_waits,
                                                       robot_waits):
        robot: list[Item] = [*(Wait(t) for t in w1), m1, *(Wait(t) for t in w2), m2]
        if brusher == "robot":
            robot.append("brush")
        for pre, hw in itertools.product(((), (m1,), (m1, m2)), ((), (m1,), (m2,), (m1, m2))):
            if set(pre) & set(hw):
                continue  # waiting twice for one mix changes nothing
            human: list[Item] = [*(Wait(t) for t in pre), "prep_vise", *(Wait(t) for t in hw),
                                 "secure_piece"]
            if brusher == "human":
                human.append("brush")
            out.append(Schedule(tuple(human), tuple(robot)))
    return out


@dataclass(frozen=True)
class Behaviour:
    """One behaviour of the paper in one setting: does the best schedule have it, and by how
    many objective seconds does it beat the best schedule without it (negative: it loses)."""

    name: str
    setting: str
    belief: str
    holds: bool
    margin: float
    best: str


@dataclass
class Calibration:
    """The deciding quantities and the behaviours built on them.

    teammate: whose cycles were learned. near: the mix on their side ("mix_l" for a left-handed
    person), far: the other. durations: (mix, mode) -> completion time (s). spatial: (belief,
    mix, mode, human task) -> S, belief "prior" (population), "learned" (the prior after
    ``cycles`` observed cycles of the teammate) or "own" (the teammate's own paths only, the
    limit of learning). prep, secure: prior mean durations (s).
    """

    teammate: str
    near: str
    far: str
    cycles: int
    durations: dict[tuple[str, str], float]
    spatial: dict[tuple[str, str, str, str], float]
    prep: float
    secure: float
    behaviours: list[Behaviour] = field(default_factory=list)

    def table(self) -> str:
        """The behaviours as a plain-text table."""
        rows = [f"{'setting':<22} {'belief':<8} {'behaviour':<52} {'holds':<5} {'margin':>7}"]
        for b in self.behaviours:
            rows.append(f"{b.setting:<22} {b.belief:<8} {b.name:<52} {b.holds!s:<5} "
                        f"{b.margin:+7.2f}")
        return "\n".join(rows)


def calibrate(world: PaintingWorld | None = None, *, cycles: int = 6, seed: int = 1,
              teammate: str = "left-fast", prior: SpatialModel | None = None,
              samples: int = 64) -> Calibration:
    """Quantities and behaviours for ``teammate`` after ``cycles`` observed cycles of Prep Vise
    and Secure Piece (conjugate updates of the prior, as the loop's full adaptation does).
    ``prior``: the world's :func:`prior_model`, when already built. ``samples``: prior duration
    samples the makespan is averaged over (seeded)."""
    w = world or PaintingWorld()
    unconstrained = dataclasses.replace(w, variant="unconstrained")
    constrained = dataclasses.replace(w, variant="constrained")
    prior = prior_model(w) if prior is None else prior
    learned = copy.deepcopy(prior)
    person = w.teammate(teammate)
    rng = np.random.default_rng(seed)
    own_paths: dict[str, list[np.ndarray]] = {t: [] for t in _HUMAN_SPATIAL}
    for _ in range(cycles):
        for t in _HUMAN_SPATIAL:
            path = person.perform(t, rng)[1]
            learned.observe(t, path)
            own_paths[t].append(path)
    own = SpatialModel.from_population(spatial_config(w), own_paths)
    near, far = ("mix_l", "mix_r") if person.hand == "left" else ("mix_r", "mix_l")
    beliefs = {"prior": prior, "learned": learned, "own": own}
    durations: dict[tuple[str, str], float] = {}
    spatial: dict[tuple[str, str, str, str], float] = {}
    for name, model in beliefs.items():
        nm = NominalMotion(w, model, 0.0)
        for task in _MIXES:
            for mode, d, _ in nm.options[task]:
                durations[task, mode] = d
                for h in _HUMAN_SPATIAL:
                    spatial[name, task, mode, h] = nm.spatial(task, mode, [h])
    problem = unconstrained.problem()
    out = Calibration(teammate, near, far, cycles, durations, spatial,
                      float(problem.task("prep_vise").human_mean or 0.0),
                      float(problem.task("secure_piece").human_mean or 0.0))
    temporal = TemporalModel.from_population(problem, w.prior().durations)
    draws = temporal.sample(samples, np.random.default_rng(seed))
    mean = temporal.mean()

    worlds = {"unconstrained": unconstrained, "constrained": constrained}
    for spec in behaviours(near, far):
        world, gamma = worlds[spec.variant], spec.gamma
        prob = world.problem().with_objective(gamma=gamma, lam=0.0)
        motion = NominalMotion(world, beliefs[spec.belief], gamma)
        evs = evaluate_population(
            EvaluationContext(prob, draws, mean, TrajectoryCache(motion),
                              motion.nominal_durations(prob), gamma, 0.0),
            enumerate_schedules(prob))
        ranked = sorted((e for e in evs if e.feasible), key=lambda e: e.objective)
        summaries = [summarize(prob, e, lambda t, p, m=motion: m.choose(t, p.concurrent)[0])
                     for e in ranked]
        yes = [e.objective for e, sm in zip(ranked, summaries, strict=True) if spec.test(sm)]
        no = [e.objective for e, sm in zip(ranked, summaries, strict=True) if not spec.test(sm)]
        holds = bool(yes) and (not no or yes[0] < no[0])
        margin = -np.inf if not yes else (no[0] if no else np.inf) - yes[0]
        out.behaviours.append(Behaviour(spec.name, spec.setting, spec.belief, holds,
                                        float(margin), str(summaries[0])))
    return out


@dataclass(frozen=True)
class PlanSummary:
    """What a painting plan does, as the paper's behaviours speak of it: the robot's first
    mix, the motion mode of every mix that runs during Secure Piece, and whether anyone idles
    on the expected timeline (the person between Prep Vise and Secure Piece, the robot before
    or between its mixes; wait tokens that cost nothing do not count)."""

    robot: tuple[str, ...]
    human: tuple[str, ...]
    first: str
    during: dict[str, str]
    idle: bool

    def __str__(self) -> str:
        during = ", ".join(f"{t} {m}" for t, m in self.during.items()) or "no mix"
        return (f"robot [{' '.join(self.robot)}] person [{' '.join(self.human)}]; during "
                f"Secure Piece: {during}")


def summarize(problem: Problem, ev: Evaluation, mode: Callable[[str, MotionPlan], str],
              ) -> PlanSummary:
    """The :class:`PlanSummary` of an evaluated plan; ``mode(task, plan)`` names a motion's
    mode ("direct" or "avoidant"), e.g. :meth:`PaintingWorld.motion_label` of its trajectory."""
    idx = problem.index
    first = next(str(x) for x in ev.schedule.robot if str(x) in _MIXES)
    second = next(t for t in _MIXES if t != first)
    s, f = ev.expected_start, ev.expected_finish
    idle = not (s[idx["secure_piece"]] <= f[idx["prep_vise"]] + 1e-9
                and s[idx[first]] <= 1e-9 and s[idx[second]] <= f[idx[first]] + 1e-9)
    during = {t: mode(t, p) for t, p in ev.motions.items()
              if t in _MIXES and "secure_piece" in ev.overlaps.get(t, ())}
    return PlanSummary(tuple(str(x) for x in ev.schedule.robot),
                       tuple(str(x) for x in ev.schedule.human), first, during, idle)


@dataclass(frozen=True)
class BehaviourSpec:
    """One of the paper's behaviours: the setting it is claimed in and the test of a plan."""

    name: str
    variant: str
    gamma: float
    belief: str
    test: Callable[[PlanSummary], bool]

    @property
    def setting(self) -> str:
        return f"{self.variant} g{self.gamma:g}"


def behaviours(near: str = "mix_l", far: str = "mix_r") -> list[BehaviourSpec]:
    """The paper's four behaviours as tests of the plan made before learning ("prior") and
    after ("learned") for a person whose hand works near ``near``'s tray."""
    specs = [
        BehaviourSpec("a mix runs during Secure Piece, direct", "unconstrained", 12, "prior",
                      lambda p: list(p.during.values()) == ["direct"]),
        BehaviourSpec(f"{near} first, {far} direct during Secure Piece", "unconstrained", 12,
                      "learned", lambda p: p.first == near and p.during == {far: "direct"}),
        BehaviourSpec("Mix L direct during Secure Piece", "constrained", 12, "prior",
                      lambda p: p.during.get("mix_l") == "direct"),
    ]
    if near == "mix_l":
        specs.append(BehaviourSpec(
            "Mix L avoidant during Secure Piece, no wait", "constrained", 12, "learned",
            lambda p: p.during.get("mix_l") == "avoidant" and not p.idle))
    else:  # Mix L is the far mix of a right-handed person: it stays direct
        specs.append(BehaviourSpec("Mix L direct during Secure Piece", "constrained", 12,
                                   "learned", lambda p: p.during.get("mix_l") == "direct"))
    specs += [
        BehaviourSpec("a mix runs during Secure Piece, avoidant", "unconstrained", 25, "prior",
                      lambda p: list(p.during.values()) == ["avoidant"]),
        BehaviourSpec(f"{near} first, {far} direct during Secure Piece", "unconstrained", 25,
                      "learned", lambda p: p.first == near and p.during == {far: "direct"}),
        BehaviourSpec("no mix during Secure Piece (a wait)", "unconstrained", 85, "prior",
                      lambda p: not p.during),
        BehaviourSpec(f"no wait, {near} first, {far} during Secure Piece", "unconstrained", 85,
                      "learned", lambda p: not p.idle and p.first == near
                      and set(p.during) == {far}),
    ]
    return specs
