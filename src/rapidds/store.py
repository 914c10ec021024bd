"""SQLite store for runs: every cycle's plan, observations, costs, arrays and learned model.

One transaction per cycle, so a run killed at any moment holds exactly the cycles that finished,
and ``--resume`` continues from the last one with the human model as it was then. The store is
also what ``rapidds report`` and the ablation study read back.
"""

from __future__ import annotations

import io
import json
import sqlite3
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from rapidds.errors import StateError

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


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.asarray(a), allow_pickle=False)
    return buf.getvalue()


def _from_npy(b: bytes) -> np.ndarray:
    return np.load(io.BytesIO(b), allow_pickle=False)


class RunStore:
    """A SQLite file holding one or many runs (an ablation study keeps all its trials in one)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._db = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._db.executescript(_SCHEMA)
            # Two processes may open a new store at once (a run and a reader): first one wins.
            self._db.execute(
                "INSERT OR IGNORE INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),)
            )
            row = self._db.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
        except sqlite3.DatabaseError as exc:
            raise StateError(f"{self.path}: not a rapidds run store ({exc})") from None
        if int(row[0]) != SCHEMA_VERSION:
            raise StateError(
                f"{self.path}: store schema {row[0]}, this rapidds reads {SCHEMA_VERSION}"
            )

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> RunStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        self._db.execute("BEGIN IMMEDIATE")
        try:
            yield self._db
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._db.execute("COMMIT")

    # runs -----------------------------------------------------------------------------------
    def create_run(self, run_id: str, config: dict[str, Any]) -> None:
        """Register a run. Re-creating an existing run with a different config is refused, so a
        resumed run cannot silently continue under other settings."""
        existing = self.run_config(run_id)
        if existing is not None:
            if existing != json.loads(json.dumps(config)):
                raise StateError(
                    f"run '{run_id}' already exists in {self.path} with other settings; "
                    "use another --out or the same settings"
                )
            return
        with self._tx() as db:
            db.execute(
                "INSERT INTO runs VALUES (?, ?, ?)", (run_id, time.time(), json.dumps(config))
            )

    def run_config(self, run_id: str) -> dict[str, Any] | None:
        row = self._db.execute("SELECT config FROM runs WHERE run_id=?", (run_id,)).fetchone()
        return None if row is None else json.loads(row[0])

    def run_ids(self) -> list[str]:
        return [r[0] for r in self._db.execute("SELECT run_id FROM runs ORDER BY run_id")]

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
                db.execute(
                    "INSERT INTO cycles VALUES (?, ?, ?, ?, ?)",
                    (run_id, cycle, json.dumps(record), state, time.time()),
                )
                db.executemany(
                    "INSERT INTO arrays VALUES (?, ?, ?, ?)",
                    [(run_id, cycle, k, _npy(v)) for k, v in (arrays or {}).items()],
                )
        except sqlite3.IntegrityError:
            raise StateError(f"run '{run_id}' already has cycle {cycle}") from None

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
        cfg_json = json.dumps(config)
        with self._tx() as db:
            row = db.execute("SELECT config FROM runs WHERE run_id=?", (run_id,)).fetchone()
            if row is None:
                db.execute("INSERT INTO runs VALUES (?, ?, ?)", (run_id, time.time(), cfg_json))
            elif json.loads(row[0]) != json.loads(cfg_json):
                raise StateError(
                    f"run '{run_id}' already exists in {self.path} with other settings; "
                    "use another --out or the same settings"
                )
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
                [(run_id, int(r["cycle"]), json.dumps(r), now) for r in records],
            )
        return True

    def last_cycle(self, run_id: str) -> int | None:
        row = self._db.execute("SELECT MAX(cycle) FROM cycles WHERE run_id=?", (run_id,)).fetchone()
        return None if row[0] is None else int(row[0])

    def records(self, run_id: str | None = None) -> list[dict[str, Any]]:
        """Cycle records in order; each gains ``run_id`` and ``cycle``."""
        sql = "SELECT run_id, cycle, record FROM cycles"
        args: tuple[Any, ...] = ()
        if run_id is not None:
            sql += " WHERE run_id=?"
            args = (run_id,)
        out = []
        for rid, cyc, rec in self._db.execute(sql + " ORDER BY run_id, cycle", args):
            d = json.loads(rec)
            d.update(run_id=rid, cycle=cyc)
            out.append(d)
        return out

    def state(self, run_id: str, cycle: int) -> bytes | None:
        row = self._db.execute(
            "SELECT state FROM cycles WHERE run_id=? AND cycle=?", (run_id, cycle)
        ).fetchone()
        if row is None:
            raise StateError(f"run '{run_id}' has no cycle {cycle}")
        return row[0]

    def arrays(self, run_id: str, cycle: int) -> dict[str, np.ndarray]:
        rows = self._db.execute(
            "SELECT name, data FROM arrays WHERE run_id=? AND cycle=? ORDER BY name",
            (run_id, cycle),
        )
        return {name: _from_npy(data) for name, data in rows}
