"""ROS 2 on the wire without ROS: rmw_zenoh's format, so a ROS 2 node on rmw_zenoh_cpp (the
middleware ROS 2 is moving to) and rapidds see each other's topics with no bridge between them.

What rmw_zenoh's design document (docs/design.md) specifies, and this module writes and reads:

- **Data keys** ``<domain>/<topic>/<DDS type name>/<type hash>``: the topic without its leading
  slash, the type as DDS names it (``std_msgs/msg/String`` -> ``std_msgs::msg::dds_::String_``)
  and its REP-2011 type hash (``RIHS01_`` + the SHA-256 of the type description's canonical
  JSON), which ``rosbags`` computes from its ROS 2 message definitions. The domain is
  ``ROS_DOMAIN_ID`` (0 by default), as rmw_zenoh reads it.
- **The attachment** every sample carries (rmw_zenoh drops a sample without it): the publisher's
  sequence number (int64, little-endian), the source timestamp (int64 ns since the epoch), then
  the publisher's 16-byte GID prefixed by its length (one byte, 16): Zenoh's own serialisation
  (``zenoh.ext``) of the triple, as rmw_zenoh writes it.
- **Liveliness tokens** ``@ros2_lv/<domain>/<session id>/<node id>/<entity id>/<kind>/<enclave>/
  <namespace>/<node>[/<topic>/<type>/<hash>/<qos>]`` for the node (``NN``) and each publisher
  (``MP``) and subscription (``MS``), names mangled (``/`` -> ``%``), QoS in rmw_zenoh's compact
  form (empty fields are rmw_zenoh's defaults: reliable, volatile, keep-last; the depth given).

Where rmw_zenoh leaves room: a GID only has to be unique per publisher (ROS 2 compares GIDs, never
derives them), so rapidds takes the first 16 bytes of the SHA-256 of the publisher's liveliness
key where rmw_zenoh takes its XXH3-128; sequence numbers start at 1 per publisher.
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass
from typing import Any

from rapidds.errors import RapiddsError

__all__ = ["ADMIN_SPACE", "GID_SIZE", "Attachment", "NodeName", "WireError", "attachment_bytes",
           "data_key", "dds_type_name", "domain_id", "entity_token", "gid_of", "mangle",
           "node_token", "parse_attachment", "qos_key", "type_hash"]

ADMIN_SPACE = "@ros2_lv"
"""rmw_zenoh's hermetic namespace of liveliness tokens (``*`` and ``**`` never match it)."""
GID_SIZE = 16
_MSGTYPE = re.compile(r"(\w+)/(msg|srv)/(\w+)")
_MAX_DOMAIN = 232  # the largest ROS_DOMAIN_ID ROS 2 maps to ports on any platform


class WireError(RapiddsError):
    """A wire option that cannot be spoken (an unknown wire, a bad ROS_DOMAIN_ID)."""


@dataclass(frozen=True)
class Attachment:
    """What rmw_zenoh attaches to a sample: who sent it, which of theirs, when."""

    sequence_number: int
    source_timestamp_ns: int
    gid: bytes


def domain_id(env: dict[str, str] | None = None) -> int:
    """``ROS_DOMAIN_ID`` (0 when unset), as rmw_zenoh reads it; WireError when not 0..232."""
    text = (os.environ if env is None else env).get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    if not text.isdigit() or int(text) > _MAX_DOMAIN:
        raise WireError(f"ROS_DOMAIN_ID={text[:20]!r}: expected an integer 0..{_MAX_DOMAIN}")
    return int(text)


def dds_type_name(msgtype: str) -> str:
    """The DDS name of a ROS 2 type: ``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_``."""
    m = _MSGTYPE.fullmatch(msgtype)
    if m is None:
        raise ValueError(f"{msgtype!r} is not a ROS 2 type name (pkg/msg/Name)")
    return f"{m[1]}::{m[2]}::dds_::{m[3]}_"


def type_hash(msgtype: str) -> str:
    """The REP-2011 type hash (``RIHS01_<sha256>``) of a ROS 2 message type, from rosbags'
    definitions (ROS 2 Jazzy's, as the rest of the bridge)."""
    from rapidds.bridge.ros2 import typestore

    return str(typestore().hash_rihs01(msgtype))


def data_key(domain: int, topic: str, msgtype: str) -> str:
    """The key of a topic's samples: ``<domain>/<topic>/<DDS type>/<type hash>``."""
    return f"{domain}/{topic.strip('/')}/{dds_type_name(msgtype)}/{type_hash(msgtype)}"


def mangle(name: str) -> str:
    """A name inside a liveliness key: each ``/`` becomes ``%`` (``/`` alone is ``%``)."""
    return name.replace("/", "%")


def qos_key(depth: int = 10) -> str:
    """rmw_zenoh's compact QoS: reliability, durability, history,depth, deadline, lifespan,
    liveliness; empty fields are its defaults (reliable, volatile, keep-last, infinite)."""
    return f"::,{depth}:,:,:,,"


@dataclass(frozen=True)
class NodeName:
    """Where a node's liveliness keys start: the ROS domain, the Zenoh session's id, the node's
    id in the session, its name, namespace and enclave."""

    domain: int
    session_id: str
    node_id: int
    name: str
    namespace: str = "/"
    enclave: str = "/"

    def prefix(self, entity_id: int, kind: str) -> str:
        return (f"{ADMIN_SPACE}/{self.domain}/{self.session_id}/{self.node_id}/{entity_id}/"
                f"{kind}/{mangle(self.enclave)}/{mangle(self.namespace)}/{self.name}")


def node_token(node: NodeName) -> str:
    """The liveliness key announcing a node (``NN``)."""
    return node.prefix(node.node_id, "NN")


def entity_token(node: NodeName, entity_id: int, kind: str, topic: str, msgtype: str, *,
                 depth: int = 10) -> str:
    """The liveliness key announcing a publisher (``MP``) or a subscription (``MS``)."""
    if kind not in ("MP", "MS"):
        raise ValueError(f"entity kind {kind!r}: MP or MS")
    return (f"{node.prefix(entity_id, kind)}/{mangle(topic)}/"
            f"{dds_type_name(msgtype)}/{type_hash(msgtype)}/{qos_key(depth)}")


def gid_of(token: str) -> bytes:
    """A publisher's 16-byte GID, stable for its liveliness key."""
    return hashlib.sha256(token.encode()).digest()[:GID_SIZE]


def attachment_bytes(att: Attachment) -> bytes:
    """The attachment as rmw_zenoh writes it: int64 LE, int64 LE, then the GID as a
    length-prefixed byte sequence (Zenoh's serialisation)."""
    from zenoh.ext import Int64, z_serialize

    if len(att.gid) != GID_SIZE:
        raise ValueError(f"a GID has {GID_SIZE} bytes, not {len(att.gid)}")
    return bytes(z_serialize((Int64(att.sequence_number), Int64(att.source_timestamp_ns),
                              bytes(att.gid))).to_bytes())


def parse_attachment(data: Any) -> Attachment | None:
    """The attachment of a received sample (bytes or Zenoh's ZBytes), or None when it is
    missing or not rmw_zenoh's."""
    import zenoh
    from zenoh.ext import Int64, z_deserialize

    if data is None:
        return None
    raw = data if isinstance(data, zenoh.ZBytes) else zenoh.ZBytes(bytes(data))
    if len(raw) != 8 + 8 + 1 + GID_SIZE:
        return None
    try:
        seq, stamp, gid = z_deserialize(tuple[Int64, Int64, bytes], raw)
    except Exception:  # zenoh.ext raises its own ZDeserializeError
        return None
    if len(gid) != GID_SIZE:
        return None
    return Attachment(int(seq), int(stamp), bytes(gid))
