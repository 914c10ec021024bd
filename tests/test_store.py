import errno
import hashlib
import multiprocessing as mp
import os
import shutil
import sqlite3
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from rapidds.errors import RapiddsError, StateError
from rapidds.fileio import atomic_write_text, locked_folder
from rapidds.store import _SCHEMA, SCHEMA_VERSION, RunStore


def test_cycle_round_trip_and_order(tmp_path):
    with RunStore(tmp_path / "runs.sqlite") as st:
        st.create_run("a", {"seed": 1})
        traj = np.arange(12.0).reshape(3, 2, 2)
        st.record_cycle("a", 1, {"cost": 2.0}, {"traj": traj}, state=b"s1")
        st.record_cycle("a", 0, {"cost": 3.0}, state=b"s0")
        assert st.last_cycle("a") == 1
        assert [r["cost"] for r in st.records("a")] == [3.0, 2.0]
        assert st.state("a", 1) == b"s1"
        np.testing.assert_array_equal(st.arrays("a", 1)["traj"], traj)
        assert st.arrays("a", 0) == {}
    # persisted across connections
    with RunStore(tmp_path / "runs.sqlite") as st:
        assert st.run_ids() == ["a"]
        assert st.last_cycle("a") == 1
        assert st.last_cycle("missing") is None


def test_duplicate_cycle_refused_and_nothing_half_written(tmp_path):
    with RunStore(tmp_path / "r.sqlite") as st:
        st.create_run("a", {})
        st.record_cycle("a", 0, {"x": 1}, {"t": np.zeros(2)})
        with pytest.raises(StateError, match="already has cycle 0"):
            st.record_cycle("a", 0, {"x": 2}, {"t": np.ones(2)})
        assert [r["x"] for r in st.records("a")] == [1]
        np.testing.assert_array_equal(st.arrays("a", 0)["t"], np.zeros(2))


def test_failed_transaction_rolls_back(tmp_path):
    with RunStore(tmp_path / "r.sqlite") as st:
        st.create_run("a", {})
        with pytest.raises(TypeError):
            st.record_cycle("a", 0, {"x": object()})  # not JSON: fails inside the transaction
        assert st.records("a") == []
        assert st.last_cycle("a") is None


def test_run_config_mismatch_refused(tmp_path):
    with RunStore(tmp_path / "r.sqlite") as st:
        st.create_run("a", {"seed": 0, "cycles": 4})
        st.create_run("a", {"seed": 0, "cycles": 4})  # same settings: fine (resume)
        with pytest.raises(StateError, match="other settings"):
            st.create_run("a", {"seed": 1, "cycles": 4})


def test_corrupt_store_clear_error(tmp_path):
    bad = tmp_path / "bad.sqlite"
    bad.write_bytes(b"this is not sqlite at all" * 100)
    with pytest.raises(StateError, match="not a rapidds run store"):
        RunStore(bad)


def test_atomic_write_replaces_whole_file(tmp_path):
    p = tmp_path / "sub" / "f.txt"
    atomic_write_text(p, "one")
    atomic_write_text(p, "two")
    assert p.read_text() == "two"
    assert [x.name for x in p.parent.iterdir()] == ["f.txt"]


def test_record_trial_whole_or_nothing_and_idempotent(tmp_path):
    recs = [{"cycle": c, "cost": float(c)} for c in range(3)]
    with RunStore(tmp_path / "s.sqlite") as st:
        assert st.record_trial("t", {"seed": 1}, recs) is True
        assert [r["cost"] for r in st.records("t")] == [0.0, 1.0, 2.0]
        assert st.last_cycle("t") == 2 and st.run_config("t") == {"seed": 1}
        # a rescheduled task delivering the same trial again writes nothing
        assert st.record_trial("t", {"seed": 1}, recs) is False
        assert len(st.records("t")) == 3
        with pytest.raises(StateError, match="other settings"):
            st.record_trial("t", {"seed": 2}, recs)
        # a bad record in the middle leaves neither the run nor any of its cycles
        bad = [{"cycle": 0, "x": 1}, {"cycle": 1, "x": object()}]
        with pytest.raises(TypeError):
            st.record_trial("u", {"seed": 3}, bad)
        assert st.run_config("u") is None and st.records("u") == []
        # a run partly written cycle by cycle is not silently completed
        st.create_run("p", {"seed": 4})
        st.record_cycle("p", 0, {"cost": 1.0})
        with pytest.raises(StateError, match="1 of 3 cycles"):
            st.record_trial("p", {"seed": 4}, recs)
        assert len(st.records("p")) == 1
        with pytest.raises(ValueError, match="no cycle records"):
            st.record_trial("v", {}, [])


# -- opening under concurrency ----------------------------------------------------------------
def _write_schema(db: sqlite3.Connection) -> None:
    """What an opener creating a store in place does inside its write transaction (the rapidds
    schema, statement by statement: executescript would commit first)."""
    for stmt in _SCHEMA.split(";"):
        if stmt.strip():
            db.execute(stmt)
    db.execute("INSERT INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),))


def _open_in_thread(path: Path, **kw) -> tuple[threading.Thread, list]:
    out: list = []

    def target() -> None:
        try:
            st = RunStore(path, **kw)
            out.append(st.run_ids())
            st.close()
        except Exception as exc:
            out.append(exc)

    t = threading.Thread(target=target, daemon=True)
    t.start()
    return t, out


def test_open_waits_while_another_connection_initialises_a_fresh_file(tmp_path):
    """The window of the old race: a new file exists (0 bytes, rollback mode) and another
    connection holds its write lock while writing the schema. The open waits for the lock,
    then finds a store and switches it to WAL."""
    path = tmp_path / "run.sqlite"
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    _write_schema(holder)
    t, out = _open_in_thread(path, timeout=20)
    t.join(0.5)
    assert t.is_alive() and not out  # waiting, neither failed nor opened a half-made store
    holder.execute("COMMIT")
    t.join(20)
    assert out == [[]]
    holder.close()
    with RunStore(path) as st:
        assert st._db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_open_retries_the_wal_switch_until_the_writer_lets_go(tmp_path):
    """A store still in rollback mode while another connection holds the write lock: PRAGMA
    journal_mode=WAL answers SQLITE_BUSY at once (no busy handler), so the open must retry."""
    path = tmp_path / "run.sqlite"
    RunStore(path).close()
    legacy = sqlite3.connect(path, isolation_level=None)
    assert legacy.execute("PRAGMA journal_mode=DELETE").fetchone()[0] == "delete"
    legacy.execute("BEGIN IMMEDIATE")
    legacy.execute("INSERT INTO runs VALUES ('old', 0, '{}')")
    # held past a short timeout: a clear StateError, and nothing changed
    with pytest.raises(StateError, match=r"locked by another process for more than 0\.3 s"):
        RunStore(path, timeout=0.3)
    t, out = _open_in_thread(path, timeout=20)
    t.join(0.5)
    assert t.is_alive() and not out
    legacy.execute("COMMIT")
    t.join(20)
    assert out == [["old"]]
    legacy.close()
    with RunStore.open_readonly(path) as st:
        assert st._db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def _digest(path: Path) -> bytes:
    return hashlib.sha256(path.read_bytes()).digest()


@pytest.mark.parametrize("kind", ["foreign", "foreign-wal", "empty", "not-sqlite"])
def test_a_file_that_is_not_a_store_is_refused_and_left_as_it_was(tmp_path, kind):
    path = tmp_path / "run.sqlite"
    if kind.startswith("foreign"):
        db = sqlite3.connect(path)
        if kind == "foreign-wal":
            db.execute("PRAGMA journal_mode=WAL")
        db.execute("CREATE TABLE meta (key TEXT, value TEXT)")  # a name rapidds uses, too
        db.execute("INSERT INTO meta VALUES ('schema', '1')")
        db.commit()
        db.close()
    elif kind == "empty":
        path.touch()
    else:
        path.write_bytes(b"not a database\n" * 100)
    before, listing = _digest(path), sorted(tmp_path.iterdir())
    with pytest.raises(StateError, match="not a rapidds run store"):
        RunStore(path, timeout=0.5)
    assert _digest(path) == before and sorted(tmp_path.iterdir()) == listing
    with pytest.raises(StateError, match="not a rapidds run store"):
        RunStore.open_readonly(path, timeout=0.5)
    assert _digest(path) == before  # (a reader of a WAL file may leave SQLite's -wal/-shm)


def test_empty_file_held_by_a_writer_that_gives_up_is_refused_after_the_wait(tmp_path):
    path = tmp_path / "run.sqlite"
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    t, out = _open_in_thread(path, timeout=20)
    t.join(0.3)
    assert t.is_alive() and not out
    holder.execute("ROLLBACK")
    t.join(20)
    assert len(out) == 1 and isinstance(out[0], StateError) and "empty file" in str(out[0])
    holder.close()
    assert path.stat().st_size == 0


def test_new_store_appears_whole_and_leaves_no_temporary_files(tmp_path):
    path = tmp_path / "sub" / "run.sqlite"
    with RunStore(path) as st:
        st.create_run("a", {})
    assert [p.name for p in path.parent.iterdir()] == ["run.sqlite"]
    assert path.read_bytes()[:16] == b"SQLite format 3\x00"
    assert path.read_bytes()[18:20] == b"\x02\x02"  # WAL from its first byte on disk


def test_without_hard_links_the_store_is_copied_into_place(tmp_path, monkeypatch):
    def no_link(src, dst):
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "link", no_link)
    path = tmp_path / "run.sqlite"
    with RunStore(path) as st:
        st.create_run("a", {"x": 1})
    assert [p.name for p in tmp_path.iterdir()] == ["run.sqlite"]
    with RunStore.open_readonly(path) as st:
        assert st.run_config("a") == {"x": 1}


# -- reading only -----------------------------------------------------------------------------
def test_readonly_open_never_creates_or_writes(tmp_path):
    missing = tmp_path / "none" / "run.sqlite"
    with pytest.raises(StateError, match="no such run store"):
        RunStore.open_readonly(missing)
    assert not missing.parent.exists()
    path = tmp_path / "run.sqlite"
    with RunStore(path) as st:
        st.create_run("a", {"x": 1})
        st.record_cycle("a", 0, {"cost": 1.0})
    with RunStore.open_readonly(path) as st:
        assert st.records("a")[0]["cost"] == 1.0
        with pytest.raises(StateError, match="opened read-only"):
            st.create_run("b", {})
        # and SQLite itself refuses (mode=ro), whatever a caller tries
        with pytest.raises(sqlite3.OperationalError, match="readonly"):
            st._db.execute("INSERT INTO runs VALUES ('c', 0, '{}')")
    with RunStore(path) as st:
        assert st.run_ids() == ["a"]


_READ_SCRIPT = """
import sys
from rapidds.errors import StateError
from rapidds.store import RunStore
with RunStore.open_readonly(sys.argv[1]) as st:
    print(st.run_ids(), len(st.records()))
try:
    RunStore(sys.argv[1])
except (StateError, OSError) as exc:
    print("write refused:", type(exc).__name__)
"""


def test_readonly_open_reads_a_store_on_read_only_media(tmp_path):
    """A store copied into a folder and file nobody may write (the child drops root's power to
    ignore permission bits): reading works, opening it for writing is refused."""
    import os_helpers

    if not os_helpers.can_obey_permissions():
        pytest.skip("cannot drop CAP_DAC_OVERRIDE here, so permission bits are not enforced")
    src = tmp_path / "src" / "run.sqlite"
    with RunStore(src) as st:
        st.create_run("a", {"x": 1})
        st.record_cycle("a", 0, {"cost": 1.0})
        st.record_cycle("a", 1, {"cost": 2.0})
    media = tmp_path / "media"
    media.mkdir()
    shutil.copy(src, media / "run.sqlite")
    (media / "run.sqlite").chmod(0o444)
    media.chmod(0o555)
    try:
        res = subprocess.run([sys.executable, "-c", _READ_SCRIPT, str(media / "run.sqlite")],
                             capture_output=True, text=True, timeout=60,
                             preexec_fn=os_helpers.obey_permissions)
    finally:
        media.chmod(0o755)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == ["['a'] 2", "write refused: StateError"]
    assert sorted(p.name for p in media.iterdir()) == ["run.sqlite"]


# -- many processes ---------------------------------------------------------------------------
def _rounds(tmp_path: Path, configs: list[dict], rounds: int) -> list[tuple]:
    """len(configs) spawned processes open ``rounds`` new stores, all at once each round."""
    import os_helpers

    ctx = mp.get_context("spawn")
    barrier, results = ctx.Barrier(len(configs)), ctx.Queue()
    paths = [str(tmp_path / f"r{k}" / "run.sqlite") for k in range(rounds)]
    procs = [ctx.Process(target=os_helpers.open_rounds,
                         args=(barrier, paths, w, cfg, results)) for w, cfg in enumerate(configs)]
    for p in procs:
        p.start()
    try:
        out = [results.get(timeout=120) for _ in range(len(configs) * rounds)]
    finally:
        for p in procs:
            p.join(30)
            if p.is_alive():
                p.kill()
    return out


def test_many_processes_open_one_new_store_at_once(tmp_path):
    """8 processes x 10 new stores, released together: every open, create_run and cycle
    succeeds (before the fix, opening a new store at once failed 3-40 % of the time)."""
    out = _rounds(tmp_path, [{"seed": 0}] * 8, rounds=10)
    failures = [e for _, _, e in out if e is not None]
    assert not failures, f"{len(failures)} of {len(out)} failed; first:\n{failures[0]}"
    for k in range(10):
        # no temporary store left behind by the processes whose link lost
        assert sorted(p.name for p in (tmp_path / f"r{k}").iterdir()) == ["run.sqlite"]
        with RunStore.open_readonly(tmp_path / f"r{k}" / "run.sqlite") as st:
            assert st.run_ids() == ["r"] and st.last_cycle("r") == 7
            assert sorted(r["worker"] for r in st.records("r")) == list(range(8))


def test_two_processes_creating_one_run_with_other_settings(tmp_path):
    """create_run is one step: of two processes registering one run with different settings,
    exactly one wins and the other is told so (never an IntegrityError)."""
    out = _rounds(tmp_path, [{"seed": 0}, {"seed": 1}], rounds=5)
    for k in range(5):
        errors = [e for _, r, e in out if r == k and e is not None]
        assert len(errors) == 1 and "already exists" in errors[0] and "other settings" in errors[0]
        with RunStore.open_readonly(tmp_path / f"r{k}" / "run.sqlite") as st:
            assert len(st.records("r")) == 1


def test_corrupt_stored_json_is_a_state_error(tmp_path):
    path = tmp_path / "run.sqlite"
    with RunStore(path) as st:
        st.create_run("a", {"x": 1})
        st.record_cycle("a", 0, {"cost": 1.0})
        st._db.execute("UPDATE cycles SET record='{\"cost\": ' WHERE run_id='a'")
        st._db.execute("UPDATE runs SET config='[1,' WHERE run_id='a'")
        with pytest.raises(StateError, match="corrupt stored JSON in run 'a' cycle 0"):
            st.records()
        with pytest.raises(StateError, match="corrupt stored JSON in run 'a'"):
            st.run_config("a")


def test_non_finite_values_are_never_stored(tmp_path):
    with RunStore(tmp_path / "run.sqlite") as st:
        st.create_run("a", {})
        with pytest.raises(ValueError, match="not JSON compliant"):
            st.record_cycle("a", 0, {"cost": float("nan")})
        assert st.records() == []


def test_folder_lock_keeps_a_second_writer_out_until_the_first_closes(tmp_path):
    out = tmp_path / "out"
    with locked_folder(out, "rapidds run"):
        with pytest.raises(RapiddsError, match=f"another rapidds run is writing {out}"):
            RunStore(out / "run.sqlite", lock_as="rapidds run")
        assert not (out / "run.sqlite").exists()  # refused before anything was created
    st = RunStore(out / "run.sqlite", lock_as="rapidds run")
    with pytest.raises(RapiddsError, match="another rapidds ablation is writing"), \
            locked_folder(out, "rapidds ablation"):
        pass
    with RunStore.open_readonly(out / "run.sqlite"):  # readers need no lock
        pass
    st.close()
    with locked_folder(out, "rapidds run"):
        pass
