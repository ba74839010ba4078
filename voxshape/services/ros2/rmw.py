"""What rmw_zenoh puts on zenoh, after ros2/rmw_zenoh docs/design.md and
rmw_zenoh_cpp/src/detail/ (liveliness_utils.cpp, attachment_helpers.cpp, qos.cpp); and the
plain keys of zenoh-bridge-ros2dds (zenoh-plugin-ros2dds ros2_utils.rs). Pure: no zenoh.

- A topic's key: `<domain>/<name without its leading and trailing />/<DDS type>/<RIHS01>`.
- Every sample carries an attachment, which rmw_zenoh's subscriber needs (a sample without
  one is logged "Unable to obtain attachment" and dropped): the publisher's sequence number,
  the source time in ns since the epoch and the publisher's GID, in zenoh-ext's serialization.
  Since rmw_zenoh 0.2.4 (Jazzy) it is 33 bytes: int64 LE, int64 LE, a length byte (16) and
  the 16 GID bytes. Before, 77 bytes: each of the three preceded by its name as a string
  ("sequence_number", "source_timestamp", "source_gid"); the two do not read each other.
- Liveliness tokens make a node and its publishers and subscriptions visible to the ROS graph
  (`ros2 node list`, `ros2 topic info`): `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/
  <NN|MP|MS>/<enclave>/<namespace>/<node name>[/<topic>/<type>/<hash>/<qos>]`, names mangled
  (`/` -> `%`), the QoS written only where it differs from rmw_zenoh's default (reliable,
  volatile, keep last 42).
- zenoh-bridge-ros2dds routes a DDS robot's topics on plain keys, `<namespace>/<name>` without
  the leading `/` and without domain or type, raw CDR, no attachment.
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass
from typing import Literal

from voxshape.services.ros2.msgs import RosType

ADMIN_SPACE = "@ros2_lv"
GID_SIZE = 16
AttachmentFormat = Literal["33", "77"]
ATTACHMENT_FORMATS: tuple[AttachmentFormat, ...] = ("33", "77")
_OLD_KEYS = ("sequence_number", "source_timestamp", "source_gid")


class RmwError(ValueError):
    """A name or an attachment rmw_zenoh would not take; says which and why."""


# -- names and keys ---------------------------------------------------------------------------
def fully_qualified(namespace: str, name: str) -> str:
    """`/ns/name` (a relative name under the namespace; an absolute one as it is)."""
    if name.startswith("/"):
        return name
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{name}"


def check_name(name: str, what: str) -> str:
    """A ROS name's characters (letters, digits, `_`, `/`): a key chunk must not hold more.
    `/` alone is the root namespace."""
    if name == "/":
        return name
    bare = name.replace("/", "")
    if not bare or not all(c.isascii() and (c.isalnum() or c == "_") for c in bare):
        raise RmwError(f"{what} {name!r}: use letters, digits, _ and / (a ROS name)")
    if "//" in name:
        raise RmwError(f"{what} {name!r}: an empty part between two /")
    return name


def topic_key(domain: int, fqn: str, ros_type: RosType) -> str:
    """rmw_zenoh's key of a topic: `0/robot1/chatter/std_msgs::msg::dds_::String_/RIHS01_...`."""
    return f"{domain}/{fqn.strip('/')}/{ros_type.dds_name}/{ros_type.type_hash}"


def ros2dds_key(fqn: str) -> str:
    """zenoh-bridge-ros2dds's key of a topic: the name without its leading `/`."""
    return fqn.strip("/")


def mangle(name: str) -> str:
    return name.replace("/", "%")


# -- QoS, as liveliness_utils.cpp's qos_to_keyexpr writes it ----------------------------------
RELIABLE, BEST_EFFORT = 1, 2  # rmw_qos_reliability_policy_e
TRANSIENT_LOCAL, VOLATILE = 1, 2  # rmw_qos_durability_policy_e
KEEP_LAST, KEEP_ALL = 1, 2  # rmw_qos_history_policy_e
DEFAULT_DEPTH = 42


@dataclass(frozen=True)
class Qos:
    reliability: int = RELIABLE
    durability: int = VOLATILE
    history: int = KEEP_LAST
    depth: int = DEFAULT_DEPTH

    def keyexpr(self) -> str:
        """`<rel>:<dur>:<hist>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<s>,<ns>`,
        each part empty where it is rmw_zenoh's default (deadline, lifespan and liveliness
        always are here)."""

        def given(value: int, default: int) -> str:
            return "" if value == default else str(value)

        return (
            f"{given(self.reliability, RELIABLE)}:{given(self.durability, VOLATILE)}:"
            f"{given(self.history, KEEP_LAST)},{given(self.depth, DEFAULT_DEPTH)}:,:,:,,"
        )


# -- liveliness tokens ------------------------------------------------------------------------
@dataclass(frozen=True)
class RosNodeName:
    """Who the bridge is in the ROS graph: one node of one zenoh session."""

    domain: int
    zid: str  # the zenoh session id, lowercase hex
    name: str
    namespace: str = "/"
    node_id: int = 0
    enclave: str = "/"

    def prefix(self, entity_id: int, kind: str) -> str:
        return (
            f"{ADMIN_SPACE}/{self.domain}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
            f"{mangle(self.enclave)}/{mangle(self.namespace or '/')}/{mangle(self.name)}"
        )


def node_token(node: RosNodeName) -> str:
    return node.prefix(node.node_id, "NN")


def entity_token(
    node: RosNodeName,
    entity_id: int,
    kind: Literal["MP", "MS"],
    fqn: str,
    ros_type: RosType,
    qos: Qos,
) -> str:
    """A publisher's (MP) or subscription's (MS) token on topic `fqn`."""
    topic = f"{mangle(fqn)}/{ros_type.dds_name}/{ros_type.type_hash}/{qos.keyexpr()}"
    return f"{node.prefix(entity_id, kind)}/{topic}"


def entity_gid(token: str) -> bytes:
    """A publisher's 16-byte GID, from its token as rmw_zenoh makes its own (which hashes it
    with XXH3-128; this one with SHA-256: subscribers only tell publishers apart by it)."""
    return hashlib.sha256(token.encode()).digest()[:GID_SIZE]


# -- attachments ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Attachment:
    sequence: int
    timestamp_ns: int
    gid: bytes


def _zstring(text: str) -> bytes:
    raw = text.encode()
    return bytes([len(raw)]) + raw  # a LEB128 length: one byte below 128


def encode_attachment(a: Attachment, fmt: AttachmentFormat = "33") -> bytes:
    if len(a.gid) != GID_SIZE:
        raise RmwError(f"a GID is {GID_SIZE} bytes, got {len(a.gid)}")
    gid = bytes([GID_SIZE]) + a.gid
    if fmt == "33":
        return struct.pack("<qq", a.sequence, a.timestamp_ns) + gid
    seq, stamp, source = (_zstring(k) for k in _OLD_KEYS)
    return (
        seq
        + struct.pack("<q", a.sequence)
        + stamp
        + struct.pack("<q", a.timestamp_ns)
        + (source + gid)
    )


def decode_attachment(raw: bytes) -> tuple[Attachment, AttachmentFormat]:
    """The attachment of a sample and which format it is in; RmwError if neither."""
    for fmt in ATTACHMENT_FORMATS:
        size = 33 if fmt == "33" else 77
        if len(raw) != size:
            continue
        if fmt == "33":
            sequence, stamp = struct.unpack_from("<qq", raw)
            gid_at = 16
        else:
            if raw[:16] != _zstring(_OLD_KEYS[0]):
                break
            (sequence,) = struct.unpack_from("<q", raw, 16)
            (stamp,) = struct.unpack_from("<q", raw, 24 + 17)
            gid_at = 77 - GID_SIZE - 1
        if raw[gid_at] != GID_SIZE:
            break
        return Attachment(sequence, stamp, bytes(raw[gid_at + 1 :])), fmt
    raise RmwError(
        f"an attachment of {len(raw)} bytes is neither rmw_zenoh's 33-byte format (0.2.4 and "
        "later) nor its 77-byte one (before): is the robot's rmw_zenoh that old or new?"
    )
