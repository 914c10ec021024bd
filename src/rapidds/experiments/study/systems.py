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
    "spatial": (True, False),
    "temporal": (False, True),
    "none": (False, False),
}
"""System -> (spatial adaptation, temporal adaptation)."""

FACTORS: tuple[str, str] = ("spatial", "temporal")
"""Names of the two adaptation factors, in the order of :data:`ADAPTATION`'s pairs."""
