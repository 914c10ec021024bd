"""How people react at the painting cell and how its Panda stops (docs/design-notes.md
"Reacting inside the cycle"). Metres and seconds."""

from __future__ import annotations

from rapidds.worlds.reactions import ReactionPopulation, SafetyLimits

__all__ = ["REACTIONS", "SAFETY"]

REACTIONS = ReactionPopulation(comfort=(0.25, 0.05), stop=(0.12, 0.03), slow=(0.3, 0.6),
                               pause=(1.5, 4.0))
"""Comfort ~ 25 cm between a hand or forearm and the arm, stop ~ 12 cm."""

SAFETY = SafetyLimits(reaction_time=0.1, stopping_time=0.2, intrusion=0.05, sensing=0.02,
                      position=0.01)
"""A Panda: 0.1 s from sensing to command, ~0.2 s to a stop (category 1) at these speeds;
C = 5 cm (a hand's reach past the sensed point), Z_d = 2 cm tracking, Z_r = 1 cm of arm."""
