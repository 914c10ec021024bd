"""The study app's observations: a tracker file (CSV or JSON) read back to the loop's paths at
the world's dt, typed-in durations with the priming group's nominal path, and every malformed
file refused with a line that says what to fix."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from rapidds.web.study.tracker import (
    TrackerError,
    group_teammate,
    parse_tracker,
    tracker_csv,
    typed_execution,
)
from rapidds.worlds.registry import make_world

TASKS = ["prep_vise", "brush"]


@pytest.fixture(scope="module")
def painting():  # type: ignore[no-untyped-def]
    return make_world("painting")


@pytest.fixture(scope="module")
def done(painting):  # type: ignore[no-untyped-def]
    return group_teammate(painting, "right-slow").execute(0, TASKS, np.random.default_rng(3))


def test_a_tracker_file_gives_back_what_the_person_did(painting, done) -> None:  # type: ignore[no-untyped-def]
    text = tracker_csv(done, painting.dt, t0=1234.5)
    for data in (text.encode(), _as_json(text).encode()):
        back = parse_tracker(data, painting, list(reversed(TASKS)))
        assert list(back) == list(reversed(TASKS))  # in the order asked
        for t in TASKS:
            assert back[t].duration == pytest.approx(done[t].duration, abs=1e-3)
            assert back[t].trajectory.shape == done[t].trajectory.shape  # (T, 4, 3) at dt
            np.testing.assert_allclose(back[t].trajectory, done[t].trajectory, atol=1e-4)


def test_samples_off_the_grid_are_interpolated_at_the_worlds_rows(painting) -> None:  # type: ignore[no-untyped-def]
    # every point moves along x at 0.1 m/s, sampled at an odd rate and in shuffled order
    t = np.arange(0.0, 2.001, 0.07)
    rows = [f"brush,{j},{s:.4f},{0.1 * s:.5f},0,0.1" for s in t for j in range(4)]
    rows = [rows[i] for i in np.random.default_rng(0).permutation(len(rows))]
    ex = parse_tracker(("task,point,t,x,y,z\n" + "\n".join(rows)).encode(), painting,
                       ["brush"])["brush"]
    assert ex.duration == pytest.approx(t[-1])
    grid = np.minimum(np.arange(ex.trajectory.shape[0]) * painting.dt, ex.duration)
    assert ex.trajectory.shape == (int(np.ceil(t[-1] / painting.dt)) + 1, 4, 3)
    np.testing.assert_allclose(ex.trajectory[:, 2, 0], 0.1 * grid, atol=1e-4)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda s: "", "empty"),
    (lambda s: "task,point,t,x,y\n", "lacks column(s) z"),
    (lambda s: s.split("\n", 1)[0] + "\n", "no rows"),
    (lambda s: s.replace("brush,", "paint,"), "does not do this round"),
    (lambda s: "\n".join(r for r in s.split("\n") if not r.startswith("brush")), "no rows for "
     "task brush"),
    (lambda s: "\n".join(r for r in s.split("\n") if not r.startswith("brush,3,")),
     "no samples of body point 3"),
    (lambda s: s.replace("brush,1,", "brush,7,", 1), "body points 0..3"),
    (lambda s: s.replace("brush,1,", "brush,x,", 1), "not a finite number"),
    (lambda s: s.replace(",0.03", ",inf", 1), "not a finite number"),
    (lambda s: s.replace("prep_vise,0,", "prep_vise,0,nan", 1), "not a finite number"),
    (lambda s: "\n".join(r if not r.startswith("brush,") else
                         r.replace(",-0.", ",-160.") for r in s.split("\n")), "metres"),
    (lambda s: s + s.split("\n")[-2] + "\n", "same t"),
    (lambda s: "[1, 2]", "list of objects"),
    (lambda s: "{oops", "not valid JSON"),
    # bounded before anything is allocated or parsed column by column
    (lambda s: re.sub(r"brush,0,[^,]+,", "brush,0,1e12,", s, count=1), "longer than any task "
     "of this study (120 s"),
    (lambda s: "[" * 100_000, "nested too deeply"),
    (lambda s: "task,point,t,x,y,z," + ",".join(f"c{i}" for i in range(100_000)) + "\n",
     "100006 columns; at most 32"),
    (lambda s: json.dumps([{f"c{i}": 0 for i in range(33)}]), "more than 32 distinct fields"),
])
def test_a_bad_tracker_file_is_refused_in_one_line(painting, done, edit, message) -> None:  # type: ignore[no-untyped-def]
    text = edit(tracker_csv(done, painting.dt))
    with pytest.raises(TrackerError, match=None) as err:
        parse_tracker(text.encode(), painting, TASKS)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_the_studys_own_bound_replaces_the_worlds(painting, done) -> None:  # type: ignore[no-untyped-def]
    text = tracker_csv(done, painting.dt).encode()
    longest = max(ex.duration for ex in done.values())
    assert set(parse_tracker(text, painting, TASKS, at_most=longest + 0.01)) == set(TASKS)
    with pytest.raises(TrackerError, match=rf"than any task of this study \({longest - 1:g} s"):
        parse_tracker(text, painting, TASKS, at_most=longest - 1)


def test_a_file_that_is_not_text_is_refused(painting) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(TrackerError, match="not UTF-8"):
        parse_tracker(b"\xff\xfe\x00garbage", painting, TASKS)


def test_typed_durations_take_the_groups_nominal_path_stretched(painting) -> None:  # type: ignore[no-untyped-def]
    mate = group_teammate(painting, "left-fast")
    for d in (2.0, 9.5):
        ex = typed_execution(painting, mate, "brush", d)
        assert ex.duration == d
        assert ex.trajectory.shape == (int(np.ceil(d / painting.dt)) + 1, 4, 3)
        rest = painting.human_rest()
        np.testing.assert_allclose(ex.trajectory[0], rest, atol=1e-9)  # starts and ends at rest
        np.testing.assert_allclose(ex.trajectory[-1], rest, atol=1e-9)
    # stretched in time, the same path: at twice the duration, row 2k is where row k was
    slow, fast = (typed_execution(painting, mate, "brush", d).trajectory for d in (9.0, 4.5))
    np.testing.assert_allclose(slow[::2], fast, atol=1e-9)
    assert np.ptp(fast[:, 0], axis=0).max() > 0.1  # and the brushing hand does move
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(TrackerError, match="positive number"):
            typed_execution(painting, mate, "brush", bad)


def test_a_group_without_a_simulated_person_is_said(painting) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(TrackerError, match="upload a tracker file"):
        group_teammate(painting, "left")


def _as_json(csv_text: str) -> str:
    head, *rows = [r for r in csv_text.split("\n") if r]
    keys = head.split(",")
    return json.dumps([{k: (v if k == "task" else float(v)) for k, v in zip(keys, r.split(","),
                                                                             strict=True)}
                       for r in rows])
