"""Atomic file writes (a crash leaves either the old file or the new one, never half of one) and
the folder lock that keeps two writers out of one output folder."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from rapidds.errors import RapiddsError

LOCK_NAME = ".lock"


def new_file_mode() -> int:
    """The permission bits a plain ``open(path, "w")`` would give a new file (0666 less the
    umask): files made under a temporary name (mkstemp makes them 0600) get them before they are
    renamed or linked into place."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def ensure_folder(path: str | Path) -> Path:
    """``mkdir -p``, with one clear line when a file stands where a folder must be."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise RapiddsError(f"{path} exists and is not a folder") from None
    except NotADirectoryError:
        raise RapiddsError(f"cannot make folder {path}: part of that path is a file") from None
    return path


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write via a temporary file in the same folder and rename; permissions follow the umask
    like any other new file (mkstemp alone would leave them 0600)."""
    path = Path(path)
    ensure_folder(path.parent)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, new_file_mode())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


@contextmanager
def locked_folder(folder: str | Path, what: str) -> Iterator[Path]:
    """Hold ``folder/.lock`` exclusively (created with the folder if missing) while the block runs,
    so two commands never write one folder; a second one stops at once with "another {what} is
    writing {folder}". An flock dies with its process, so a killed run never leaves a stale lock
    behind. The lock file is the only file this creates; it is left in place (deleting it would
    let a third process lock a fresh inode while the second still holds the old one)."""
    folder = ensure_folder(folder)
    # "a", not "w": taking the lock must not truncate (change) a file another process holds.
    with open(folder / LOCK_NAME, "a") as lock:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: no lock
            yield folder
            return
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RapiddsError(f"another {what} is writing {folder}") from None
        yield folder
