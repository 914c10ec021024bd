"""How people react in the fetch room and how its robot stops (docs/design-notes.md "Reacting
inside the cycle"). Metres and seconds; people walk 2.4-5.0 m/s here, the robot 4 m/s, so the
distances are those of a fast game rather than of a factory floor."""

from __future__ import annotations

from rapidds.worlds.reactions import ReactionPopulation, SafetyLimits

__all__ = ["REACTIONS", "SAFETY"]

REACTIONS = ReactionPopulation(comfort=(1.5, 0.3), stop=(0.7, 0.15), slow=(0.3, 0.6),
                               pause=(2.0, 5.0))
"""Comfort ~ 1.5 m (a third of a second of walking), stop ~ 0.7 m (the two bodies' reach)."""

SAFETY = SafetyLimits(reaction_time=0.1, stopping_time=0.3, intrusion=0.2, sensing=0.1,
                      position=0.05)
"""A mobile base at 4 m/s: 0.1 s sensing-to-command, 0.3 s braking; C = 0.2 m, the body
radius a point-sized agent stands for; Z_d = 0.1 m of tracking, Z_r = 0.05 m of odometry."""
