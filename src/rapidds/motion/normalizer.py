"""Per-dimension min-max normalisation of trajectories to [-1, 1].

The diffusion model works in [-1, 1] (sample clipping assumes it); value functions and users see
the world's units. The fitted bounds travel inside the checkpoint so a loaded policy maps back
exactly as the trained one did.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, TypeVar

import numpy as np
import torch

ArrayT = TypeVar("ArrayT", np.ndarray, torch.Tensor)

# Ranges below this are treated as constant: the dimension maps to 0 and back to its value.
_EPS = 1e-8


class MinMaxNormalizer:
    """x_n = (x - centre) / half_range per state dimension; constant dimensions map to 0.

    ``low``, ``high``: (d,) bounds fitted on demonstration points. Stored as float64 so a
    JSON round trip is exact.
    """

    def __init__(self, low: np.ndarray, high: np.ndarray):
        low = np.asarray(low, dtype=np.float64)
        high = np.asarray(high, dtype=np.float64)
        if low.ndim != 1 or low.shape != high.shape or low.size == 0:
            raise ValueError(f"low and high must be equal (d,) vectors, got {low.shape} and "
                             f"{high.shape}")
        if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
            raise ValueError("normaliser bounds must be finite")
        if np.any(high < low):
            raise ValueError("normaliser needs high >= low in every dimension")
        self.low = low
        self.high = high
        self.centre = (high + low) / 2
        half = (high - low) / 2
        self.half_range = np.where(half < _EPS, 1.0, half)
        self._tensors: dict[tuple[torch.device, torch.dtype],
                            tuple[torch.Tensor, torch.Tensor]] = {}

    @classmethod
    def fit(cls, points: np.ndarray) -> MinMaxNormalizer:
        """Bounds of ``points`` (..., d), e.g. demonstrations (N, H, d)."""
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim < 1 or pts.shape[-1] == 0 or pts.size == 0:
            raise ValueError(f"cannot fit a normaliser on an array of shape {pts.shape}")
        flat = pts.reshape(-1, pts.shape[-1])
        return cls(flat.min(axis=0), flat.max(axis=0))

    @property
    def dim(self) -> int:
        return int(self.low.shape[0])

    def _params(self, like: ArrayT) -> tuple[Any, Any]:
        if isinstance(like, torch.Tensor):
            # kept per (device, dtype): a copy to a GPU on every call would stall the steering
            key = (like.device, like.dtype)
            if key not in self._tensors:
                self._tensors[key] = (
                    torch.as_tensor(self.centre, dtype=like.dtype, device=like.device),
                    torch.as_tensor(self.half_range, dtype=like.dtype, device=like.device))
            return self._tensors[key]
        return self.centre, self.half_range

    def _check(self, x: ArrayT) -> None:
        if x.shape[-1] != self.dim:
            raise ValueError(f"normaliser fitted on d={self.dim}, got last dimension "
                             f"{x.shape[-1]}")

    def normalize(self, x: ArrayT) -> ArrayT:
        """(..., d) world units -> (..., d) in [-1, 1] (on the fitted range)."""
        self._check(x)
        c, h = self._params(x)
        return (x - c) / h

    def unnormalize(self, x: ArrayT) -> ArrayT:
        """(..., d) normalised -> (..., d) world units."""
        self._check(x)
        c, h = self._params(x)
        return x * h + c

    def state_dict(self) -> dict[str, list[float]]:
        return {"low": self.low.tolist(), "high": self.high.tolist()}

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Any]) -> MinMaxNormalizer:
        try:
            return cls(np.asarray(state["low"], dtype=np.float64),
                       np.asarray(state["high"], dtype=np.float64))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"normaliser state needs numeric 'low' and 'high' lists ({exc})") \
                from exc

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Replace this normaliser's bounds with ``state`` (as saved by :meth:`state_dict`)."""
        other = self.from_state_dict(state)
        self.__dict__.update(other.__dict__)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, MinMaxNormalizer):
            return NotImplemented
        return np.array_equal(self.low, other.low) and np.array_equal(self.high, other.high)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"MinMaxNormalizer(low={self.low.tolist()}, high={self.high.tolist()})"
