"""Worlds (job cells) and their teammates, found by name through :mod:`.registry`."""

from rapidds.worlds.base import (
    HumanExecution,
    PopulationPrior,
    RobotDemos,
    SimulatedTeammate,
    Teammate,
    World,
)
from rapidds.worlds.registry import make_world, register, world_names

__all__ = [
    "HumanExecution",
    "PopulationPrior",
    "RobotDemos",
    "SimulatedTeammate",
    "Teammate",
    "World",
    "make_world",
    "register",
    "world_names",
]
