"""The collaborative-painting world (the paper's robot case): a Franka Emika Panda in MuJoCo, a
person's hands and forearms, five tasks in two variants. Importing this package is cheap: MuJoCo
and mink load when a scene, a motion or forward kinematics is first needed."""

from rapidds.worlds.painting.teammates import ARCHETYPES, PaintingTeammate
from rapidds.worlds.painting.world import TASK_IDS, VARIANTS, PaintingWorld

__all__ = ["ARCHETYPES", "TASK_IDS", "VARIANTS", "PaintingTeammate", "PaintingWorld"]
