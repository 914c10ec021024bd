"""Which of the paper's painting behaviours this world's numbers support, computed from the world
alone: the population prior's spatial model, a left-handed person's learned model, the robot's
nominal motions and their completion times. Nothing here runs the planner; it evaluates the
inequalities the planner's choices hinge on (docs/design-notes.md, "The painting cell").

Two decisions make every behaviour:

* Steering (per motion request, the paper's V = d + gamma * S): for a mix concurrent with Secure
  Piece it keeps the direct motion iff d_dir + gamma * S(dir) < d_avo + gamma * S(avo).
* Scheduling (per plan, makespan + gamma * sum S): moving during Secure Piece with the steered
  motion costs its makespan increase e (the mixes overrunning Prep Vise + Secure Piece) plus
  gamma * S; waiting for Secure Piece to end costs W, the second mix's duration after it.

S values are exact :class:`~rapidds.human.spatial.SpatialModel` costs (grid interpolation, the
loop's default) of the arm's points over the whole trajectory.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from rapidds.human.spatial import SpatialConfig, SpatialModel
from rapidds.worlds.painting.world import PaintingWorld

__all__ = ["Calibration", "Check", "calibrate", "prior_model", "spatial_config"]

_HUMAN_SPATIAL = ("prep_vise", "secure_piece")


def spatial_config(world: PaintingWorld, rho: float = 0.05) -> SpatialConfig:
    """The spatial model configuration the world asks for (bounds, beta, grid)."""
    lo, hi = world.workspace_bounds
    return SpatialConfig.from_box(lo, hi, beta=world.spatial_beta, grid_points=world.spatial_grid,
                                  rho=rho)


@dataclass(frozen=True)
class Check:
    """One inequality ``lhs < rhs`` a behaviour needs; ``margin`` = rhs - lhs (seconds)."""

    behaviour: str
    statement: str
    lhs: float
    rhs: float

    @property
    def margin(self) -> float:
        return self.rhs - self.lhs

    @property
    def holds(self) -> bool:
        return self.lhs < self.rhs


@dataclass
class Calibration:
    """The deciding quantities and the checks built on them.

    teammate: whose cycles were learned; near: the mix on their side ("mix_l" for a
    left-handed person); the other one is "far". durations: (role, mode) -> completion time
    (s), role "near" or "far". spatial: (belief, role, mode, human task) -> S, belief "prior"
    (population), "learned" (the prior after ``cycles`` observed cycles of the teammate) or
    "own" (the teammate's own paths only, the limit of learning).
    prep, secure: the prior mean durations (s). wait: W, what waiting for Secure Piece to end
    costs the makespan; overrun: mode -> e, the makespan increase of moving during it.
    """

    teammate: str
    near: str
    cycles: int
    durations: dict[tuple[str, str], float]
    spatial: dict[tuple[str, str, str, str], float]
    prep: float
    secure: float
    wait: float
    overrun: dict[str, float]
    checks: list[Check] = field(default_factory=list)

    def table(self) -> str:
        """The checks as a plain-text table."""
        rows = [f"{'behaviour':<34} {'needs':<58} {'lhs':>6} {'rhs':>6} {'margin':>7}"]
        for c in self.checks:
            rows.append(f"{c.behaviour:<34} {c.statement:<58} {c.lhs:6.2f} {c.rhs:6.2f} "
                        f"{c.margin:+7.2f}")
        return "\n".join(rows)


def prior_model(world: PaintingWorld) -> SpatialModel:
    """The spatial prior of Prep Vise and Secure Piece from the world's population (Eq. 9)."""
    paths = {t: world.prior().paths[t] for t in _HUMAN_SPATIAL}
    return SpatialModel.from_population(spatial_config(world), paths)


def calibrate(world: PaintingWorld | None = None, *, cycles: int = 6, seed: int = 1,
              teammate: str = "left-fast", prior: SpatialModel | None = None) -> Calibration:
    """Compute the quantities and checks for ``teammate`` after ``cycles`` observed cycles of
    Prep Vise and Secure Piece (conjugate updates of the prior, as the loop's full adaptation
    does). The checks speak of the teammate's own side: for a left-handed person the "near"
    mix is Mix L and the "far" one Mix R, for a right-handed person the other way round.
    ``prior``: the world's :func:`prior_model`, when already built."""
    w = world or PaintingWorld()
    cfg = spatial_config(w)
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
    own = SpatialModel.from_population(cfg, own_paths)
    near, far = ("mix_l", "mix_r") if person.hand == "left" else ("mix_r", "mix_l")
    durations: dict[tuple[str, str], float] = {}
    spatial: dict[tuple[str, str, str, str], float] = {}
    for task, role in ((near, "near"), (far, "far")):
        for mode in w.modes(task):
            traj = w.robot_trajectory(task, mode)
            durations[role, mode] = float(w.completion_time(task, traj[None])[0])
            pts = w.robot_points(traj).reshape(1, -1, 3)
            for name, model in (("prior", prior), ("learned", learned), ("own", own)):
                for human in _HUMAN_SPATIAL:
                    spatial[name, role, mode, human] = float(model.cost([human], pts)[0])
    problem = w.problem()
    prep = float(problem.task("prep_vise").human_mean or 0.0)
    secure = float(problem.task("secure_piece").human_mean or 0.0)
    d_dir, d_avo = durations["near", "direct"], durations["near", "avoidant"]
    end = prep + secure
    wait = end + d_dir - max(end, 2 * d_dir)
    overrun = {"direct": max(0.0, 2 * d_dir - end), "avoidant": max(0.0, d_dir + d_avo - end)}
    out = Calibration(teammate, near, cycles, durations, spatial, prep, secure, wait, overrun)
    out.checks = _checks(out)
    return out


def _checks(c: Calibration) -> list[Check]:
    d = c.durations
    s = c.spatial
    dd, da = d["near", "direct"], d["near", "avoidant"]

    def v(belief: str, role: str, mode: str, gamma: float) -> float:
        """Steering value of a mix concurrent with Secure Piece."""
        return d[role, mode] + gamma * s[belief, role, mode, "secure_piece"]

    def steered(belief: str, role: str, gamma: float) -> str:
        return min(("direct", "avoidant"), key=lambda m: v(belief, role, m, gamma))

    def move(belief: str, role: str, gamma: float) -> float:
        """Plan cost of moving during Secure Piece with the steered motion: e + gamma * S."""
        m = steered(belief, role, gamma)
        return c.overrun[m] + gamma * s[belief, role, m, "secure_piece"]

    def order(belief: str, first: str, second: str, gamma: float) -> float:
        """Plan cost of one mix (direct) during Prep Vise and the other during Secure Piece."""
        m = steered(belief, second, gamma)
        return (gamma * s[belief, first, "direct", "prep_vise"] + c.overrun[m]
                + gamma * s[belief, second, m, "secure_piece"])

    return [
        Check("1 unconstrained g12, first cycle", "direct mix in Secure Piece: V(dir) < V(avo)",
              v("prior", "near", "direct", 12), v("prior", "near", "avoidant", 12)),
        Check("1 unconstrained g12, learned", "near mix first: cost(near, far) < cost(far, near)",
              order("learned", "near", "far", 12), order("learned", "far", "near", 12)),
        Check("2 constrained g12, learned", "avoidant near mix: V(avo) < V(dir)",
              v("learned", "near", "avoidant", 12), v("learned", "near", "direct", 12)),
        Check("2 constrained g12, learned", "moving beats waiting: e + 12 S < W",
              move("learned", "near", 12), c.wait),
        Check("3 unconstrained g25, first cycle", "avoidant mix in Secure Piece",
              v("prior", "near", "avoidant", 25), v("prior", "near", "direct", 25)),
        Check("3 unconstrained g25, first cycle", "moving beats waiting: e + 25 S < W",
              move("prior", "near", 25), c.wait),
        Check("3 unconstrained g25, learned", "direct far mix in Secure Piece",
              v("learned", "far", "direct", 25), v("learned", "far", "avoidant", 25)),
        Check("3 unconstrained g25, learned", "near mix first: cost(near, far) < cost(far, near)",
              order("learned", "near", "far", 25), order("learned", "far", "near", 25)),
        Check("4 unconstrained g85, first cycle", "waiting beats moving: W < e + 85 S",
              c.wait, move("prior", "near", 85)),
        Check("4 unconstrained g85, learned", "far mix moves in Secure Piece: e + 85 S < W",
              move("learned", "far", 85), c.wait),
        Check("4 unconstrained g85, learned", "near mix first: cost(near, far) < cost(far, near)",
              order("learned", "near", "far", 85), order("learned", "far", "near", 85)),
        Check("timeline", "the first mix fits in Prep Vise: d_dir < prep", dd, c.prep),
        Check("timeline", "the avoidant mix is slower: d_dir < d_avo", dd, da),
    ]
