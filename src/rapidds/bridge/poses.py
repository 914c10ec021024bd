"""Robot demonstrations recorded as end-effector poses with task labels, as the paper's own lab
recorded them (franka_ros's ``O_T_EE``, one-hot labels, CSV), turned into the world's joint
paths by the world's inverse kinematics.

The CSV: a header row, columns ``x, y, z`` (metres: the world's tool point in the robot's base
frame, Franka's ``O`` frame), ``qx, qy, qz, qw`` (its orientation, read and checked to be a
rotation; the world's IK decides the tool's orientation: the painting arm keeps its tool
pointing down), one column per labelled task named by the task's id (1 on the rows of that
task, 0 elsewhere: one-hot), and optionally ``t`` or ``time`` (seconds; without it the rows are
taken ``dt`` apart, the world's step) and ``demo`` (a new demonstration where it changes).
A demonstration is a run of consecutive rows with the same label (a row labelled with no task
separates two runs); each is resampled at the world's dt from its first row, solved for joints
row by row (each row's IK seeded with the previous row's answer, the first with the robot's
rest pose, so a path stays on one branch) and held at its last pose to the world's horizon,
the demonstrations' convention. The world supplies the IK as ``end_effector_ik`` (positions
(T, 3) in the base frame -> joint paths (T, d); ValueError for an unreachable one).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from rapidds.errors import RapiddsError
from rapidds.worlds.base import World
from rapidds.worlds.capabilities import capability, lacks

__all__ = ["POSE_COLUMNS", "pose_demonstrations"]

log = logging.getLogger("rapidds.bridge")
POSE_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw")
_TIME = ("t", "time")


def _table(path: Path) -> Any:
    import pandas as pd

    try:
        frame = pd.read_csv(path, skipinitialspace=True)
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise RapiddsError(f"{path}: not a readable CSV of end-effector poses ({exc})") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    if missing := [c for c in POSE_COLUMNS if c not in frame.columns]:
        raise RapiddsError(f"{path}: no column {missing[0]!r} (a CSV of end-effector poses has "
                           f"{', '.join(POSE_COLUMNS)} and one column per task label)")
    if frame.empty:
        raise RapiddsError(f"{path}: no rows")
    return frame


def _numbers(frame: Any, cols: list[str], path: Path) -> np.ndarray:
    import pandas as pd

    values = frame[cols].apply(pd.to_numeric, errors="coerce").to_numpy(float)
    if not np.isfinite(values).all():
        row, col = np.argwhere(~np.isfinite(values))[0]
        raise RapiddsError(f"{path}: row {row + 2}, column {cols[col]!r} is not a number")
    return values


def _runs(path: Path, frame: Any, tasks: tuple[str, ...],
          dt: float) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(task, times (n,) s, positions (n, 3)) of each labelled run of rows."""
    labels = [c for c in frame.columns if c not in POSE_COLUMNS and c not in (*_TIME, "demo")]
    if not labels:
        raise RapiddsError(f"{path}: no task label column (one per task, named by its id)")
    if bad := [c for c in labels if c not in tasks]:
        raise RapiddsError(f"{path}: column {bad[0]!r} is not a robot task ({', '.join(tasks)})")
    pose = _numbers(frame, list(POSE_COLUMNS), path)
    onehot = _numbers(frame, labels, path)
    if not np.isin(onehot, (0.0, 1.0)).all() or (onehot.sum(axis=1) > 1).any():
        row = int(np.argwhere(~np.isin(onehot, (0.0, 1.0)).any(axis=1)
                              | (onehot.sum(axis=1) > 1))[0, 0])
        raise RapiddsError(f"{path}: row {row + 2} is not one-hot (0 or 1 in each label "
                           "column, at most one 1)")
    norms = np.linalg.norm(pose[:, 3:], axis=1)
    if (np.abs(norms - 1.0) > 1e-2).any():
        row = int(np.argmax(np.abs(norms - 1.0) > 1e-2))
        raise RapiddsError(f"{path}: row {row + 2}'s quaternion has norm {norms[row]:.3f}, "
                           "not a rotation")
    tcol = next((c for c in _TIME if c in frame.columns), None)
    times = _numbers(frame, [tcol], path)[:, 0] if tcol else np.arange(len(frame)) * dt
    label = np.where(onehot.sum(axis=1) > 0, onehot.argmax(axis=1), -1)
    demo = frame["demo"].astype(str).to_numpy() if "demo" in frame.columns else None
    runs, start = [], 0
    for k in range(1, len(frame) + 1):
        if k < len(frame) and label[k] == label[start] and (demo is None
                                                            or demo[k] == demo[start]):
            continue
        if label[start] >= 0:
            t = times[start:k] - times[start]
            if (np.diff(t) <= 0).any():
                raise RapiddsError(f"{path}: rows {start + 2}..{k + 1}: time does not increase")
            runs.append((labels[label[start]], t, pose[start:k, :3]))
        start = k
    return runs


def pose_demonstrations(path: str | Path, world: World) -> Any:
    """:class:`~rapidds.motion.demos.Demonstrations` of the robot from a CSV of end-effector
    poses with task labels (module docstring); RapiddsError in one line for a file that is not
    one, a world without IK, or a pose the arm cannot reach."""
    from rapidds.motion.demos import Demonstrations

    path = Path(path)
    arm = capability(world, "end_effector_ik")
    if arm is None:
        raise RapiddsError(lacks(world, "end_effector_ik"))
    tasks = tuple(t.id for t in world.problem().tasks if "robot" in t.allowed)
    dt, horizon = world.dt, world.horizon
    rows, index = [], []
    for n, (task, t, pos) in enumerate(_runs(path, _table(path), tasks, dt)):
        if t[-1] > (horizon - 1) * dt + 1e-9:
            log.warning("%s: demonstration %d (%s) takes %.2f s, longer than the horizon "
                        "(%.2f s); dropped", path, n + 1, task, t[-1], (horizon - 1) * dt)
            continue
        steps = math.ceil(t[-1] / dt - 1e-9) + 1
        at = np.minimum(np.arange(steps) * dt, t[-1])
        target = np.stack([np.interp(at, t, pos[:, i]) for i in range(3)], axis=1)
        try:
            joints = np.asarray(arm.end_effector_ik(target), float)
        except ValueError as exc:
            raise RapiddsError(f"{path}: demonstration {n + 1} ({task}): {exc}") from None
        hold = np.repeat(joints[-1:], horizon - steps, axis=0)
        rows.append(np.concatenate([joints, hold]))
        index.append(tasks.index(task))
    if not rows:
        raise RapiddsError(f"{path}: no labelled demonstration within the horizon")
    if missing := [t for k, t in enumerate(tasks) if k not in index]:
        log.warning("no demonstration of robot task(s) %s: the policy will not know them",
                    ", ".join(missing))
    return Demonstrations(np.stack(rows), np.array(index), tasks)
