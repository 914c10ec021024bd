"""A content-addressed cache of deterministic arrays across runs (issue 36 item 5).

Some artefacts cost seconds and are the same in every run that asks for them: the population
prior's spatial model, a simulated person's true spatial model. Each entry is one ``.npz`` file
named by the SHA-256 of everything its arrays depend on (the inputs' bytes, the settings, the
source of the code that builds them, the numpy version), so a changed input or a changed
builder is a miss, never a stale hit, and the arrays read back are the bits that were built.

Where: ``$RAPIDDS_CACHE`` (a folder, or ``off`` to build everything anew), else
``$XDG_CACHE_HOME/rapidds``, else ``~/.cache/rapidds``. Entries are written atomically (a
temporary file renamed into place), so two processes building one entry at once both write the
same bits and a reader never sees half a file. A corrupt or unreadable entry is rebuilt with
one warning line; a cache folder that cannot be written is skipped (one warning line per
process), never an error: the cache only ever saves time.
"""

from __future__ import annotations

import hashlib
import io
import logging
import os
import zipfile
from collections.abc import Callable, Iterable
from functools import cache
from pathlib import Path

import numpy as np

from rapidds.errors import RapiddsError
from rapidds.fileio import atomic_write_bytes

__all__ = ["cache_dir", "cached_arrays", "code_version", "content_key"]

log = logging.getLogger("rapidds.cache")
ENV = "RAPIDDS_CACHE"
OFF = ("off", "0", "no", "false")
_unwritable: set[Path] = set()


def cache_dir() -> Path | None:
    """The cache folder the environment names (None: caching is off)."""
    env = os.environ.get(ENV)
    if env is not None:
        return None if env.strip().lower() in OFF or not env.strip() else Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return base / "rapidds"


@cache
def code_version(*files: str) -> str:
    """SHA-256 of the source files that build an artefact (and numpy's version, whose SIMD
    kernels may round differently): part of every key, so editing the builder is a miss."""
    h = hashlib.sha256(np.__version__.encode())
    for f in files:
        h.update(Path(f).read_bytes())
    return h.hexdigest()


def content_key(*parts: object) -> str:
    """SHA-256 over ``parts``: arrays by dtype, shape and bytes; anything else by ``repr``
    (floats by their shortest round-trip text, so equal settings give equal keys)."""
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(repr(p).encode())
        h.update(b"\x00")
    return h.hexdigest()


def _read(path: Path, names: Iterable[str]) -> dict[str, np.ndarray] | None:
    """The entry's arrays, None when there is none; raises on a corrupt one."""
    try:
        data = path.read_bytes()
    except (FileNotFoundError, NotADirectoryError):
        return None
    with np.load(io.BytesIO(data), allow_pickle=False) as z:  # zip CRCs catch damaged bytes
        arrays = {k: z[k] for k in z.files}
    if set(arrays) != set(names):
        raise ValueError(f"holds {sorted(arrays)}, expected {sorted(names)}")
    return arrays


def cached_arrays(kind: str, key: str, names: tuple[str, ...],
                  build: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The arrays ``build()`` returns (named ``names``), read from the cache entry ``key`` of
    ``kind`` when there is one, built and stored otherwise."""
    folder = cache_dir()
    if folder is None:
        return build()
    path = folder / kind / f"{key}.npz"
    try:
        hit = _read(path, names)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        log.warning("rapidds: cache entry %s is corrupt or unreadable (%s); rebuilding it",
                    path, exc)
        hit = None
    if hit is not None:
        return hit
    arrays = build()
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    try:
        atomic_write_bytes(path, buf.getvalue())
    except (OSError, RapiddsError) as exc:  # an unwritable cache only costs time
        if folder not in _unwritable:
            _unwritable.add(folder)
            log.warning("rapidds: cannot write the cache in %s (%s); building without it "
                        "(set %s=off to silence)", folder, exc, ENV)
    return arrays
