"""rmw_zenoh's naming on the Zenoh wire: topic key expressions, liveliness tokens, QoS strings,
entity GIDs and the sample attachment. Pure: strings and bytes, no I/O.

As rmw_zenoh defines them (its docs/design.md and rmw_zenoh_cpp/src/detail/liveliness_utils.cpp,
attachment_helpers.cpp; rmw_zenoh 0.2.x for Jazzy, 0.6.x for Kilted, Rolling):

- a topic's data:      `<domain_id>/<topic name without the outer slashes>/<DDS type>/<type hash>`
- an entity's token:   `@ros2_lv/<domain_id>/<session zid>/<node id>/<entity id>/<NN|MP|MS>/
  <enclave>/<namespace>/<node name>[/<topic>/<DDS type>/<type hash>/<QoS>]`, every part with `/`
  replaced by `%` ("mangled"), so the root namespace `/` is `%`;
- the QoS part: `reliability:durability:history,depth:deadline_s,deadline_ns:lifespan_s,
  lifespan_ns:liveliness,lease_s,lease_ns`, each value left empty when it is rmw_zenoh's
  default (reliable, volatile, keep last 42, infinite durations, automatic liveliness);
- the attachment every sample carries: the Zenoh serialization of (int64 sequence number,
  int64 source timestamp in ns, std::array<uint8_t, 16> GID): 8 + 8 bytes little-endian, then
  the array as a sequence (LEB128 length 16) and its 16 bytes, 33 bytes in all.
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"
GID_BYTES = 16
ATTACHMENT_BYTES = 8 + 8 + 1 + GID_BYTES
_ATTACHMENT = struct.Struct(f"<qqB{GID_BYTES}s")

# rmw/types.h policy numbers
RELIABLE, BEST_EFFORT = 1, 2
TRANSIENT_LOCAL, VOLATILE = 1, 2
KEEP_LAST, KEEP_ALL = 1, 2
_DEFAULT_DEPTH = 42  # rmw_zenoh's default history depth


class WireError(ValueError):
    """A name or attachment that rmw_zenoh's format cannot carry, or a malformed one."""


@dataclass(frozen=True, slots=True)
class Qos:
    """The QoS policies a liveliness token carries (durations are left at their infinite
    defaults: cablebot sets no deadline, lifespan or lease)."""

    reliability: int = RELIABLE
    durability: int = VOLATILE
    history: int = KEEP_LAST
    depth: int = 10


def qos_keyexpr(qos: Qos) -> str:
    """The QoS part of a liveliness token, rmw_zenoh's encoding (defaults left empty):
    reliable, volatile, keep last 10 -> `::,10:,:,:,,`."""
    rel = "" if qos.reliability == RELIABLE else str(qos.reliability)
    dur = "" if qos.durability == VOLATILE else str(qos.durability)
    hist = "" if qos.history == KEEP_LAST else str(qos.history)
    depth = "" if qos.depth == _DEFAULT_DEPTH else str(qos.depth)
    return f"{rel}:{dur}:{hist},{depth}:,:,:,,"


def mangle(name: str) -> str:
    """A ROS name as one key-expression chunk: every `/` becomes `%`."""
    return name.replace("/", "%")


def topic_key(domain_id: int, topic: str, dds_type: str, type_hash: str) -> str:
    """The key expression of a topic's samples, e.g.
    `0/cablebot/pose/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_...`.
    Raises WireError for a topic that is not an absolute ROS name."""
    if not topic.startswith("/") or "//" in topic or topic.endswith("/") or len(topic) < 2:
        raise WireError(f"not an absolute ROS topic name: {topic!r}")
    return f"{int(domain_id)}/{topic.strip('/')}/{dds_type}/{type_hash}"


def node_token(
    domain_id: int, zid: str, node_id: int, namespace: str, node_name: str, enclave: str = "/"
) -> str:
    """The liveliness token that declares a node (NN); its entity id is its node id."""
    return (
        f"{ADMIN_SPACE}/{int(domain_id)}/{zid}/{node_id}/{node_id}/{NODE}/"
        f"{mangle(enclave)}/{mangle(namespace)}/{mangle(node_name)}"
    )


def endpoint_token(
    kind: str,
    domain_id: int,
    zid: str,
    node_id: int,
    entity_id: int,
    namespace: str,
    node_name: str,
    topic: str,
    dds_type: str,
    type_hash: str,
    qos: Qos,
    enclave: str = "/",
) -> str:
    """The liveliness token that declares a publisher (`kind` MP) or a subscription (MS) of
    node `node_id` on `topic`. Raises WireError for another kind."""
    if kind not in (PUBLISHER, SUBSCRIPTION):
        raise WireError(f"entity kind must be {PUBLISHER} or {SUBSCRIPTION}, got {kind!r}")
    return (
        f"{ADMIN_SPACE}/{int(domain_id)}/{zid}/{node_id}/{entity_id}/{kind}/"
        f"{mangle(enclave)}/{mangle(namespace)}/{mangle(node_name)}/"
        f"{mangle(topic)}/{mangle(dds_type)}/{mangle(type_hash)}/{qos_keyexpr(qos)}"
    )


def gid(token: str) -> bytes:
    """A 16-byte GID for the entity declared by liveliness `token`.

    rmw_zenoh derives its GIDs from the token too (XXH3-128); receivers treat the GID as an
    opaque identity of the sender, so a 16-byte BLAKE2b digest of the same string serves and
    needs no extra dependency.
    """
    return hashlib.blake2b(token.encode("utf-8"), digest_size=GID_BYTES).digest()


def encode_attachment(sequence_number: int, source_timestamp_ns: int, source_gid: bytes) -> bytes:
    """The attachment of one sample (33 bytes). Raises WireError for a GID that is not 16
    bytes, struct.error for numbers outside int64."""
    if len(source_gid) != GID_BYTES:
        raise WireError(f"a GID is {GID_BYTES} bytes, got {len(source_gid)}")
    return _ATTACHMENT.pack(sequence_number, source_timestamp_ns, GID_BYTES, source_gid)


def decode_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source timestamp ns, GID) of an attachment. Raises WireError if it
    is not exactly the 33-byte positional form."""
    if len(data) != ATTACHMENT_BYTES:
        raise WireError(f"an attachment is {ATTACHMENT_BYTES} bytes, got {len(data)}")
    seq, stamp, n, g = _ATTACHMENT.unpack(data)
    if n != GID_BYTES:
        raise WireError(f"the GID must be a {GID_BYTES}-byte sequence, got length {n}")
    return int(seq), int(stamp), bytes(g)
