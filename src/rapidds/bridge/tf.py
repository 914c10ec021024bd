"""TF trees as tf2 composes them: the transforms of ``/tf`` and ``/tf_static`` chained from a
frame up to a root frame, so a skeleton tracker's ``l_wrist`` published relative to its
``l_elbow`` (ROS4HRI, REP-155) is read where it is, not as if it were in the root frame.

tf2's lookup rule, followed here: every frame has one parent; a transform published on
``/tf_static`` holds at every time; one on ``/tf`` is looked up at the query time by
interpolating between the two stamped transforms around it (linear in translation, spherical
linear in rotation), exactly at a stamp when one matches, and not at all outside the stamps
the buffer holds (tf2's ExtrapolationException: that sample is dropped). A frame is queried at
its own header stamps, as ``lookupTransform(root, frame, stamp)`` would be.

ROS4HRI names a tracked body's frames ``<joint>_<body id>`` (``body_<id>``, ``head_<id>``,
``l_wrist_<id>``, ...; REP-155 and ros4hri/human_description); :func:`body_ids` lists the
bodies a tree holds, first seen first, so a mapping can take the first tracked one.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

__all__ = ["BODY", "TfBuffer", "body_ids", "tracked_frames"]

_BODY = re.compile(r"^body_(.+)$")


@dataclass
class _Link:
    """The transforms parent <- child of one frame, as published (stamps in ns)."""

    parent: str
    static: bool
    stamps: list[int] = field(default_factory=list)
    translations: list[np.ndarray] = field(default_factory=list)
    rotations: list[np.ndarray] = field(default_factory=list)  # quaternions [x, y, z, w]

    def at(self, times: np.ndarray) -> tuple[np.ndarray, Rotation, np.ndarray]:
        """(translations (n, 3), rotations, valid (n,) bool) of this link at ``times`` (ns)."""
        n = len(times)
        if self.static:  # the last static transform holds for ever
            t = np.repeat(self.translations[-1][None], n, axis=0)
            return t, Rotation.from_quat(np.repeat(self.rotations[-1][None], n, axis=0)), \
                np.ones(n, bool)
        stamps = np.asarray(self.stamps, np.int64)
        order = np.argsort(stamps, kind="stable")
        # the same stamp published twice: the first is kept (tf2 ignores the second,
        # TF_REPEATED_DATA)
        keep = np.r_[True, stamps[order][1:] != stamps[order][:-1]]
        idx = order[keep]
        s = stamps[idx]
        trans = np.stack(self.translations)[idx]
        quats = np.stack(self.rotations)[idx]
        valid = (times >= s[0]) & (times <= s[-1])
        q = np.clip(times, s[0], s[-1])
        if len(s) == 1:
            return np.repeat(trans, n, axis=0), Rotation.from_quat(np.repeat(quats, n, axis=0)), \
                valid
        hi = np.clip(np.searchsorted(s, q, side="left"), 1, len(s) - 1)
        lo = hi - 1
        w = ((q - s[lo]) / (s[hi] - s[lo]))[:, None]
        t = (1 - w) * trans[lo] + w * trans[hi]
        # times from the first stamp: wall-clock ns lose precision as floats
        rot = Slerp((s - s[0]).astype(float), Rotation.from_quat(quats))((q - s[0]).astype(float))
        return t, rot, valid


class TfBuffer:
    """The transforms of a bag's ``/tf`` and ``/tf_static``, composed on request (module
    docstring). Frames are told apart by name, without a leading ``/`` (tf2 strips it)."""

    def __init__(self) -> None:
        self.links: dict[str, _Link] = {}
        self.seen: list[str] = []  # frames in the order they first appeared
        self.reparented: dict[str, str] = {}  # child -> a second parent, ignored

    def add(self, parent: str, child: str, stamp_ns: int, translation: Iterable[float],
            rotation: Iterable[float], static: bool = False) -> bool:
        """One transform parent <- child (rotation a quaternion [x, y, z, w]); False when it
        is not one (a zero or non-finite quaternion, a non-finite translation)."""
        parent, child = parent.lstrip("/"), child.lstrip("/")
        for f in (child, parent):
            if f not in self.links and f not in self.seen:
                self.seen.append(f)
        link = self.links.get(child)
        if link is None:
            link = self.links[child] = _Link(parent, static)
        elif link.parent != parent:
            self.reparented.setdefault(child, parent)
            return True
        q = np.asarray(list(rotation), float)
        p = np.asarray(list(translation), float)
        norm = np.linalg.norm(q)
        if not (np.isfinite(q).all() and np.isfinite(p).all()) or norm < 1e-9:
            return False
        if static:
            link.static = True
        link.stamps.append(int(stamp_ns))
        link.translations.append(p)
        link.rotations.append(q / norm)
        return True

    def add_message(self, msg: object, static: bool = False,
                    unstamped: int = 0) -> list[tuple[str, int]]:
        """Every transform of a ``tf2_msgs/TFMessage`` (ROS 1 or ROS 2), one stamped 0 taken
        at ``unstamped`` (its receive time: tf2 reads time 0 as "latest"); (child, stamp) of
        each one kept, in order. Transforms that are not are skipped (:meth:`add`)."""
        kept = []
        for tf in msg.transforms:  # type: ignore[attr-defined]
            t, r = tf.transform.translation, tf.transform.rotation
            stamp = int(tf.header.stamp.sec) * 1_000_000_000 + int(tf.header.stamp.nanosec)
            stamp = stamp or unstamped
            if self.add(tf.header.frame_id, tf.child_frame_id, stamp, (t.x, t.y, t.z),
                        (r.x, r.y, r.z, r.w), static):
                kept.append((tf.child_frame_id, stamp))
        return kept

    def chain(self, frame: str, root: str) -> tuple[list[str], str | None]:
        """The frames from ``frame`` up to (not including) ``root``, and None; or, when the
        chain breaks, the frames walked and the first frame without a parent."""
        walked, f, root = [], frame.lstrip("/"), root.lstrip("/")
        while f != root:
            if f in walked or f not in self.links:
                return walked, f
            walked.append(f)
            f = self.links[f].parent
        return walked, None

    def positions(self, frame: str, root: str, stamps_ns: np.ndarray,
                  local: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n, 3) in ``root`` of ``frame``'s origin, or of the points ``local``
        (n, 3) given in ``frame``, valid (n,) bool) at the stamps; a sample is invalid where a
        link of the chain cannot be looked up (extrapolation). ValueError when the chain does
        not reach ``root``."""
        links, broken = self.chain(frame, root)
        if broken is not None:
            raise ValueError(broken)
        times = np.asarray(stamps_ns, np.int64)
        p = np.zeros((len(times), 3)) if local is None else np.asarray(local, float).copy()
        valid = np.ones(len(times), bool)
        for f in links:  # leaf first: p_parent = R p_child + t
            t, rot, ok = self.links[f].at(times)
            p = rot.apply(p) + t
            valid &= ok
        return p, valid


def body_ids(frames: Iterable[str]) -> list[str]:
    """The ROS4HRI body ids of ``body_<id>`` frames, in the order given (first tracked first)."""
    out: list[str] = []
    for f in frames:
        m = _BODY.match(f.lstrip("/"))
        if m and m.group(1) not in out:
            out.append(m.group(1))
    return out


BODY = "{body}"
"""Where a mapping's source names the ROS4HRI body id (``l_wrist_{body}``)."""


def _resolve(buffer: TfBuffer, keys: Iterable[str],
             body_id: str | None) -> tuple[dict[str, str], set[str], list[str]]:
    """(frame -> mapping key with the body id filled in, every tracked body's id, lines)."""
    keys = list(keys)
    ids = body_ids(buffer.seen)
    if not any(BODY in k for k in keys):
        return {k.lstrip("/"): k for k in keys}, set(), []
    lines = []
    if body_id is None:
        if not ids:
            return ({k.lstrip("/"): k for k in keys if BODY not in k}, set(),
                    ["no ROS4HRI body on /tf (no body_<id> frame) for the mapping's "
                     f"{BODY} sources; they are not learned"])
        body_id = ids[0]
        if len(ids) > 1:
            lines.append(f"ROS4HRI bodies {', '.join(ids)} tracked; the first, {body_id!r}, is "
                         "learned, the others dropped (the mapping's body_id chooses)")
    elif ids and body_id not in ids:
        lines.append(f"ROS4HRI body {body_id!r} (the mapping's body_id) is not on /tf (bodies "
                     f"tracked: {', '.join(ids)}); not learned")
    return {k.replace(BODY, body_id).lstrip("/"): k for k in keys}, {*ids, body_id}, lines


def tracked_frames(buffer: TfBuffer, samples: Iterable[tuple[int, str, int]],
                   keys: Iterable[str], root: str, body_id: str | None = None,
                   frames: Iterable[str] = (),
                   ) -> tuple[list[tuple[int, str, int, np.ndarray]], list[str]]:
    """The mapped frames' positions in ``root``: for each (receive ns, frame, stamp ns) of
    ``samples`` whose frame a mapping key names, (receive ns, key, stamp ns, position (3,)),
    in the order given; and one line per thing dropped: a mapped frame whose chain does not
    reach ``root`` (not learned at all), samples a chain cannot be looked up at, a frame that
    changed parent, a frame neither mapped nor on a mapped frame's chain (nor on the chain of
    ``frames``, those other tracked messages are stamped in)."""
    sources, bodies, lines = _resolve(buffer, keys, body_id)
    rows: dict[str, list[tuple[int, int]]] = {}
    for recv, frame, stamp in samples:
        rows.setdefault(frame.lstrip("/"), []).append((recv, stamp))
    needed: set[str] = {f for frame in frames for f in buffer.chain(frame, root)[0]}
    driver: dict[str, str] = {}  # mapped frame -> the frame whose samples time it
    for frame in sources:
        if frame not in buffer.links:
            continue  # a topic, or a frame the bag does not hold (the caller sees it missing)
        walked, gap = buffer.chain(frame, root)
        needed.update(walked)
        moving = next((f for f in walked if not buffer.links[f].static), None)
        if gap is not None:
            lines.append(f"TF frame {frame!r} does not reach the root frame {root!r} (chain "
                         f"{' -> '.join([*walked, gap])}; {gap!r} has no parent); not learned")
        elif moving is None:
            lines.append(f"TF frame {frame!r} is fixed to {root!r} (/tf_static only); not "
                         "learned")
        else:
            # a frame on /tf_static (a skeleton's fixed joint) is sampled when the nearest
            # moving frame of its chain is
            driver[frame] = moving
    for child, parent in buffer.reparented.items():
        lines.append(f"TF frame {child!r} also published under parent {parent!r}; only its "
                     f"first parent, {buffer.links[child].parent!r}, is used")
    for frame in rows:
        if frame not in sources and frame not in needed \
                and not any(frame.endswith(f"_{b}") for b in bodies):
            lines.append(f"{frame!r} is not in the mapping; dropped")
    out: dict[str, list[tuple[int, str, int, np.ndarray]]] = {}
    for frame, moving in driver.items():
        got = rows.get(moving, [])
        if not got:
            continue
        pos, ok = buffer.positions(frame, root, np.array([s for _, s in got], np.int64))
        if not ok.all():
            lines.append(f"TF frame {frame!r}: {int((~ok).sum())} of {len(ok)} samples stamped "
                         "outside the transforms of its chain dropped (tf2 does not extrapolate)")
        out[frame] = [(r, sources[frame], s, p) for (r, s), p, good in zip(got, pos, ok,
                                                                             strict=True)
                      if good]
    merged = sorted((x for v in out.values() for x in v), key=lambda x: x[0])
    return merged, lines
