"""The live link: ROS 2 messages (CDR) over Zenoh, keyed as zenoh-bridge-ros2dds keys topics.

The planner is the hub: it listens (``tcp/127.0.0.1:7447`` by default) as a Zenoh router; the
nodes (a robot driver, a tracker, the reference simulators) connect to it as Zenoh clients,
wait for it when it is not up yet and reconnect when it restarts (``--resume``). Multicast
scouting is off, so nothing is found or reached that was not named: the link stays on localhost
unless told otherwise. A ROS 2 graph joins through zenoh-bridge-ros2dds (topic ``/a/b`` <->
key ``a/b``), or a ROS 2 node on rmw_zenoh directly (``wire``, :mod:`.wire`). Across
machines, ``config`` (``--zenoh-config``, :mod:`.zenoh_config`) puts the link under Zenoh's
mutual TLS and access control.

Received samples are decoded on Zenoh's thread and queued; the owner reads them in its own
thread with :meth:`Link.receive`, so no handler ever runs concurrently with the loop. A sample
that does not decode as its topic's type is logged in one line and dropped; so is a sample on a
key nobody subscribed to (it cannot happen with exact keys, but a lab's bridge may route more).
"""

from __future__ import annotations

import json
import logging
import queue
import re
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from rapidds.bridge.faults import FaultLog, size_limit
from rapidds.bridge.ros2 import MessageError, deserialize, serialize, zenoh_key
from rapidds.bridge.wire import Wire
from rapidds.bridge.zenoh_config import LinkConfig, session_config
from rapidds.errors import RapiddsError

__all__ = ["ALIVE_PREFIX", "DEFAULT_ENDPOINT", "Link", "LinkError", "Received", "StampGate",
           "check_endpoint", "log"]

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
log = logging.getLogger("rapidds.bridge")
ALIVE_PREFIX = "/rapidds/alive/"
"""A node's liveliness token (``/rapidds/alive/<node>/<session id>``, Zenoh liveliness): a hub
that watches (``watch=True``) receives ``Received(ALIVE_PREFIX + node/id, True | False, ...)``
when the node joins or leaves the link (its process ends, its connection drops). The session
id tells a restarted node from the one it replaces."""
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic)/(\[[0-9a-fA-F:]+\]|[A-Za-z0-9.\-]+):(\d{1,5})$")


class LinkError(RapiddsError):
    """The link cannot be opened (a bad endpoint, a port in use, Zenoh missing)."""


def check_endpoint(endpoint: str) -> str:
    """``endpoint`` if it reads PROTO/HOST:PORT (e.g. tcp/127.0.0.1:7447); LinkError otherwise."""
    m = _ENDPOINT.match(endpoint)
    if m is None or not 0 < int(m.group(3)) < 65536:
        raise LinkError(f"bad endpoint {endpoint!r}: expected PROTO/HOST:PORT, "
                        f"e.g. {DEFAULT_ENDPOINT}")
    return endpoint


@dataclass(frozen=True)
class Received:
    """A decoded message: its ROS 2 topic, the message and the wall time it arrived (ns)."""

    topic: str
    msg: Any
    received_ns: int


class Link:
    """One Zenoh session: a hub (``listen``: a Zenoh router) or a node (``connect``: a client
    of the hub, waiting for it to come up), no scouting.

    ``topics``: ROS 2 topic -> message type to subscribe to; their samples are decoded into
    :class:`Received` and queued for :meth:`receive`.
    """

    def __init__(self, topics: Mapping[str, str], *, listen: str | None = None,
                 connect: str | None = None, alive: str | None = None, watch: bool = False,
                 config: LinkConfig | None = None, wire: Wire | None = None):
        try:
            import zenoh
        except ImportError:
            raise LinkError("the live link needs eclipse-zenoh; pip install eclipse-zenoh") \
                from None
        conf = session_config(config, listen or connect or "")  # --zenoh-config: TLS, ACL
        # The hub routes between its nodes (two peers behind a third do not hear each other);
        # a node is a client that waits for the hub and reconnects when it comes back.
        conf.insert_json5("mode", '"router"' if listen else '"client"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        if not listen:
            conf.insert_json5("connect/timeout_ms", "-1")
            conf.insert_json5("connect/exit_on_failure", "false")
        conf.insert_json5("listen/endpoints",
                          json.dumps([check_endpoint(listen)] if listen else []))
        conf.insert_json5("connect/endpoints",
                          json.dumps([check_endpoint(connect)] if connect else []))
        try:
            self._session = zenoh.open(conf)
        except Exception as exc:  # zenoh raises its own ZError for a busy port
            where = listen or connect
            raise LinkError(f"cannot open the Zenoh link on {where}: "
                            f"{str(exc).strip().splitlines()[0] if str(exc).strip() else exc}") \
                from None
        self._inbox: queue.Queue[Received] = queue.Queue()
        self.faults = FaultLog()
        self._wire = Wire() if wire is None else wire  # --wire: whose keys, attachments
        self._wire.start(self._session)
        self._types = {self._wire.subscribe(t, kind): (t, kind) for t, kind in topics.items()}
        self._subs = [self._session.declare_subscriber(key, self._on_sample)
                      for key in self._types]
        if watch:  # history: the nodes already on the link are announced too
            self._subs.append(self._session.liveliness().declare_subscriber(
                zenoh_key(ALIVE_PREFIX) + "/**", self._on_alive, history=True))
        self._token = (None if alive is None else self._session.liveliness().declare_token(
            f"{zenoh_key(ALIVE_PREFIX + alive)}/{self._session.zid()}"))
        self._closed = False

    def _on_alive(self, sample: Any) -> None:
        import zenoh

        topic = "/" + str(sample.key_expr)
        self._inbox.put(Received(topic, sample.kind == zenoh.SampleKind.PUT, time.time_ns()))

    def _on_sample(self, sample: Any) -> None:
        key = str(sample.key_expr)
        known = self._types.get(key)
        if known is None:
            self.faults.warn("unknown key", "dropped a message on unknown key %s", key[:160])
            return
        topic, kind = known
        if not self._wire.accept(sample):  # rmw_zenoh's attachment missing or malformed
            self.faults.warn("no attachment", "dropped a message on %s without rmw_zenoh's "
                             "attachment", topic)
            return
        size = len(sample.payload)
        if size > size_limit(topic, kind):  # measured before a byte of it is decoded
            self.faults.warn("oversized", "dropped a message of %d bytes on %s: at most %d",
                             size, topic, size_limit(topic, kind))
            return
        try:
            msg = deserialize(sample.payload.to_bytes(), kind)
        except MessageError as exc:
            self.faults.warn("malformed", "dropped a malformed message on %s: %s", topic,
                             str(exc)[:160])
            return
        self._inbox.put(Received(topic, msg, time.time_ns()))

    def publish(self, topic: str, msg: Any) -> None:
        """Send a message built with :mod:`rapidds.bridge.ros2` on ``topic`` (CDR)."""
        key, options = self._wire.publication(topic, msg.__msgtype__)
        self._session.put(key, serialize(msg), **options)

    def publish_raw(self, topic: str, payload: bytes, msgtype: str | None = None) -> None:
        """Send raw bytes on ``topic`` (what a faulty peer might send; for tests of the gate)."""
        key, options = self._wire.publication(topic, msgtype)
        self._session.put(key, payload, **options)

    def receive(self, timeout: float) -> Received | None:
        """The next decoded message, or None after ``timeout`` seconds without one."""
        try:
            return self._inbox.get(timeout=max(timeout, 0.0))
        except queue.Empty:
            return None

    def drain(self) -> list[Received]:
        """Every message queued now, without waiting."""
        out = []
        while True:
            try:
                out.append(self._inbox.get_nowait())
            except queue.Empty:
                return out

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            for s in self._subs:
                s.undeclare()
            if self._token is not None:
                self._token.undeclare()
            self._wire.close()
            self._session.close()

    def __enter__(self) -> Link:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class StampGate:
    """Drops a stamped message older than the last one accepted from the same source (a topic,
    or a TF child frame): a late or replayed sample would rewrite the past. Logged in one line."""

    def __init__(self, faults: FaultLog | None = None) -> None:
        self._last: dict[str, int] = {}
        self.faults = faults

    def accept(self, source: str, stamp_ns: int) -> bool:
        last = self._last.get(source)
        if last is not None and stamp_ns < last:
            text = "dropped a message on %s stamped %.3f s before the last one"
            if self.faults is None:
                log.warning(text, source, (last - stamp_ns) / 1e9)
            else:
                self.faults.warn("out of order", text, source, (last - stamp_ns) / 1e9)
            return False
        self._last[source] = stamp_ns
        return True
