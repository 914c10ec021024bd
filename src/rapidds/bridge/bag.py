"""rosbag2 bags through ``rosbags``: write MCAP (what ``ros2 bag`` and Foxglove open), read MCAP
or SQLite (a bag folder with ``metadata.yaml``, or a bare ``.mcap`` / ``.db3`` file), and ROS 1
bags (``.bag``, as franka_ros labs record), whose messages come decoded by the message
definitions the bag carries (ROS 1 names its types ``pkg/Type``; rosbags gives them as
``pkg/msg/Type``, the ROS 2 spelling the rest of rapidds matches on; a ROS 1 header has a
``seq`` more, which nothing here reads).

Reading never stops at a bad message: one that does not decode, or whose type rapidds does not
know, is logged in one line and dropped, and the rest of the bag is read.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from rapidds.bridge.ros2 import MessageError, deserialize, typestore
from rapidds.errors import RapiddsError

__all__ = ["BagMessage", "read_bag", "write_bag"]

log = logging.getLogger("rapidds.bridge")


@dataclass(frozen=True)
class BagMessage:
    """One message of a bag: its topic, ROS 2 type, receive (log) time in ns and content."""

    topic: str
    msgtype: str
    time_ns: int
    msg: Any


def write_bag(path: str | Path, messages: Iterable[BagMessage],
              storage: Literal["mcap", "sqlite3"] = "mcap") -> Path:
    """Write ``messages`` as a rosbag2 bag and return what was written.

    ``mcap``: ``path`` is one ``.mcap`` file (the bag's only storage file; ``ros2 bag play``,
    Foxglove and ``mcap_ros2`` read it without the folder's ``metadata.yaml``). ``sqlite3``:
    ``path`` is a bag folder. Either appears whole or not at all: the bag is written beside it
    under a temporary name and renamed into place.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = Path(path)
    if path.exists():
        raise RapiddsError(f"{path} exists already; choose another name")
    parent = path.parent if str(path.parent) else Path(".")
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=parent, prefix=f".{path.name}."))
    try:
        bag = tmp / (path.stem if storage == "mcap" else path.name)
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        with Writer(bag, version=9, storage_plugin=plugin) as writer:
            conns: dict[tuple[str, str], Any] = {}
            for m in messages:
                key = (m.topic, m.msgtype)
                if key not in conns:
                    conns[key] = writer.add_connection(m.topic, m.msgtype, typestore=typestore())
                writer.write(conns[key], int(m.time_ns),
                             typestore().serialize_cdr(m.msg, m.msgtype))
        if storage == "mcap":
            (written,) = bag.glob("*.mcap")
            os.replace(written, path)
        else:
            os.replace(bag, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path


def read_bag(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """The messages of a rosbag2 bag in receive-time order (of ``topics`` only, if given);
    undecodable messages and unknown types are logged and dropped. RapiddsError when the bag
    itself cannot be opened."""
    from rosbags.rosbag2 import Reader

    path = Path(path)
    wanted = None if topics is None else set(topics)
    if path.suffix == ".bag" and path.is_file():
        yield from _read_ros1(path, wanted)
        return
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises its own errors, yaml's, sqlite's, OSError
        raise RapiddsError(f"{path}: not a readable rosbag2 bag ({exc})") from None
    known = typestore().types
    try:
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        for c in conns:
            if c.msgtype not in known:
                log.warning("%s: topic %s has type %s, which rapidds does not read; dropped",
                            path, c.topic, c.msgtype)
        conns = [c for c in conns if c.msgtype in known]
        if not conns:
            return
        for conn, t, raw in reader.messages(connections=conns):
            try:
                msg = deserialize(raw, conn.msgtype)
            except MessageError as exc:
                log.warning("%s: %s at %d ns: %s; dropped", path, conn.topic, t, exc)
                continue
            yield BagMessage(conn.topic, conn.msgtype, int(t), msg)
    finally:
        reader.close()


def _read_ros1(path: Path, wanted: set[str] | None) -> Iterator[BagMessage]:
    """The messages of a ROS 1 bag (:func:`read_bag`'s contract)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS1_NOETIC))
        reader.open()
    except Exception as exc:  # rosbags' own errors, OSError, a file that is no bag
        raise RapiddsError(f"{path}: not a readable ROS 1 bag ({exc})") from None
    try:
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        for conn, t, raw in reader.messages(connections=conns) if conns else ():
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:  # a definition rosbags cannot use, truncated data
                log.warning("%s: %s at %d ns: not a %s (%s); dropped", path, conn.topic, t,
                            conn.msgtype, exc)
                continue
            yield BagMessage(conn.topic, conn.msgtype, int(t), msg)
    finally:
        reader.close()
