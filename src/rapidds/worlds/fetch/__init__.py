"""The fetch game, the paper's running example: map (:mod:`.map`), world (:mod:`.world`),
simulated teammates (:mod:`.teammates`) and the bundled policy (``policy/``)."""

from rapidds.worlds.fetch.map import HOMES, MODES, OBJECTS, TASK_IDS, WALLS, Route
from rapidds.worlds.fetch.teammates import ARCHETYPES, FetchTeammate, archetype, population
from rapidds.worlds.fetch.world import (
    POLICY_DEFAULTS,
    PRIOR_SEED,
    FetchWorld,
    default_world,
    fetch_problem,
)

__all__ = [
    "ARCHETYPES",
    "HOMES",
    "MODES",
    "OBJECTS",
    "POLICY_DEFAULTS",
    "PRIOR_SEED",
    "TASK_IDS",
    "WALLS",
    "FetchTeammate",
    "FetchWorld",
    "Route",
    "archetype",
    "default_world",
    "fetch_problem",
    "population",
]
