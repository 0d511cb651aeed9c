"""The ROS 2 message types the bridge speaks, their RIHS01 type hashes, and CDR.

The message definitions and the CDR codec are rosbags' (a maintained pure-Python library
that ships the definitions of every ROS 2 distribution: :data:`STORE`, Jazzy's; Kilted's
are the same for these types). The hashes are shipped here (:data:`TYPE_HASHES`), not
computed or fetched at run time; ``tests/unit/test_ros2.py`` checks them against rosbags'
own for Jazzy and Kilted, against zenoh-ros2-sdk's computation from the upstream ``.msg``
files, and against the examples in ros2/rmw_zenoh ``docs/design.md``.
"""

from __future__ import annotations

from functools import cache
from typing import Any

# REP-2016 type hashes (RIHS01: SHA-256 of the type description), as rosidl generates
# them for ROS 2 Jazzy and Kilted (and `ros2 topic info -v` prints them)
TYPE_HASHES: dict[str, str] = {
    "geometry_msgs/msg/PoseStamped": "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    "geometry_msgs/msg/TwistStamped": "RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64",
    "tf2_msgs/msg/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "visualization_msgs/msg/MarkerArray": "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf",
    "std_msgs/msg/Empty": "RIHS01_20b625256f32d5dbc0d04fee44f43c41e51c70d3502f84b4a08e7a9c26a96312",
    "diagnostic_msgs/msg/DiagnosticStatus": "RIHS01_b0e3e692ea2d54a8af2f4ef1930e81556a2db55216b771f8a7d2724ed47bf0e4",
    "rosgraph_msgs/msg/Clock": "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
}
POSE, TWIST, TF, MARKERS, EMPTY, STATUS, CLOCK = TYPE_HASHES


def dds_type_name(ros_type: str) -> str:
    """The type name as declared in DDS, which rmw_zenoh puts in its keys:
    ``geometry_msgs/msg/PoseStamped`` -> ``geometry_msgs::msg::dds_::PoseStamped_``
    (ros2/rmw_zenoh ``docs/design.md``, "Topic and Service name mapping")."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


@cache
def store() -> Any:
    """rosbags' type store of ROS 2 Jazzy (loaded once per process, about 0.1 s)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def serialize(msg: Any, ros_type: str) -> bytes:
    """CDR (little-endian, with its 4-byte encapsulation header) of ``msg``."""
    return bytes(store().serialize_cdr(msg, ros_type))


def deserialize(data: bytes, ros_type: str) -> Any:
    """The message of CDR ``data``; rosbags raises on a payload too short for the type."""
    return store().deserialize_cdr(data, ros_type)


def message_definition(ros_type: str) -> str:
    """The ``ros2msg`` text of ``ros_type`` with every type it uses (rosbag2's MCAP schema)."""
    return str(store().generate_msgdef(ros_type, ros_version=2)[0])
