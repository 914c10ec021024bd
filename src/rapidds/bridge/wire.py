"""How the live link names and frames its samples (``--wire``): zenoh-bridge-ros2dds's keys (the
default) or rmw_zenoh's format (:mod:`.rmw_zenoh`). A :class:`~rapidds.bridge.link.Link` asks its
wire for a topic's key, for what to attach to a sample it sends and whether to take one it
received; the rmw_zenoh wire also announces the link's node, publishers and subscriptions with
rmw_zenoh's liveliness tokens, so a ROS 2 graph on rmw_zenoh lists them (``ros2 topic list``).
"""

from __future__ import annotations

import itertools
import time
from typing import Any

from rapidds.bridge import rmw_zenoh
from rapidds.bridge.ros2 import zenoh_key

__all__ = ["WIRES", "RmwZenohWire", "Wire", "make_wire"]

WIRES = ("ros2dds", "rmw-zenoh")
"""The wires ``--wire`` takes: zenoh-bridge-ros2dds keys (default), rmw_zenoh's format."""


class Wire:
    """zenoh-bridge-ros2dds's keys: topic ``/a/b`` is key ``a/b``, samples bare CDR."""

    name = "ros2dds"

    def start(self, session: Any) -> None:
        """Called once the link's session is open."""

    def subscribe(self, topic: str, msgtype: str) -> str:
        """The key to subscribe to for ``topic`` (announcing the subscription where the wire
        announces)."""
        return zenoh_key(topic)

    def publication(self, topic: str, msgtype: str | None) -> tuple[str, dict[str, Any]]:
        """The key of a sample on ``topic`` and the keyword arguments of its ``put``."""
        return zenoh_key(topic), {}

    def accept(self, sample: Any) -> bool:
        """Whether to decode a received sample (its framing is the wire's)."""
        return True

    def close(self) -> None:
        """Withdraw what :meth:`start` and the others announced (before the session closes)."""


class RmwZenohWire(Wire):
    """rmw_zenoh's keys, attachments and liveliness tokens, for one ROS 2 node named ``node``
    in ``ROS_DOMAIN_ID``'s domain."""

    name = "rmw-zenoh"

    def __init__(self, node: str, domain: int | None = None):
        self.node = node
        self.domain = rmw_zenoh.domain_id() if domain is None else domain
        self._session: Any = None
        self._ids = itertools.count(1)  # entity ids within the node (the node itself is 0)
        self._tokens: list[Any] = []
        self._publishers: dict[str, tuple[str, bytes, itertools.count[int]]] = {}

    def _announce(self, key: str) -> None:
        self._tokens.append(self._session.liveliness().declare_token(key))

    def _entity(self, kind: str, topic: str, msgtype: str) -> str:
        name = rmw_zenoh.NodeName(self.domain, str(self._session.zid()), 0, self.node)
        return rmw_zenoh.entity_token(name, next(self._ids), kind, topic, msgtype)

    def start(self, session: Any) -> None:
        self._session = session
        self._announce(rmw_zenoh.node_token(
            rmw_zenoh.NodeName(self.domain, str(session.zid()), 0, self.node)))

    def subscribe(self, topic: str, msgtype: str) -> str:
        self._announce(self._entity("MS", topic, msgtype))
        return rmw_zenoh.data_key(self.domain, topic, msgtype)

    def publication(self, topic: str, msgtype: str | None) -> tuple[str, dict[str, Any]]:
        if msgtype is None:
            raise ValueError("an rmw_zenoh key names the message type; give it")
        if topic not in self._publishers:  # a publisher is announced when it first sends
            token = self._entity("MP", topic, msgtype)
            self._announce(token)
            self._publishers[topic] = (rmw_zenoh.data_key(self.domain, topic, msgtype),
                                       rmw_zenoh.gid_of(token), itertools.count(1))
        key, gid, seq = self._publishers[topic]
        att = rmw_zenoh.Attachment(next(seq), time.time_ns(), gid)
        return key, {"attachment": rmw_zenoh.attachment_bytes(att)}

    def accept(self, sample: Any) -> bool:
        """Only a sample carrying rmw_zenoh's attachment, as rmw_zenoh itself takes."""
        return rmw_zenoh.parse_attachment(sample.attachment) is not None

    def close(self) -> None:
        for token in self._tokens:
            token.undeclare()
        self._tokens.clear()


def make_wire(name: str, node: str) -> Wire:
    """The wire ``--wire NAME`` names, for a link that is the ROS 2 node ``node``."""
    if name == "ros2dds":
        return Wire()
    if name == "rmw-zenoh":
        return RmwZenohWire(node)
    raise rmw_zenoh.WireError(f"unknown --wire {name!r}; one of {', '.join(WIRES)}")
