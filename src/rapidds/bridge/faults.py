"""Bounds on what the live link lets in, and the log of what it drops.

* **Sizes** (:func:`size_limit`): every message is measured before it is decoded. The
  messages of the contract are small (an event or a stop is a line of JSON, a tracked point 60
  bytes, a joint state a few hundred); a trajectory or a plan grows with the task, so they get
  room for the longest task a world allows (:func:`~rapidds.worlds.bounds.world_task_bound`
  at a fine dt) and no more.
* **Stamps** (:data:`CLOCK_SKEW`): a stamp may lead its arrival by this much (two machines'
  clocks under NTP); one further ahead is a forgery or a broken clock, and an event stamped
  before its cycle's start by more is from another cycle.
* **The fault log** (:class:`FaultLog`): every dropped message is counted by kind; the first
  :data:`LINES_PER_KIND` of a kind in a cycle are logged one line each and the rest summed up
  in one line when the cycle ends (30 000 bad messages gave 30 000 lines).
"""

from __future__ import annotations

import logging
import threading
from collections import Counter

__all__ = ["CLOCK_SKEW", "LINES_PER_KIND", "MAX_LARGE_BYTES", "MAX_SMALL_BYTES", "FaultLog",
           "size_limit"]

log = logging.getLogger("rapidds.bridge")

MAX_SMALL_BYTES = 64 * 1024
"""Largest message of a small type (strings, points, joint states, scalars): a thousand times
what the contract sends, so only a forged or broken message is refused."""
MAX_LARGE_BYTES = 16 * 1024 * 1024
"""Largest trajectory, plan or point cloud: an hour's trajectory of a 7-joint arm at 100 rows a
second (positions, velocities and times: about 10 MiB)."""
_LARGE = ("trajectory_msgs/msg/JointTrajectory", "sensor_msgs/msg/PointCloud2")
CLOCK_SKEW = 1.0
"""Wall seconds a stamp may lead its arrival (or an event lag its cycle's start)."""
LINES_PER_KIND = 5
"""Lines a kind of fault gets in a cycle before the rest are only counted."""


def size_limit(topic: str, msgtype: str) -> int:
    """Largest payload (bytes of CDR) accepted on ``topic`` for a message of ``msgtype``."""
    return MAX_LARGE_BYTES if msgtype in _LARGE or topic == "/rapidds/plan" else MAX_SMALL_BYTES


class FaultLog:
    """Counts dropped input by kind and logs each kind's first lines (module docstring).
    Thread-safe: the link counts on Zenoh's thread, the hub on its own."""

    def __init__(self, lines_per_kind: int = LINES_PER_KIND):
        self.lines_per_kind = lines_per_kind
        self._counts: Counter[str] = Counter()
        self._lock = threading.Lock()

    def warn(self, kind: str, message: str, *args: object, lines: int | None = None) -> None:
        """Count one fault of ``kind``; log ``message % args`` unless the kind had its
        ``lines`` (default :attr:`lines_per_kind`) this cycle."""
        with self._lock:
            self._counts[kind] += 1
            n = self._counts[kind]
        if n <= (self.lines_per_kind if lines is None else lines):
            log.warning(message, *args)

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def summary(self, what: str) -> dict[str, int]:
        """Log one line with every kind's count since the last summary (when there was any
        fault) and start counting afresh; the counts. ``what``: e.g. ``cycle 3``."""
        with self._lock:
            counts, self._counts = dict(self._counts), Counter()
        if counts:
            log.warning("%s: dropped %d message(s): %s", what, sum(counts.values()),
                        ", ".join(f"{k} {n}" for k, n in sorted(counts.items())))
        return counts
