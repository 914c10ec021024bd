"""SQLite store for runs: every cycle's plan, observations, costs, arrays and learned model.

One transaction per cycle, so a run killed at any moment holds exactly the cycles that finished,
and ``--resume`` continues from the last one with the human model as it was then. The store is
also what ``rapidds report`` and the ablation study read back.

Many processes may open one store at the same moment (a run and a poll, two runs racing for one
new ``--out``, a study's client and ``rapidds report``):

* A new store is built under a private temporary name (WAL mode, then the schema in one
  transaction) and published with ``os.link``, which fails rather than replace a file that is
  already there. So the file at a store's path is absent or a whole store, never a half-made one;
  when two processes create it at once, one link wins and the other opens the winner's store.
  (This replaces switching a new shared file to WAL: ``PRAGMA journal_mode=WAL`` answers
  SQLITE_BUSY at once, without the busy handler, while another connection holds a lock.)
* Since rapidds never shows an empty file under a store's name, a 0-byte file there is not a
  store and is refused, after waiting for the write lock in case another program (or an older
  rapidds) holds it while initialising the file right now. Any other SQLite database or
  non-SQLite file is refused too. A refused file is only read, never altered.
* A store not yet in WAL mode (an older rapidds's, or one a user switched) is switched with the
  pragma retried on SQLITE_BUSY, with a bounded backoff, until ``timeout``.
* Readers (:meth:`RunStore.open_readonly`) open ``mode=ro``: no DDL, no inserts, no file
  created on a missing path. On a read-only folder without a WAL index (``-shm``) they read the
  file as immutable: no process can be writing it then, since a WAL writer keeps that index.
* A writer may hold the folder lock (``lock_as``, :func:`rapidds.fileio.locked_folder`) for
  as long as the store is open, so two commands never write one folder.
"""

from __future__ import annotations

import errno
import io
import json
import os
import sqlite3
import tempfile
import time
from collections.abc import Iterator, Mapping
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar
from urllib.parse import urlencode

from rapidds.errors import RapiddsError, StateError
from rapidds.fileio import ensure_folder, locked_folder, new_file_mode

if TYPE_CHECKING:  # numpy is imported where arrays are (de)serialised: light commands skip it
    import numpy as np

    from rapidds.record import CycleRecord

SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS runs (
    run_id TEXT PRIMARY KEY,
    created REAL NOT NULL,
    config TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS cycles (
    run_id TEXT NOT NULL REFERENCES runs(run_id),
    cycle INTEGER NOT NULL,
    record TEXT NOT NULL,
    state BLOB,
    created REAL NOT NULL,
    PRIMARY KEY (run_id, cycle)
);
CREATE TABLE IF NOT EXISTS arrays (
    run_id TEXT NOT NULL,
    cycle INTEGER NOT NULL,
    name TEXT NOT NULL,
    data BLOB NOT NULL,
    PRIMARY KEY (run_id, cycle, name),
    FOREIGN KEY (run_id, cycle) REFERENCES cycles(run_id, cycle)
);
"""


PATH_KINDS = ("robot", "human")
"""The agents whose paths a cycle stores, each path as the array ``KIND/TASK``."""


def path_arrays(robot: Mapping[str, np.ndarray], human: Mapping[str, np.ndarray]
                ) -> dict[str, np.ndarray]:
    """A cycle's arrays to store: each robot motion's and each human task's path, by task. The
    one writer of the array names; :func:`cycle_paths` is their one reader."""
    return {f"{kind}/{task}": path for kind, paths in zip(PATH_KINDS, (robot, human), strict=True)
            for task, path in paths.items()}


def cycle_paths(arrays: Mapping[str, np.ndarray]) -> dict[str, dict[str, np.ndarray]]:
    """``{"robot": {task: path}, "human": {task: path}}`` from a cycle's stored arrays (as
    :meth:`RunStore.arrays` returns them); arrays of other names are left out."""
    out: dict[str, dict[str, np.ndarray]] = {kind: {} for kind in PATH_KINDS}
    for name, arr in arrays.items():
        kind, sep, task = name.partition("/")
        if sep and kind in out:
            out[kind][task] = arr
    return out


def _npy(a: np.ndarray) -> bytes:
    import numpy as np

    buf = io.BytesIO()
    np.save(buf, np.asarray(a), allow_pickle=False)
    return buf.getvalue()


def _from_npy(b: bytes) -> np.ndarray:
    import numpy as np

    return np.load(io.BytesIO(b), allow_pickle=False)


_TABLES = frozenset({"meta", "runs", "cycles", "arrays"})
DEFAULT_TIMEOUT = 30.0
"""Seconds a store waits for another process's write lock before giving up."""

# Errors that say the file is not (or no longer) a database rapidds can read.
_NOT_A_STORE = ("SQLITE_NOTADB", "SQLITE_CORRUPT", "SQLITE_ERROR")
# A read-only folder without the WAL index (-shm) that a reader would have to create.
_NO_WAL_INDEX = ("SQLITE_READONLY_DIRECTORY", "SQLITE_READONLY_CANTINIT", "SQLITE_CANTOPEN")
# Filesystems without hard links (FAT, some network shares) answer os.link with one of these.
_NO_HARD_LINKS = {errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.ENOSYS, errno.EMLINK}


def _errname(exc: sqlite3.Error) -> str:
    return getattr(exc, "sqlite_errorname", "") or ""


def _busy(exc: sqlite3.Error) -> bool:
    return _errname(exc).startswith(("SQLITE_BUSY", "SQLITE_LOCKED"))


def _uri(path: Path, **params: str) -> str:
    """A SQLite URI of ``path``: as_uri percent-encodes '?', '#' and '%' in the name."""
    return f"{path.absolute().as_uri()}?{urlencode(params)}"


def _dumps(obj: Any) -> str:
    """JSON without NaN or Infinity: a non-finite result is a bug to see, not a value to keep."""
    return json.dumps(obj, allow_nan=False)


class RunStore:
    """A SQLite file holding one or many runs (an ablation study keeps all its trials in one).

    ``RunStore(path)`` creates the store (and its folder) or opens it for writing;
    :meth:`open_readonly` opens an existing one for reading only. ``timeout``: seconds to wait
    for another process's write lock (opening and every transaction), then StateError.
    ``lock_as``: hold ``path.parent/.lock`` while the store is open, refusing a second writer
    of the folder with "another {lock_as} is writing ...".
    """

    KIND: ClassVar[str] = "run store"
    """What the store is called in messages."""
    EXTRA_SCHEMA: ClassVar[str] = ""
    """SQL a subclass adds to a new store, in the transaction that creates it."""
    TABLES: ClassVar[frozenset[str]] = _TABLES
    """Tables an existing store must have to be opened as this kind."""

    def __init__(self, path: str | Path, *, readonly: bool = False,
                 timeout: float = DEFAULT_TIMEOUT, lock_as: str | None = None):
        self.path = Path(path)
        self.readonly = readonly
        self.timeout = float(timeout)
        self._held = ExitStack()
        try:
            if lock_as is not None:
                self._held.enter_context(locked_folder(self.path.parent, lock_as))
            try:
                self._db = self._open_readonly() if readonly else self._open_for_writing()
            except sqlite3.Error as exc:
                raise self._failure(exc) from None
        except BaseException:
            self._held.close()
            raise

    @classmethod
    def open_readonly(cls, path: str | Path, *, timeout: float = DEFAULT_TIMEOUT) -> RunStore:
        """An existing store, for reading: never creates, alters or initialises a file, and
        works on read-only media. A missing file is a StateError."""
        return cls(path, readonly=True, timeout=timeout)

    # opening --------------------------------------------------------------------------------
    def _connect(self, **params: str) -> sqlite3.Connection:
        return sqlite3.connect(_uri(self.path, **params), uri=True, timeout=self.timeout,
                               isolation_level=None)

    def _failure(self, exc: sqlite3.Error) -> StateError:
        """One line for what went wrong talking to SQLite."""
        name = _errname(exc)
        if _busy(exc):
            return StateError(f"{self.path}: locked by another process for more than "
                              f"{self.timeout:g} s; try again when it has finished")
        if name.startswith(_NOT_A_STORE):
            return StateError(f"{self.path}: not a rapidds {self.KIND} ({exc})")
        if name.startswith("SQLITE_CANTOPEN"):
            return StateError(f"{self.path}: cannot open the {self.KIND} ({exc})")
        if name.startswith(("SQLITE_READONLY", "SQLITE_FULL", "SQLITE_IOERR")):
            return StateError(f"{self.path}: cannot write the {self.KIND} ({exc})")
        return StateError(f"{self.path}: {self.KIND} error ({name or type(exc).__name__}: {exc})")

    def _open_for_writing(self) -> sqlite3.Connection:
        deadline = time.monotonic() + self.timeout
        ensure_folder(self.path.parent)
        if not os.path.lexists(self.path):
            self._publish_new()
        db = self._connect(mode="rw")  # never creates: a file gone meanwhile is an error
        try:
            if self._inspect(db) is None:
                # An empty database: another program (or an older rapidds) may have created the
                # file and be writing its schema right now. Wait for its write lock and look
                # again; still empty means it is simply not a store.
                db.execute("BEGIN IMMEDIATE")
                try:
                    found = self._inspect(db)
                finally:
                    db.execute("ROLLBACK")
                if found is None:
                    raise StateError(f"{self.path}: an empty file, not a rapidds {self.KIND}; "
                                     "remove it or choose another path")
            self._ensure_wal(db, deadline)
            db.execute("PRAGMA synchronous=FULL")
            db.execute("PRAGMA foreign_keys=ON")
        except BaseException:
            db.close()
            raise
        return db

    def _open_readonly(self) -> sqlite3.Connection:
        if not self.path.exists():
            raise StateError(f"{self.path}: no such {self.KIND}")
        if not self.path.is_file():
            raise StateError(f"{self.path}: not a file, so not a rapidds {self.KIND}")
        db = self._connect(mode="ro")
        try:
            found = self._inspect(db)
        except sqlite3.OperationalError as exc:
            if not _errname(exc).startswith(_NO_WAL_INDEX):
                db.close()
                raise
            # A read-only folder without the WAL index: no writer has the store open (a WAL
            # writer keeps its -shm there), so reading the file as immutable is exact.
            db.close()
            db = self._connect(mode="ro", immutable="1")
            try:
                found = self._inspect(db)
            except BaseException:
                db.close()
                raise
        except BaseException:
            db.close()
            raise
        if found is None:
            db.close()
            raise StateError(f"{self.path}: an empty file, not a rapidds {self.KIND}")
        return db

    def _inspect(self, db: sqlite3.Connection) -> int | None:
        """The store's schema version; None for an empty database; StateError for a file that
        is not a rapidds store. Only reads."""
        try:
            tables = {r[0] for r in db.execute(
                "SELECT name FROM sqlite_master WHERE type='table'").fetchall()}
            if not tables:
                return None
            if not tables >= self.TABLES:
                shown = ", ".join(sorted(tables)[:6]) + (", ..." if len(tables) > 6 else "")
                raise StateError(f"{self.path}: not a rapidds {self.KIND} (an SQLite database "
                                 f"with tables {shown})")
            row = db.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
        except sqlite3.DatabaseError as exc:
            if _errname(exc).startswith(_NOT_A_STORE):
                raise StateError(f"{self.path}: not a rapidds {self.KIND} ({exc})") from None
            raise
        if row is None or not str(row[0]).isdigit():
            raise StateError(f"{self.path}: not a rapidds {self.KIND} (no schema version)")
        if int(row[0]) != SCHEMA_VERSION:
            raise StateError(
                f"{self.path}: store schema {row[0]}, this rapidds reads {SCHEMA_VERSION}"
            )
        self._check_kind(db)
        return int(row[0])

    def _check_kind(self, db: sqlite3.Connection) -> None:
        """A subclass's check that the store is its kind (StateError if not); only reads."""

    def _ensure_wal(self, db: sqlite3.Connection, deadline: float) -> None:
        """Switch to WAL (readers never wait for the writer). The pragma needs an exclusive
        lock and answers SQLITE_BUSY at once, without the busy handler, while anyone else holds
        a lock, so it is retried with a growing pause until the deadline."""
        if db.execute("PRAGMA journal_mode").fetchone()[0].lower() == "wal":
            return
        pause = 0.001
        while True:
            try:
                mode = db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
                break
            except sqlite3.OperationalError as exc:
                left = deadline - time.monotonic()
                if not _busy(exc) or left <= 0:
                    raise
                time.sleep(min(pause, left))
                pause = min(2 * pause, 0.05)
        if mode.lower() != "wal":
            raise StateError(f"{self.path}: cannot use the WAL journal here (SQLite kept "
                             f"'{mode}'); put the store on a local disk")

    def _publish_new(self) -> None:
        """Build a whole store under a private name and link it into place (see the module
        docstring); a store another process linked first wins and this one is discarded."""
        fd, name = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.name}.",
                                    suffix=".new")
        os.close(fd)
        tmp = Path(name)
        try:
            os.chmod(tmp, new_file_mode())
            db = sqlite3.connect(tmp, isolation_level=None)
            try:
                db.execute("PRAGMA journal_mode=WAL")
                db.executescript(f"BEGIN IMMEDIATE; {_SCHEMA} {self.EXTRA_SCHEMA} "
                                 f"INSERT INTO meta VALUES ('schema', '{SCHEMA_VERSION}'); "
                                 "COMMIT;")
            finally:
                db.close()  # checkpoints: the whole store is in the file now
            try:
                os.link(tmp, self.path)
            except FileExistsError:
                pass  # another process published its store first: open that one
            except OSError as exc:
                if exc.errno not in _NO_HARD_LINKS:
                    raise
                self._publish_by_copy(tmp)
        finally:
            for p in (tmp, Path(f"{tmp}-wal"), Path(f"{tmp}-shm")):
                p.unlink(missing_ok=True)

    def _publish_by_copy(self, tmp: Path) -> None:
        """Without hard links: create the name exclusively and copy. A process opening the store
        during the copy may find it incomplete and be refused; it can simply retry."""
        try:
            fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, new_file_mode())
        except FileExistsError:
            return
        with os.fdopen(fd, "wb") as f:
            f.write(tmp.read_bytes())
            f.flush()
            os.fsync(f.fileno())

    def close(self) -> None:
        try:
            self._db.close()
        finally:
            self._held.close()

    def __enter__(self) -> RunStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        """One write transaction, taken up front (BEGIN IMMEDIATE waits for another writer up to
        ``timeout``); SQLite's failures (locked, disk full, read-only) become StateError."""
        if self.readonly:
            raise StateError(f"{self.path} was opened read-only")
        try:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._db
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            self._db.execute("COMMIT")
        except sqlite3.IntegrityError:
            raise
        except sqlite3.Error as exc:
            raise self._failure(exc) from None

    def _rows(self, sql: str, args: tuple[Any, ...] = ()) -> list[Any]:
        try:
            return self._db.execute(sql, args).fetchall()
        except sqlite3.Error as exc:
            raise self._failure(exc) from None

    def _json(self, text: str, what: str) -> Any:
        try:
            return json.loads(text)
        except (TypeError, ValueError) as exc:
            raise StateError(f"{self.path}: corrupt stored JSON in {what} ({exc})") from None

    # runs -----------------------------------------------------------------------------------
    def _register(self, db: sqlite3.Connection, run_id: str, config: dict[str, Any]) -> None:
        """Insert the run, or check that the stored one has these settings; inside a
        transaction, so two processes registering one run at once cannot both insert."""
        cfg_json = _dumps(config)
        db.execute("INSERT INTO runs VALUES (?, ?, ?) ON CONFLICT (run_id) DO NOTHING",
                   (run_id, time.time(), cfg_json))
        (stored,) = db.execute("SELECT config FROM runs WHERE run_id=?", (run_id,)).fetchone()
        if self._json(stored, f"run '{run_id}'") != json.loads(cfg_json):
            raise StateError(
                f"run '{run_id}' already exists in {self.path} with other settings; "
                "use another --out or the same settings"
            )

    def create_run(self, run_id: str, config: dict[str, Any]) -> None:
        """Register a run. Re-creating an existing run with a different config is refused, so a
        resumed run cannot silently continue under other settings. One transaction: two
        processes creating one run at once both succeed (same settings) or one is refused."""
        with self._tx() as db:
            self._register(db, run_id, config)

    def run_config(self, run_id: str) -> dict[str, Any] | None:
        rows = self._rows("SELECT config FROM runs WHERE run_id=?", (run_id,))
        return self._json(rows[0][0], f"run '{run_id}'") if rows else None

    def run_created(self, run_id: str) -> float | None:
        """Wall-clock seconds (Unix time) at which the run was first stored, or None."""
        rows = self._rows("SELECT created FROM runs WHERE run_id=?", (run_id,))
        return float(rows[0][0]) if rows else None

    def run_ids(self) -> list[str]:
        return [r[0] for r in self._rows("SELECT run_id FROM runs ORDER BY run_id")]

    def pick_run(self, run_id: str | None) -> str:
        """The run a command means: ``run_id`` (checked), or the store's only run; a
        RapiddsError naming the runs (and ``--run``) otherwise."""
        ids = self.run_ids()
        if run_id is not None:
            if run_id not in ids:
                raise RapiddsError(f"{self.path} has no run '{run_id}' (runs: "
                                   f"{', '.join(ids) or 'none'})")
            return run_id
        if len(ids) != 1:
            raise RapiddsError(f"{self.path} holds {len(ids)} runs ({', '.join(ids) or 'none'}); "
                               "name one with --run")
        return str(ids[0])

    # cycles ---------------------------------------------------------------------------------
    def record_cycle(
        self,
        run_id: str,
        cycle: int,
        record: dict[str, Any],
        arrays: dict[str, np.ndarray] | None = None,
        state: bytes | None = None,
    ) -> None:
        """Write one finished cycle atomically: its record, arrays and the model state after it.
        Writing a cycle twice is refused rather than duplicated."""
        try:
            with self._tx() as db:
                self._before_cycle(db, run_id, cycle)
                db.execute(
                    "INSERT INTO cycles VALUES (?, ?, ?, ?, ?)",
                    (run_id, cycle, _dumps(record), state, time.time()),
                )
                db.executemany(
                    "INSERT INTO arrays VALUES (?, ?, ?, ?)",
                    [(run_id, cycle, k, _npy(v)) for k, v in (arrays or {}).items()],
                )
        except sqlite3.IntegrityError:
            raise StateError(f"run '{run_id}' already has cycle {cycle}") from None

    def _before_cycle(self, db: sqlite3.Connection, run_id: str, cycle: int) -> None:
        """A subclass's check, inside :meth:`record_cycle`'s transaction, that the cycle may be
        written now (StateError if not)."""

    def record_trial(
        self, run_id: str, config: dict[str, Any], records: list[dict[str, Any]]
    ) -> bool:
        """Register a run and write all its cycle records in ONE transaction, so a study's trial
        (computed elsewhere, e.g. on a Dask worker) is stored whole or not at all.

        Storing the same trial again (a task Dask re-ran after a worker died, a second client)
        changes nothing and returns False; True when this call wrote it. A run stored under
        other settings, or partly stored by :meth:`record_cycle`, is refused.
        """
        if not records:
            raise ValueError(f"trial '{run_id}' has no cycle records")
        with self._tx() as db:
            self._register(db, run_id, config)
            (have,) = db.execute(
                "SELECT COUNT(*) FROM cycles WHERE run_id=?", (run_id,)
            ).fetchone()
            if have == len(records):
                return False
            if have:
                raise StateError(
                    f"run '{run_id}' has {have} of {len(records)} cycles stored; "
                    "a whole trial cannot be written over a partial run"
                )
            now = time.time()
            db.executemany(
                "INSERT INTO cycles VALUES (?, ?, ?, NULL, ?)",
                [(run_id, int(r["cycle"]), _dumps(r), now) for r in records],
            )
            db.execute("DELETE FROM meta WHERE key=?", (self._FAILED + run_id,))
        return True

    _POLICY: ClassVar[str] = "policy:"  # meta keys: the network a run plans with

    def claim_policy(self, run_id: str, fingerprint: str) -> None:
        """Keep that ``run_id`` plans with the network ``fingerprint`` names; StateError, one
        line, when the run planned with another. A run stored before runs kept theirs takes the
        first network it resumes with. One transaction."""
        with self._tx() as db:
            db.execute("INSERT INTO meta VALUES (?, ?) ON CONFLICT (key) DO NOTHING",
                       (self._POLICY + run_id, fingerprint))
            (stored,) = db.execute("SELECT value FROM meta WHERE key=?",
                                   (self._POLICY + run_id,)).fetchone()
        if stored != fingerprint:
            raise StateError(f"run '{run_id}' in {self.path} planned with another network "
                             f"(fingerprint {stored}, this one {fingerprint}); resume it with "
                             "the --policy it began with, or use another --out")

    # failed trials ------------------------------------------------------------------------
    _FAILED: ClassVar[str] = "failed:"  # meta keys: every store has the table; old: none

    def record_failure(self, run_id: str, config: dict[str, Any], reason: str) -> None:
        """Keep that a study's trial failed and why (its cycles are not stored); a later
        :meth:`record_trial` of the same run, which succeeded, clears it."""
        entry = _dumps({"config": config, "reason": reason, "created": time.time()})
        with self._tx() as db:
            db.execute("INSERT INTO meta VALUES (?, ?) ON CONFLICT (key) DO UPDATE SET "
                       "value=excluded.value", (self._FAILED + run_id, entry))

    def failures(self) -> dict[str, dict[str, Any]]:
        """run_id -> {"config", "reason", "created"} of every trial kept as failed."""
        rows = self._rows("SELECT key, value FROM meta WHERE key >= ? AND key < ? ORDER BY key",
                          (self._FAILED, self._FAILED[:-1] + ";"))
        return {k[len(self._FAILED):]: self._json(v, f"failure of '{k}'") for k, v in rows}

    def last_cycle(self, run_id: str) -> int | None:
        (last,) = self._rows("SELECT MAX(cycle) FROM cycles WHERE run_id=?", (run_id,))[0]
        return None if last is None else int(last)

    def records(self, run_id: str | None = None) -> list[dict[str, Any]]:
        """Cycle records in order; each gains ``run_id`` and ``cycle``."""
        sql = "SELECT run_id, cycle, record FROM cycles"
        args: tuple[Any, ...] = ()
        if run_id is not None:
            sql += " WHERE run_id=?"
            args = (run_id,)
        out = []
        for rid, cyc, rec in self._rows(sql + " ORDER BY run_id, cycle", args):
            d = self._json(rec, f"run '{rid}' cycle {cyc}")
            if not isinstance(d, dict):
                raise StateError(f"{self.path}: corrupt stored JSON in run '{rid}' cycle {cyc} "
                                 f"(a {type(d).__name__}, not an object)")
            d.update(run_id=rid, cycle=cyc)
            out.append(d)
        return out

    def cycle_records(self, run_id: str | None = None) -> list[CycleRecord]:
        """:meth:`records`, typed (StateError naming the cycle if one is not a cycle record)."""
        from rapidds.record import CycleRecord  # its schedule items need numpy: see above

        out = []
        for d in self.records(run_id):
            try:
                out.append(CycleRecord.from_json(d))
            except StateError as exc:
                raise StateError(f"{self.path}: run '{d['run_id']}' cycle {d['cycle']}: "
                                 f"{exc}") from None
        return out

    def state(self, run_id: str, cycle: int) -> bytes | None:
        rows = self._rows("SELECT state FROM cycles WHERE run_id=? AND cycle=?", (run_id, cycle))
        if not rows:
            raise StateError(f"run '{run_id}' has no cycle {cycle}")
        return rows[0][0]

    def arrays(self, run_id: str, cycle: int) -> dict[str, np.ndarray]:
        rows = self._rows(
            "SELECT name, data FROM arrays WHERE run_id=? AND cycle=? ORDER BY name",
            (run_id, cycle),
        )
        try:
            return {name: _from_npy(data) for name, data in rows}
        except (TypeError, ValueError, OSError) as exc:
            raise StateError(f"{self.path}: corrupt stored array in run '{run_id}' cycle "
                             f"{cycle} ({exc})") from None
