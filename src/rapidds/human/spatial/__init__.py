"""Individual spatial cost model: where this person is while doing each task (paper, "Spatial
Adaptation", Eqs. 7-11).

For a robot point x and one human path xi_h the point cost is
s(x, xi_h) = max_{x_h in xi_h} exp(-beta ||x_h - x||) (Eq. 7; by default the max runs over the
piecewise-linear path through the samples, see ``SpatialConfig.polyline``). For every human task
the model keeps, at the V points of a regular grid over the workspace, a Gaussian belief about
this person's expected point cost s*(x) (Eq. 8): its prior is the population average (Eq. 9),
and every observed path of the person updates it by the conjugate Normal rule with observation
variance rho (Eqs. 10-11). Between grid points the cost is either a small MLP fitted to the
posterior mean (the paper's choice) or exact multilinear interpolation of the grid (the
reference the MLP is held against, and the default). The cost of a robot trajectory is the
maximum over its points, the paper's S_i(xi), and a set of concurrent human tasks costs the
maximum over the tasks.

Storage: :meth:`SpatialModel.to_dict` is JSON-safe (arrays as little-endian base64 with dtype
and shape, so float64 beliefs and float32 MLP weights round-trip bit for bit);
:meth:`SpatialModel.save` writes that dict as JSON with a SHA-256 of its body, atomically.

The package's parts: :mod:`.config` (the settings), :mod:`.path_cost` (Eq. 7), :mod:`.grid`
(the belief of one task), :mod:`.surrogate` (the MLP, torch's autograd) and :mod:`.model` (a
person's beliefs for all tasks, saved and loaded; arrays in :mod:`rapidds.codec`). Names are
imported on first use, so reading a config does not load torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rapidds.lazy import submodule_attributes

if TYPE_CHECKING:
    from rapidds.human.spatial.config import SpatialConfig
    from rapidds.human.spatial.grid import SpatialCostModel
    from rapidds.human.spatial.model import FORMAT, FORMAT_VERSION, SpatialModel
    from rapidds.human.spatial.path_cost import point_cost
    from rapidds.human.spatial.surrogate import FitReport, SurrogateError

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "FitReport",
    "SpatialConfig",
    "SpatialCostModel",
    "SpatialModel",
    "SurrogateError",
    "point_cost",
]

__getattr__ = submodule_attributes(__name__, {
    "FORMAT": "model", "FORMAT_VERSION": "model", "SpatialModel": "model",
    "FitReport": "surrogate", "SurrogateError": "surrogate", "SpatialConfig": "config",
    "SpatialCostModel": "grid", "point_cost": "path_cost",
})
