"""What a study participant did in one round, as the loop's :class:`HumanExecution` per task.

Three sources, one result (duration in s and a body-point path sampled at the world's ``dt``):

* **A tracker file** the experimenter uploads (:func:`parse_tracker`): CSV with a header, or JSON
  (a list of objects with the same fields). One row per body point per sample::

      task,point,t,x,y,z
      brush,0,12.00,-0.16,-0.29,0.03
      brush,1,12.00,0.16,-0.29,0.03
      ...

  ``task``: a human task of the round's plan (every one of them, no other). ``point``: the body
  point's index 0..K-1 in the world's order (painting: 0 left hand, 1 right hand, 2 left elbow,
  3 right elbow; worlds with one point may leave the column out). ``t``: seconds on any clock
  (only differences matter). ``x, y, z``: workspace coordinates in the world's units (metres),
  ``z`` only in 3-D worlds. A task starts at its first sample (any point) and ends at its last:
  duration = last t - first t. Each point is linearly interpolated at the world's rows
  ``min(k dt, duration)`` and held at its first / last sample outside its own samples.
* **The simulated cell** (:func:`group_teammate`): the world's simulated teammate of the
  participant's priming group performs the tasks (the loop's ``execute``).
* **Durations typed in** (:func:`typed_execution`): the path is the group's teammate's nominal
  path of the task (its habit, no per-execution noise: ``nominal_path`` where the teammate has
  one, else one execution with a fixed seed), stretched in time to the typed duration. The
  spatial model then learns the group's habitual path, not this person's: typed-in rounds adapt
  the timing to the person and the paths only to their priming group.

Every problem with the input raises :class:`TrackerError` with one line that says what to fix.
"""

from __future__ import annotations

import io
import json
import logging
import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from rapidds.errors import RapiddsError
from rapidds.loop.observation import resample, sample_times
from rapidds.worlds.base import HumanExecution, SimulatedTeammate, World, body_points
from rapidds.worlds.bounds import mostly_implausible, plausible_mask, world_task_bound

__all__ = [
    "MAX_COLUMNS",
    "MAX_TRACKER_BYTES",
    "TrackerError",
    "group_teammate",
    "parse_tracker",
    "tracker_csv",
    "typed_execution",
]

log = logging.getLogger("rapidds.web")
MAX_TRACKER_BYTES = 8 * 1024 * 1024
"""Largest tracker file accepted (about 200 000 rows of CSV)."""
MAX_COLUMNS = 32
"""Most columns (CSV) or fields per object (JSON) a tracker file may have: the format needs 6;
a header of 100 000 columns kept the study's one worker busy for 11 s."""
_AXES = ("x", "y", "z")
_NOMINAL_ROWS = 401  # phases of a nominal path before it is stretched to a typed duration


class TrackerError(RapiddsError, ValueError):
    """A tracker file, a typed duration or a priming group the study cannot use."""


def group_teammate(world: World, group: str) -> SimulatedTeammate:
    """The world's simulated teammate of priming group ``group`` (painting: "left-fast", ...)."""
    if group not in world.teammate_names:
        raise TrackerError(
            f"priming group '{group}' names no simulated teammate of world {world.name} (one of "
            f"{', '.join(world.teammate_names)}): the simulated cell and typed-in durations need "
            "one; upload a tracker file instead")
    return world.teammate(group)


def typed_execution(world: World, teammate: SimulatedTeammate, task: str,
                    duration: float) -> HumanExecution:
    """A typed-in duration with the teammate's nominal path of ``task`` stretched to it."""
    if not (isinstance(duration, int | float) and math.isfinite(duration) and duration > 0):
        raise TrackerError(f"duration of {task}: must be a positive number of seconds, got "
                           f"{duration!r}")
    nominal = getattr(teammate, "nominal_path", None)
    if callable(nominal):
        path = body_points(nominal(task, _NOMINAL_ROWS))
        phase = np.linspace(0.0, 1.0, len(path))
    else:  # one execution with a fixed seed, as its own phases
        d0, raw = teammate.perform(task, np.random.default_rng(0))
        path = body_points(raw)
        phase = np.minimum(np.arange(len(path)) * world.dt, d0) / d0
    rows = sample_times(float(duration), world.dt)
    return HumanExecution(task, float(duration), resample(phase, path, rows / duration))


class _TooWide(Exception):
    """Raised from inside the JSON parser: the objects name too many distinct fields."""


def _json_rows(text: str) -> pd.DataFrame:
    """The rows of a JSON tracker file. Checked while it is parsed, before pandas sees it:
    at most :data:`MAX_COLUMNS` distinct field names over all objects (objects with different
    fields made pandas build objects x all fields: 139 KB stalled the server 8.3 s and took
    1.5 GB), whole numbers kept as their text (a 5000-digit one is no int to convert), every
    value a number, text or null."""
    keys: dict[str, None] = {}

    def pairs(items: list[tuple[str, object]]) -> dict[str, object]:
        for k, _ in items:
            if k not in keys:
                keys[k] = None
                if len(keys) > MAX_COLUMNS:
                    raise _TooWide
        return dict(items)

    try:
        obj = json.loads(text, parse_int=str, object_pairs_hook=pairs)
    except json.JSONDecodeError as exc:
        raise TrackerError(f"the tracker file is not valid JSON: {exc.msg} (line "
                           f"{exc.lineno})") from None
    except RecursionError:
        raise TrackerError("the tracker file's JSON is nested too deeply; it must be a list "
                           "of objects") from None
    except _TooWide:
        raise TrackerError(f"the tracker file's objects name more than {MAX_COLUMNS} distinct "
                           "fields; each object needs task, point, t, x, y(, z)") from None
    if isinstance(obj, dict) and isinstance(obj.get("rows"), list):
        obj = obj["rows"]
    if not isinstance(obj, list) or not all(isinstance(r, dict) for r in obj):
        raise TrackerError("a JSON tracker file must be a list of objects with fields task, "
                           "point, t, x, y(, z)")
    for i, r in enumerate(obj):
        bad = next((k for k, v in r.items() if not isinstance(v, str | float | bool | None)),
                   None)
        if bad is not None:
            raise TrackerError(f"tracker file object {i + 1}: field {_show(bad)} is not a "
                               "number or text")
    names = list(dict.fromkeys(k for r in obj for k in r))
    return pd.DataFrame({k: [r.get(k) for r in obj] for k in names}, dtype=object)


def _show(value: object) -> str:
    """A value of the file as a message shows it: its repr, at most 40 characters (an error
    never echoes a big file back to the page)."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _table(data: bytes) -> tuple[pd.DataFrame, int]:
    """The rows, and the number the first row has in messages (CSV: its line; JSON: 1)."""
    text = data.decode("utf-8-sig", errors="strict").strip()
    if not text:
        raise TrackerError("the tracker file is empty")
    if text[0] in "[{":
        return _json_rows(text), 1
    columns = text.partition("\n")[0].count(",") + 1  # before pandas reads every one of them
    if columns > MAX_COLUMNS:
        raise TrackerError(f"the tracker file's header has {columns} columns; at most "
                           f"{MAX_COLUMNS} (task, point, t, x, y, z are needed)")
    try:
        return pd.read_csv(io.StringIO(text), dtype=str, skipinitialspace=True), 2
    except (pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        raise TrackerError("the tracker file is not valid CSV: "
                           f"{str(exc).strip().splitlines()[0][:160]}") from None


def _numbers(table: pd.DataFrame, column: str, line0: int) -> np.ndarray:
    values = pd.to_numeric(table[column].astype(str), errors="coerce").to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(values))
    if len(bad):
        i = int(bad[0])
        raise TrackerError(f"tracker file row {i + line0}: {column} = "
                           f"{_show(table[column].iloc[i])} is not a finite number")
    return values


def parse_tracker(data: bytes, world: World, tasks: Sequence[str],
                  at_most: float | None = None) -> dict[str, HumanExecution]:
    """The person's ``tasks`` of one round from a tracker file's bytes (format: module
    docstring); :class:`TrackerError` names the first problem. ``at_most``: the longest a task
    may take, s (default: the world's bound, :func:`world_task_bound`)."""
    if len(data) > MAX_TRACKER_BYTES:
        raise TrackerError(f"the tracker file is {len(data) / 2**20:.1f} MiB, larger than "
                           f"{MAX_TRACKER_BYTES // 2**20} MiB")
    try:
        table, line0 = _table(data)
    except UnicodeDecodeError:
        raise TrackerError("the tracker file is not UTF-8 text (CSV or JSON)") from None
    rest = np.asarray(world.human_rest(), dtype=float)
    k, dim = rest.shape
    table = _columns(table, k, _AXES[:dim], line0)
    samples = _samples(table, world, k, _AXES[:dim], line0)
    names = table["task"].to_numpy()
    wanted = list(dict.fromkeys(tasks))
    extra = sorted(set(names) - set(wanted))
    if extra:
        raise TrackerError(f"the tracker file has task(s) {', '.join(_show(x) for x in extra[:3])}"
                           f"{' ...' if len(extra) > 3 else ''} that the person "
                           f"does not do this round (their tasks: {', '.join(wanted)})")
    limit = world_task_bound(world) if at_most is None else at_most
    return {task: _execution(world, task, names == task, samples, limit, wanted)
            for task in wanted}


def _columns(table: pd.DataFrame, k: int, axes: Sequence[str], line0: int) -> pd.DataFrame:
    """The table's columns the format needs (``point`` implied for one body point), with the
    text columns stripped; TrackerError for a missing column or an empty cell."""
    table.columns = [str(c).strip().lower() for c in table.columns]
    if "point" not in table.columns and k == 1:
        table["point"] = "0"
    need = ["task", "point", "t", *axes]
    missing = [c for c in need if c not in table.columns]
    if missing:
        raise TrackerError(f"the tracker file lacks column(s) {', '.join(missing)}; its header "
                           f"must name {', '.join(need)}")
    if table.empty:
        raise TrackerError("the tracker file has a header but no rows")
    table = table[need].copy()
    for c in ("task", "point"):
        null = np.flatnonzero(table[c].isna().to_numpy())
        if len(null):
            raise TrackerError(f"tracker file row {int(null[0]) + line0}: {c} is empty")
        table[c] = table[c].astype(str).str.strip()
    return table


def _samples(table: pd.DataFrame, world: World, k: int, axes: Sequence[str],
             line0: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(point index, t, coordinates) of every row, checked: a body point of this world, and
    coordinates near the workspace (a file in millimetres or another frame is refused)."""
    point = _numbers(table, "point", line0)
    bad = np.flatnonzero((point != np.round(point)) | (point < 0) | (point >= k))
    if len(bad):
        i = int(bad[0])
        raise TrackerError(f"tracker file row {i + line0}: point = "
                           f"{_show(table['point'].iloc[i])}; this world's person has body "
                           f"points 0..{k - 1}")
    t = _numbers(table, "t", line0)
    xyz = np.stack([_numbers(table, a, line0) for a in axes], axis=-1)
    lo, hi = (np.asarray(b, dtype=float) for b in world.workspace_bounds)
    span = hi - lo
    far = np.flatnonzero(((xyz < lo - span) | (xyz > hi + span)).any(axis=1))
    if len(far):
        i = int(far[0])
        raise TrackerError(
            f"tracker file row {i + line0}: ({', '.join(f'{v:g}' for v in xyz[i])}) is far "
            f"outside the workspace [{', '.join(f'{v:g}' for v in lo)}] .. "
            f"[{', '.join(f'{v:g}' for v in hi)}]: are the coordinates in metres, in the "
            "world's frame?")
    return point, t, xyz


def _execution(world: World, task: str, rows: np.ndarray,
               samples: tuple[np.ndarray, np.ndarray, np.ndarray], limit: float,
               wanted: Sequence[str]) -> HumanExecution:
    """One task's execution from its ``rows`` of the file's ``samples`` (body point, t, xyz per
    row): duration from first to last sample, every body point resampled at the world's dt."""
    point, t, xyz = samples
    k = int(np.asarray(world.human_rest()).shape[0])
    if not rows.any():
        raise TrackerError(f"the tracker file has no rows for task {task} (the person's "
                           f"tasks this round: {', '.join(wanted)})")
    t0, t1 = float(t[rows].min()), float(t[rows].max())
    if not t1 > t0:
        raise TrackerError(f"task {task}: all samples have t = {t0:g}; a task needs samples "
                           "at two times at least")
    if t1 - t0 > limit:  # before its path of (t1 - t0) / dt rows is allocated
        raise TrackerError(f"task {task}: its samples span {t1 - t0:g} s, longer than any "
                           f"task of this study ({limit:g} s): are t in seconds, one "
                           "round per file?")
    grid = sample_times(t1 - t0, world.dt)
    path = np.empty((len(grid), k, xyz.shape[1]))
    for j in range(k):
        sel = rows & (point == j)
        if not sel.any():
            raise TrackerError(f"task {task}: no samples of body point {j} (this world's "
                               f"person has points 0..{k - 1}, all needed)")
        order = np.argsort(t[sel], kind="stable")
        tj, pj = t[sel][order] - t0, xyz[sel][order]
        if np.any(np.diff(tj) <= 0):
            raise TrackerError(f"task {task}, point {j}: two samples at the same t; each "
                               "time once per point")
        tj, pj = _plausible(world, task, j, tj, pj)
        path[:, j] = resample(tj, pj[:, None, :], grid)[:, 0]
    return HumanExecution(task, t1 - t0, path)


def _plausible(world: World, task: str, j: int, t: np.ndarray, xyz: np.ndarray,
               ) -> tuple[np.ndarray, np.ndarray]:
    """The samples of body point ``j`` in ``task`` that are plausible
    (:mod:`rapidds.worlds.bounds`); the others are dropped with one line. A task whose samples
    are mostly implausible is refused: it would not be learned as the person did it."""
    keep, why = plausible_mask(world, t, xyz)
    dropped = int((~keep).sum())
    if not dropped:
        return t, xyz
    if mostly_implausible(int(keep.sum()), dropped):
        raise TrackerError(f"task {task}, point {j}: {dropped} of {len(t)} samples are "
                           f"implausible (the first: {why}); is this the person's tracking, "
                           "in metres, in the world's frame?")
    log.warning("tracker file, task %s, point %d: dropped %d implausible sample(s) (the "
                "first: %s)", task, j, dropped, why)
    return t[keep], xyz[keep]


def tracker_csv(executions: Mapping[str, HumanExecution], dt: float, t0: float = 0.0) -> str:
    """A tracker file (CSV) of ``executions``, one after the other from ``t0``, sampled at
    ``dt``: the format's reference writer (tests and examples use it)."""
    lines = ["task,point,t," + ",".join(_AXES[:body_points(next(iter(
        executions.values())).trajectory).shape[-1]])]
    start = t0
    for task, ex in executions.items():
        p = body_points(ex.trajectory)
        times = np.minimum(np.arange(len(p)) * dt, ex.duration)
        for r, tr in enumerate(times):
            for j in range(p.shape[1]):
                lines.append(f"{task},{j},{start + tr:.4f}," + ",".join(f"{v:.5f}"
                                                                      for v in p[r, j]))
        start += ex.duration + 1.0
    return "\n".join(lines) + "\n"
