"""The four systems of the user study and the two adaptations each one has.

The paper's study crosses spatial adaptation (motion models) with temporal adaptation (duration
models): full = RAPIDDS, spatial only, temporal only (Liu et al. 2021), none. The analyses use
the two adaptations as the factors of a 2 x 2 within-subject design.
"""

from __future__ import annotations

SYSTEMS: tuple[str, ...] = ("full", "spatial", "temporal", "none")
"""The study's systems, in the paper's order (also the order of the ablation study)."""

ADAPTATION: dict[str, tuple[bool, bool]] = {
    "full": (True, True),
    "spatial": (False, True),
    "temporal": (True, False),
    "none": (False, False),
}
"""System -> (temporal adaptation, spatial adaptation): the order of the loop's flags
(``rapidds.loop.run.LEARNS``), so a pair means the same wherever it is read."""

FACTORS: tuple[str, str] = ("temporal", "spatial")
"""Names of the two adaptation factors, in the order of :data:`ADAPTATION`'s pairs."""

ANALYSIS_FACTORS: tuple[str, str] = ("spatial", "temporal")
"""The factors in the order the analyses and their tables present them (the paper's: spatial x
temporal); read a system's flags by name, :func:`adapts`, never by position."""


def adapts(system: str, factor: str) -> bool:
    """Whether ``system`` has the ``factor`` ("temporal" or "spatial") adaptation."""
    return ADAPTATION[system][FACTORS.index(factor)]
