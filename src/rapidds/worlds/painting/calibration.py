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
the person before Secure Piece, for either or both mixes to end). A behaviour holds when the
best schedule has it; its margin is how much worse (objective seconds) the best schedule
without it is.

S values are :class:`~rapidds.human.spatial.SpatialModel` costs (grid interpolation, the loop's
default) of the arm's 12 points over the whole trajectory.
"""

from __future__ import annotations

import copy
import itertools
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from rapidds.human.spatial import SpatialConfig, SpatialModel
from rapidds.human.temporal import TemporalModel
from rapidds.motion.interface import MotionKey, MotionPlan, TrajectoryCache
from rapidds.problem import Problem
from rapidds.schedule import Item, Schedule, Wait
from rapidds.scheduler import Evaluation, evaluate_population
from rapidds.worlds.painting.world import PaintingWorld

__all__ = [
    "Behaviour",
    "Calibration",
    "NominalMotion",
    "calibrate",
    "enumerate_schedules",
    "prior_model",
    "spatial_config",
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
                d = float(world.completion_time(task, traj[None])[0])
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
    Secure Piece to end, the person waiting before Secure Piece for either or both mixes."""
    orders = [("mix_r", "mix_l")] if ("mix_r", "mix_l") in problem.precedence else \
        [("mix_l", "mix_r"), ("mix_r", "mix_l")]
    robot_waits: tuple[tuple[str, ...], ...] = ((), ("prep_vise",), ("secure_piece",))
    out = []
    for brusher, (m1, m2), w1, w2 in itertools.product(("robot", "human"), orders, robot_waits,
                                                       robot_waits):
        robot: list[Item] = [*(Wait(t) for t in w1), m1, *(Wait(t) for t in w2), m2]
        if brusher == "robot":
            robot.append("brush")
        for hw in ((), (m1,), (m2,), (m1, m2)):
            human: list[Item] = ["prep_vise", *(Wait(t) for t in hw), "secure_piece"]
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


def _describe(ev: Evaluation, modes: Callable[[str, MotionPlan], str]) -> str:
    robot = " ".join(str(x) for x in ev.schedule.robot)
    human = " ".join(str(x) for x in ev.schedule.human)
    during = ", ".join(f"{t} {modes(t, p)}" for t, p in ev.motions.items()
                       if t in _MIXES and "secure_piece" in ev.overlaps.get(t, ()))
    return f"robot [{robot}] person [{human}]; during Secure Piece: {during or 'no mix'}"


def calibrate(world: PaintingWorld | None = None, *, cycles: int = 6, seed: int = 1,
              teammate: str = "left-fast", prior: SpatialModel | None = None,
              samples: int = 64) -> Calibration:
    """Quantities and behaviours for ``teammate`` after ``cycles`` observed cycles of Prep Vise
    and Secure Piece (conjugate updates of the prior, as the loop's full adaptation does).
    ``prior``: the world's :func:`prior_model`, when already built. ``samples``: prior duration
    samples the makespan is averaged over (seeded)."""
    w = world or PaintingWorld()
    unconstrained = PaintingWorld(**{**_fields(w), "variant": "unconstrained"})
    constrained = PaintingWorld(**{**_fields(w), "variant": "constrained"})
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

    def best_plans(world: PaintingWorld, gamma: float, belief: str,
                   ) -> tuple[list[Evaluation], NominalMotion]:
        prob = world.problem().with_objective(gamma=gamma, lam=0.0)
        motion = NominalMotion(world, beliefs[belief], gamma)
        cache = TrajectoryCache(motion)
        evs = evaluate_population(prob, enumerate_schedules(prob), draws, mean, cache,
                                  motion.nominal_durations(prob), gamma, 0.0)
        return sorted((e for e in evs if e.feasible), key=lambda e: e.objective), motion

    def check(name: str, setting: str, world: PaintingWorld, gamma: float, belief: str,
              has: Callable[[Evaluation, NominalMotion], bool]) -> None:
        evs, motion = best_plans(world, gamma, belief)

        def mode(task: str, plan: MotionPlan) -> str:
            return motion.choose(task, plan.concurrent)[0]

        yes = [e for e in evs if has(e, motion)]
        no = [e for e in evs if not has(e, motion)]
        holds = bool(yes) and (not no or yes[0].objective < no[0].objective)
        margin = (no[0].objective if no else np.inf) - (yes[0].objective if yes else np.inf)
        if not yes:
            margin = -np.inf
        out.behaviours.append(Behaviour(name, setting, belief, holds, float(margin),
                                        _describe(evs[0], mode)))

    def during(ev: Evaluation, motion: NominalMotion) -> dict[str, str]:
        return {t: motion.choose(t, p.concurrent)[0] for t, p in ev.motions.items()
                if t in _MIXES and "secure_piece" in ev.overlaps.get(t, ())}

    def first(ev: Evaluation) -> str:
        return next(str(x) for x in ev.schedule.robot if str(x) in _MIXES)

    def no_waits(ev: Evaluation) -> bool:
        """Nobody idles on the expected timeline: the person starts Secure Piece when Prep Vise
        ends, the robot starts its first mix at once and its second when the first ends (wait
        tokens that cost nothing do not count)."""
        idx = problem.index
        s, f = ev.expected_start, ev.expected_finish
        m1 = first(ev)
        m2 = next(t for t in _MIXES if t != m1)
        return bool(s[idx["secure_piece"]] <= f[idx["prep_vise"]] + 1e-9
                    and s[idx[m1]] <= 1e-9 and s[idx[m2]] <= f[idx[m1]] + 1e-9)

    u, c = unconstrained, constrained
    # 1. unconstrained, gamma 12
    check("a mix runs during Secure Piece, direct", "unconstrained g12", u, 12, "prior",
          lambda e, m: list(during(e, m).values()) == ["direct"])
    check(f"{near} first, {far} direct during Secure Piece", "unconstrained g12", u, 12,
          "learned", lambda e, m: first(e) == near and during(e, m) == {far: "direct"})
    # 2. constrained, gamma 12
    check("Mix L direct during Secure Piece", "constrained g12", c, 12, "prior",
          lambda e, m: during(e, m).get("mix_l") == "direct")
    if near == "mix_l":
        check("Mix L avoidant during Secure Piece, no wait", "constrained g12", c, 12,
              "learned", lambda e, m: during(e, m).get("mix_l") == "avoidant" and no_waits(e))
    else:
        check("Mix L direct during Secure Piece", "constrained g12", c, 12, "learned",
              lambda e, m: during(e, m).get("mix_l") == "direct")
    # 3. unconstrained, gamma 25
    check("a mix runs during Secure Piece, avoidant", "unconstrained g25", u, 25, "prior",
          lambda e, m: list(during(e, m).values()) == ["avoidant"])
    check(f"{near} first, {far} direct during Secure Piece", "unconstrained g25", u, 25,
          "learned", lambda e, m: first(e) == near and during(e, m) == {far: "direct"})
    # 4. unconstrained, gamma 85
    check("no mix during Secure Piece (a wait)", "unconstrained g85", u, 85, "prior",
          lambda e, m: not during(e, m))
    check(f"no wait, {near} first, {far} during Secure Piece", "unconstrained g85", u, 85,
          "learned", lambda e, m: no_waits(e) and first(e) == near and set(during(e, m)) == {far})
    return out


def _fields(world: PaintingWorld) -> dict[str, object]:
    return {name: getattr(world, name) for name in (
        "dt", "horizon", "rest_radius", "gamma", "lam", "beta", "grid", "prior_people",
        "prior_samples", "prior_seed", "layout")}
