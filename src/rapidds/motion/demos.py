"""Robot demonstrations: fixed-length trajectories with a task label, the policy's training set.

Stored as one ``.npz`` (numpy, no pickle) with arrays ``trajectories`` (N, H, d),
``task_index`` (N,), ``task_names`` (K,) and optionally ``start`` (N, d). Demonstrations that
finish early are padded with their last point, so the completion index of a trajectory is where
it stops moving; every motion mode the robot should be able to use must appear in them.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rapidds.errors import RapiddsError

_KEYS = ("trajectories", "task_index", "task_names", "start")


class DemonstrationError(RapiddsError, ValueError):
    """A demonstrations file is missing, unreadable or inconsistent."""


@dataclass(frozen=True, eq=False)
class Demonstrations:
    """N demonstrations of H points in R^d.

    trajectories: (N, H, d) float32, H a multiple of 8.
    task_index: (N,) int64, each in 0..K-1, indexing ``task_names``.
    task_names: K unique task names; the policy's one-hot order.
    start: optional (N, d) float32 start pose per demonstration (for start-conditioned
        policies; when absent such a policy uses each trajectory's first point).
    """

    trajectories: np.ndarray
    task_index: np.ndarray
    task_names: tuple[str, ...]
    start: np.ndarray | None = None

    def __post_init__(self) -> None:
        traj = np.asarray(self.trajectories)
        idx = np.asarray(self.task_index)
        names = tuple(str(n) for n in np.asarray(self.task_names).reshape(-1))
        start = None if self.start is None else np.asarray(self.start)

        if traj.ndim != 3:
            raise DemonstrationError(f"trajectories must have shape (N, H, d), got {traj.shape}")
        n, h, d = traj.shape
        if n == 0 or d == 0:
            raise DemonstrationError(f"trajectories are empty: shape {traj.shape}")
        if h == 0 or h % 8:
            raise DemonstrationError(f"horizon H must be a positive multiple of 8, got {h} "
                                     "(resample with Demonstrations.resample or --horizon)")
        if not (np.issubdtype(traj.dtype, np.integer) or np.issubdtype(traj.dtype, np.floating)):
            raise DemonstrationError(f"trajectories must be real numbers, got dtype {traj.dtype}")
        finite = _finite32(traj)  # stored and trained in float32: 1e308 is infinity there
        if not finite.all():
            bad = int(np.argwhere(~finite)[0, 0])
            raise DemonstrationError(f"trajectories contain NaN or infinity, or values past "
                                     f"float32's 3.4e38 (first in demo {bad})")
        if not names:
            raise DemonstrationError("task_names is empty")
        if any(not n.strip() for n in names):
            raise DemonstrationError("task_names contains an empty name")
        if len(set(names)) != len(names):
            raise DemonstrationError(f"task_names must be unique, got {list(names)}")
        if idx.shape != (n,):
            raise DemonstrationError(f"task_index must have shape ({n},), got {idx.shape}")
        integral = np.issubdtype(idx.dtype, np.integer) or (
            np.issubdtype(idx.dtype, np.floating) and bool(np.all(idx == np.round(idx))))
        if not integral:
            raise DemonstrationError(f"task_index must hold integers, got dtype {idx.dtype}")
        if idx.min() < 0 or idx.max() >= len(names):
            raise DemonstrationError(f"task_index values must be in 0..{len(names) - 1}, got "
                                     f"range {int(idx.min())}..{int(idx.max())}")
        if start is not None:
            if start.shape != (n, d):
                raise DemonstrationError(f"start must have shape ({n}, {d}), got {start.shape}")
            if not np.issubdtype(start.dtype, np.number) or not _finite32(start).all():
                raise DemonstrationError("start must hold finite numbers within float32's "
                                         "range")
            start = start.astype(np.float32)
        object.__setattr__(self, "trajectories", traj.astype(np.float32))
        object.__setattr__(self, "task_index", idx.astype(np.int64))
        object.__setattr__(self, "task_names", names)
        object.__setattr__(self, "start", start)

    # -- shape -------------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.trajectories.shape[0])

    @property
    def horizon(self) -> int:
        return int(self.trajectories.shape[1])

    @property
    def state_dim(self) -> int:
        return int(self.trajectories.shape[2])

    def start_poses(self) -> np.ndarray:
        """(N, d) start pose per demonstration: ``start`` if given, else the first point."""
        return self.trajectories[:, 0] if self.start is None else self.start

    def of_task(self, name: str) -> np.ndarray:
        """(N_task, H, d) trajectories of one task."""
        if name not in self.task_names:
            raise DemonstrationError(f"unknown task {name!r}; known: {', '.join(self.task_names)}")
        return self.trajectories[self.task_index == self.task_names.index(name)]

    @staticmethod
    def resample_array(trajectories: np.ndarray, horizon: int) -> np.ndarray:
        """(N, H, d) -> (N, horizon, d) by linear interpolation over normalised time."""
        if horizon < 2:
            raise DemonstrationError(f"horizon must be >= 2, got {horizon}")
        traj = np.asarray(trajectories, dtype=np.float64)
        src = np.linspace(0.0, 1.0, traj.shape[1])
        dst = np.linspace(0.0, 1.0, horizon)
        # Interpolate every (demo, dim) series at once: index arithmetic instead of a loop.
        pos = np.interp(dst, src, np.arange(traj.shape[1], dtype=np.float64))
        lo = np.floor(pos).astype(int)
        hi = np.minimum(lo + 1, traj.shape[1] - 1)
        w = (pos - lo)[None, :, None]
        return ((1 - w) * traj[:, lo] + w * traj[:, hi]).astype(np.float32)

    def resample(self, horizon: int) -> Demonstrations:
        """The same demonstrations with ``horizon`` points each (linear in time)."""
        return Demonstrations(self.resample_array(self.trajectories, horizon), self.task_index,
                              self.task_names, self.start)

    # -- files -------------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write an uncompressed ``.npz`` (suffix added by numpy if missing)."""
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {
            "trajectories": self.trajectories,
            "task_index": self.task_index,
            "task_names": np.array(self.task_names, dtype=np.str_),
        }
        if self.start is not None:
            arrays["start"] = self.start
        np.savez(path, **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path, horizon: int | None = None) -> Demonstrations:
        """Read and validate a demonstrations file.

        ``horizon``: resample to this many points first (for recordings whose length is not a
        multiple of 8). Raises :class:`DemonstrationError` with one line naming the problem.
        """
        path = Path(path)
        if not path.is_file():
            raise DemonstrationError(f"demonstrations file {path} does not exist")
        try:
            loaded = np.load(path, allow_pickle=False)
            if not isinstance(loaded, np.lib.npyio.NpzFile):
                raise DemonstrationError(f"{path}: expected an .npz archive, got a single array")
            with loaded as data:
                unknown = sorted(set(data.files) - set(_KEYS))
                if unknown:
                    raise DemonstrationError(f"{path}: unknown array(s) {', '.join(unknown)}; "
                                             f"expected {', '.join(_KEYS)}")
                missing = [k for k in _KEYS[:3] if k not in data.files]
                if missing:
                    raise DemonstrationError(f"{path}: missing array(s) {', '.join(missing)}")
                arrays = {k: data[k] for k in data.files}
        except DemonstrationError:
            raise
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise DemonstrationError(f"{path}: not a readable .npz file ({exc})") from exc
        traj = arrays["trajectories"]
        try:
            if horizon is not None:
                if traj.ndim != 3:
                    raise DemonstrationError(f"trajectories must have shape (N, H, d), got "
                                             f"{traj.shape}")
                traj = cls.resample_array(traj, horizon)
            return cls(traj, arrays["task_index"], tuple(arrays["task_names"].reshape(-1)),
                       arrays.get("start"))
        except DemonstrationError as exc:
            raise DemonstrationError(f"{path}: {exc}") from None


def _finite32(values: np.ndarray) -> np.ndarray:
    """Which values are finite once cast to float32 (what the policy stores and trains on)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return np.isfinite(np.asarray(values).astype(np.float32))


def _walk(amp: float, step: float, horizon: int) -> np.ndarray:
    """(horizon, 2) points of the arc y = amp * sin(pi x), x in [0, 1], walked at a constant
    ``step`` length per point and padded at the goal once reached."""
    s = np.linspace(0.0, 1.0, 512)
    arc_pts = np.stack([s, amp * np.sin(np.pi * s)], axis=-1)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(arc_pts, axis=0), axis=1))])
    at = np.minimum(np.arange(horizon) * step, arc[-1])
    return np.stack([np.interp(at, arc, arc_pts[:, 0]), np.interp(at, arc, arc_pts[:, 1])], -1)


def two_route_demos(n_per_route: int = 32, horizon: int = 16, seed: int = 0,
                    ) -> tuple[Demonstrations, np.ndarray]:
    """Toy planar demonstrations with two motion modes per task, for tests and first runs.

    Task "right" goes (0, 0) -> (1, 0) either by a short route below the line (peak y about
    -0.3, done after about half the horizon) or by a long route above it (peak y about 0.75,
    done after about three quarters). Task "up" is the same mirrored on the diagonal,
    (0, 0) -> (0, 1). The robot walks at a constant speed, so the long route finishes later:
    completion time and mode are tied, as in the fetch world's "middle" and "outside" routes.
    Returns the demonstrations and the route of each, 0 = short, 1 = long.
    """
    if n_per_route < 1:
        raise ValueError(f"n_per_route must be >= 1, got {n_per_route}")
    rng = np.random.default_rng(seed)
    step = 0.16 * 16 / horizon
    trajs, tasks, routes = [], [], []
    for task in (0, 1):
        for route, peak in ((0, -0.3), (1, 0.75)):
            for _ in range(n_per_route):
                p = _walk(peak * rng.uniform(0.9, 1.1), step * rng.uniform(0.95, 1.05), horizon)
                trajs.append(p[:, ::-1] if task == 1 else p)
                tasks.append(task)
                routes.append(route)
    demos = Demonstrations(np.array(trajs), np.array(tasks), ("right", "up"))
    return demos, np.array(routes)
