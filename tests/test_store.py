import numpy as np
import pytest

from rapidds.errors import StateError
from rapidds.fileio import atomic_write_text
from rapidds.store import RunStore


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
