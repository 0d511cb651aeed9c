"""rmw_zenoh's mapping of the ROS 2 graph onto Zenoh (pure: strings and bytes).

Upstream is the spec: ros2/rmw_zenoh ``docs/design.md`` ("Topic and Service name mapping to
Zenoh key expressions", "Graph Cache", "Publishers") and its source,
``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp`` (the token's parts, ``mangle_name``,
``qos_to_keyexpr``, the GID as XXH3-128 of the token), ``qos.cpp`` (the defaults a QoS
string leaves out) and ``attachment_helpers.cpp`` (the attachment).

* a topic's data travels on ``<domain_id>/<fully qualified name without its leading
  slash>/<DDS type name>/<RIHS01 hash>`` (:func:`topic_key`), CDR payloads;
* every node, publisher and subscription holds a liveliness token:
  ``@ros2_lv/<domain_id>/<zid>/<node id>/<node id>/NN/<enclave>/<namespace>/<node name>``
  and ``@ros2_lv/<domain_id>/<zid>/<node id>/<entity id>/MP|MS/<enclave>/<namespace>/
  <node name>/<topic>/<type>/<hash>/<qos>``, names mangled (``/`` -> ``%``);
* each sample carries an attachment: int64 sequence number, int64 source timestamp [ns
  since the Unix epoch], both little-endian, then the GID's length (1 byte, 16) and its 16
  bytes (:func:`attachment`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import StrEnum

import xxhash

from swarm.errors import DecodeError
from swarm.net.ros2.interfaces import TYPE_HASHES, dds_type_name

ADMIN_SPACE = "@ros2_lv"
GID_BYTES = 16  # RMW_GID_STORAGE_SIZE since Jazzy
_ATTACHMENT = struct.Struct("<qqB")


class Entity(StrEnum):
    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"


def qos_key(depth: int = 10, best_effort: bool = False, transient_local: bool = False) -> str:
    """The QoS part of a token (``qos_to_keyexpr``): each field left empty where it equals
    rmw_zenoh's own default (reliable, volatile, keep last 42, infinite durations,
    automatic liveliness). ``depth`` 10 is rclcpp's default profile: ``::,10:,:,:,,``."""
    reliability = "2" if best_effort else ""  # RMW_QOS_POLICY_RELIABILITY_BEST_EFFORT
    durability = "1" if transient_local else ""  # RMW_QOS_POLICY_DURABILITY_TRANSIENT_LOCAL
    return f"{reliability}:{durability}:,{'' if depth == 42 else depth}:,:,:,,"


def mangle(name: str) -> str:
    return name.replace("/", "%")


def fqn(namespace: str, *parts: str) -> str:
    """The fully qualified name ``/<namespace>/<parts...>`` (an empty namespace: none)."""
    return "/" + "/".join(p for p in (namespace.strip("/"), *parts) if p)


def topic_key(domain_id: int, name: str, ros_type: str, type_hash: str | None = None) -> str:
    """The key expression of a topic's data (``TopicInfo``'s ``topic_keyexpr_``); the hash
    is the shipped one (:data:`TYPE_HASHES`) unless given."""
    return f"{domain_id}/{name.strip('/')}/{dds_type_name(ros_type)}/{type_hash or TYPE_HASHES[ros_type]}"


@dataclass(frozen=True)
class Node:
    """A ROS 2 node of one Zenoh session: ``zid`` the session's id as Zenoh prints it."""

    domain_id: int
    zid: str
    node_id: int
    name: str
    namespace: str = "/"
    enclave: str = "/"

    def token(self) -> str:
        return "/".join(
            [
                ADMIN_SPACE,
                str(self.domain_id),
                self.zid,
                str(self.node_id),
                str(self.node_id),
                Entity.NODE.value,
                mangle(self.enclave),
                mangle(self.namespace),
                mangle(self.name),
            ]
        )

    def endpoint_token(
        self, entity_id: int, kind: Entity, topic: str, ros_type: str, qos: str, type_hash: str | None = None
    ) -> str:
        """The token of a publisher or subscription of this node on ``topic`` (its fully
        qualified name)."""
        node = self.token().split("/")
        node[4], node[5] = str(entity_id), kind.value
        return "/".join([*node, mangle(topic), dds_type_name(ros_type), type_hash or TYPE_HASHES[ros_type], qos])


def gid(token: str) -> bytes:
    """The entity's GID as rmw_zenoh makes it: XXH3-128 of its liveliness token, the low
    64 bits then the high 64, each little-endian (``Entity::Entity``)."""
    h = xxhash.xxh3_128_intdigest(token.encode())
    return (h & (2**64 - 1)).to_bytes(8, "little") + (h >> 64).to_bytes(8, "little")


def attachment(seq: int, t_ns: int, source_gid: bytes) -> bytes:
    """A sample's attachment: sequence number, source time [ns since the Unix epoch], GID."""
    return _ATTACHMENT.pack(seq, t_ns, len(source_gid)) + source_gid


def read_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source time [ns], GID) of an attachment; DecodeError if malformed."""
    if len(data) < _ATTACHMENT.size:
        raise DecodeError(f"attachment: {len(data)} bytes, need at least {_ATTACHMENT.size}")
    seq, t_ns, n = _ATTACHMENT.unpack_from(data)
    if len(data) != _ATTACHMENT.size + n:
        raise DecodeError(f"attachment: GID of {n} bytes in {len(data)} bytes")
    return seq, t_ns, data[_ATTACHMENT.size :]
