"""What a run builds once, before its first cycle: the :class:`RunContext`.

The world (from the registry unless given), the config resolved against it, the teammate,
the problem with the run's fixed weights, the steering policy, the beliefs about the person
(the world's population prior, or a given one, copied), and the simulated person's own
comfort and reaction. Every cycle of the run reads these; only the beliefs change, by
learning, and the cycle carries what it planned with (its gamma among them).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rapidds.errors import CheckpointError, RapiddsError
from rapidds.loop.comfort import SimulatedComfort, simulated_comfort
from rapidds.loop.config import RunConfig
from rapidds.loop.execute import check_cell, person_reaction
from rapidds.loop.model import HumanModel, check_teammate, gamma_prior, prior_model
from rapidds.loop.slowdowns import Slowdowns
from rapidds.motion.policy import DiffusionPolicy
from rapidds.problem import Problem
from rapidds.settings import require_memory
from rapidds.worlds.base import SimulatedTeammate, Teammate, World, shipped_policies
from rapidds.worlds.reactions import Reaction
from rapidds.worlds.registry import make_world

__all__ = ["RunContext", "load_policy", "policy_dir"]


def policy_dir(world: World, path: Path | str | None = None) -> Path:
    """The checkpoint directory ``path`` names: a directory, the name of one the world ships
    (see :func:`shipped_policies`), or None for the world's bundled policy. A study's client
    resolves it once and hands its workers the directory, so every trial loads one network."""
    if path is not None and len(Path(path).parts) == 1 and not Path(path).exists():
        shipped = shipped_policies(world)
        if str(path) not in shipped:
            raise CheckpointError(f"checkpoint {path} does not exist, and {world.name} ships "
                                  f"no policy of that name ({', '.join(shipped) or 'none'})")
        path = shipped[str(path)]
    directory = path or world.bundled_policy()
    if directory is None:
        raise CheckpointError(
            f"no bundled {world.name} policy in this install; train one with "
            f"'rapidds train-policy --world {world.name} --out DIR' and pass --policy DIR"
        )
    return Path(directory)


def load_policy(world: World, path: Path | str | None = None, device: str = "auto"
                ) -> DiffusionPolicy:
    """The checkpoint :func:`policy_dir` names, on ``device`` ("auto": a CUDA GPU when there
    is one; "cuda" without one is a ConfigError, one line at the CLI)."""
    return DiffusionPolicy.load(policy_dir(world, path), device=device)


@dataclass
class RunContext:
    """A run's fixed parts and its beliefs. ``problem`` holds the run's configured weights
    (the world's gamma unless ``--gamma``); a cycle plans with the gamma the beliefs give it.
    ``comfort``: the run's own simulated person's comfort (None for an injected teammate, who
    says what they felt through their source); ``reaction``: the simulated person's reaction
    to the robot, all run long (None unless ``reacts``)."""

    world: World
    config: RunConfig
    teammate: Teammate
    problem: Problem
    policy: DiffusionPolicy
    model: HumanModel
    comfort: SimulatedComfort | None
    reaction: Reaction | None
    slowdowns: Slowdowns

    @classmethod
    def build(cls, config: RunConfig, policy: DiffusionPolicy | None = None,
              world: World | None = None, teammate: Teammate | None = None,
              prior: HumanModel | None = None) -> RunContext:
        """The context of a run of ``config`` (module docstring); RapiddsError for settings
        that cannot run (an oracle without a simulated person, a search too large for memory,
        a live person with simulated reactions)."""
        world = world or make_world(config.world, config.variant)
        c = config.resolved(world)
        mate = check_teammate(world, c, teammate)
        if c.adapt == "oracle" and not isinstance(mate, SimulatedTeammate):
            raise RapiddsError("--adapt oracle needs a simulated teammate (it plans with their "
                               "true model)")
        n, h, d = len(world.task_ids), world.horizon, world.state_dim
        # a generation's timelines (C x K x n, a few arrays) and one steering batch of every
        # motion request of a generation (C x n requests x B x M rows, network activations)
        require_memory(8 * 8 * c.population * c.samples * n
                       + 4 * 256 * c.population * n * c.particles * c.candidates * h * d,
                       "this search (--population, --samples, --particles, --candidates)")
        policy = (policy or load_policy(world, device=c.device)).with_sampler(c.sampler)
        problem = world.problem().with_objective(gamma=c.gamma, lam=c.lam)
        # a given prior (e.g. one population prior shared by a study's runs, computed once) is
        # copied: the run learns into its own model
        model = (HumanModel.from_bytes(prior.to_bytes()) if prior is not None
                 else prior_model(world, c))
        if c.gamma_learn and model.gamma is None:
            model.gamma = gamma_prior(world, c)
        comfort = (simulated_comfort(world.problem().objective.gamma, c.seed, c.comfort)
                   if c.simulates_comfort and teammate is None else None)
        check_cell(c, mate)
        reaction = person_reaction(world, c)
        if reaction is not None and comfort is not None:
            reaction = comfort.reaction(reaction, model.spatial.config.beta)
        slowdowns = Slowdowns(world, c)
        model.slowdowns = model.slowdowns or slowdowns.belief()
        return cls(world, c, mate, problem, policy, model, comfort, reaction, slowdowns)
