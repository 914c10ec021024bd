"""How a model's arrays are written in JSON: the one codec of every saved model's arrays (the
spatial beliefs and MLP weights, the motions a run carries between cycles). Little-endian bytes
in base64 with dtype and shape, so floats round-trip bit for bit and a file stays JSON."""

from __future__ import annotations

import base64
from typing import Any

import numpy as np

from rapidds.errors import StateError

__all__ = ["decode_array", "encode_array"]


def encode_array(a: np.ndarray) -> dict[str, Any]:
    """JSON-safe ``{dtype, shape, data}``: little-endian bytes in base64, so floats round-trip
    bit for bit (float64 beliefs and paths, float32 MLP weights)."""
    a = np.ascontiguousarray(a)
    le = a.astype(a.dtype.newbyteorder("<"), copy=False)
    return {"dtype": le.dtype.str, "shape": list(a.shape),
            "data": base64.b64encode(le.tobytes()).decode("ascii")}


def decode_array(obj: Any, what: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """Inverse of :func:`encode_array`: a finite float array (of ``shape``, if given), or a
    StateError that starts with ``what`` (e.g. ``spatial model: mean``)."""
    try:
        dtype = np.dtype(obj["dtype"])
        if dtype.kind != "f":
            raise ValueError(f"dtype {dtype} is not floating point")
        arr = np.frombuffer(base64.b64decode(obj["data"], validate=True), dtype=dtype)
        arr = arr.reshape([int(n) for n in obj["shape"]]).astype(dtype.newbyteorder("="))
    except (KeyError, TypeError, ValueError) as e:
        raise StateError(f"{what} is not a valid encoded array ({e})") from None
    if shape is not None and arr.shape != shape:
        raise StateError(f"{what} has shape {arr.shape}, expected {shape}")
    if not np.isfinite(arr).all():
        raise StateError(f"{what} contains NaN or infinite values")
    return arr
