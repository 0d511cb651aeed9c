"""Crazyswarm2's services on the ROS 2 bridge (pure): their interfaces, names, keys and CDR
(what each request asks of the drones: ``swarm.ros2.services``).

The four services are those Crazyswarm2's server offers per drone and for ``/all``
(IMRCLab/crazyswarm2 ``crazyflie/src/crazyflie_server.cpp``; ``crazyflie_py`` calls them):
``takeoff``, ``land``, ``go_to`` and ``notify_setpoints_stop``. Their request fields are
written here from the package's published interface definitions, IMRCLab/crazyswarm2
``crazyflie_interfaces/srv/{Takeoff,Land,GoTo,NotifySetpointsStop}.srv`` (commit f6154e2d,
MIT): every response is empty. Nothing is read or fetched at run time. Their RIHS01 type
hashes are shipped (:data:`SERVICE_HASHES`); ``tests/unit/test_ros2_services.py`` checks them
against zenoh-ros2-sdk's computation from these definitions, which gives rmw_zenoh's own
example (``example_interfaces/srv/AddTwoInts``, ros2/rmw_zenoh ``docs/design.md``).

rmw_zenoh maps a service to a Zenoh queryable on ``<domain>/<name>/<package>::srv::dds_::
<Type>_/<hash>`` (the service's type and hash, not its request's) and announces it with a
liveliness token of kind ``SS``; a request is a query whose payload is the request's CDR and
whose attachment is the client's (sequence number, time, GID); the reply carries the
response's CDR and an attachment of the same sequence number and GID (rmw_zenoh
``rmw_zenoh_cpp/src/detail/rmw_service_data.cpp``, ``send_response``).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from functools import cache
from typing import Any

from swarm.errors import DecodeError
from swarm.net.ros2.graph import fqn, qos_key, topic_key
from swarm.net.ros2.interfaces import store

PACKAGE = "crazyflie_interfaces"
EMPTY_RESPONSE = "uint8 structure_needs_at_least_one_member"  # rosidl's member of an empty structure
# request definitions (crazyflie_interfaces/srv/*.srv, above the ``---``; the responses are empty)
REQUESTS: dict[str, str] = {
    "Takeoff": "uint8 group_mask\nfloat32 height\nbuiltin_interfaces/Duration duration",
    "Land": "uint8 group_mask\nfloat32 height\nbuiltin_interfaces/Duration duration",
    "GoTo": (
        "uint8 group_mask\nbool relative\ngeometry_msgs/Point goal\nfloat32 yaw\nbuiltin_interfaces/Duration duration"
    ),
    "NotifySetpointsStop": "uint8 group_mask\nuint32 remain_valid_millisecs",
}
# REP-2016 type hashes of the services (RIHS01: the service type, with its request, response and event)
SERVICE_HASHES: dict[str, str] = {
    "crazyflie_interfaces/srv/Takeoff": "RIHS01_c993cbf6ab9f668c9b3f85bf401956a80de5db48243ceedd5e25fdda027cb714",
    "crazyflie_interfaces/srv/Land": "RIHS01_4e9791ea19b8d15570029738e86cccc3825f87b6e60854be62d8d38a9875b208",
    "crazyflie_interfaces/srv/GoTo": "RIHS01_5ef2b5ac82f34a16abf356c3092a7d27006a9ab0dd0b88921c2f457ca293d9dc",
    "crazyflie_interfaces/srv/NotifySetpointsStop": (
        "RIHS01_3bc115f23a897d7733ea1f5a99ffb482466dacb693835f854d51ded802503e83"
    ),
}


class Srv(StrEnum):
    TAKEOFF = "takeoff"
    LAND = "land"
    GO_TO = "go_to"
    NOTIFY_SETPOINTS_STOP = "notify_setpoints_stop"


SRV_TYPES = {
    Srv.TAKEOFF: f"{PACKAGE}/srv/Takeoff",
    Srv.LAND: f"{PACKAGE}/srv/Land",
    Srv.GO_TO: f"{PACKAGE}/srv/GoTo",
    Srv.NOTIFY_SETPOINTS_STOP: f"{PACKAGE}/srv/NotifySetpointsStop",
}
SERVICE_QOS = qos_key(10)  # rmw_qos_profile_services_default: reliable, volatile, keep last 10


def store_name(srv_type: str, part: str) -> str:
    """rosbags' name of a service's ``Request`` or ``Response`` message."""
    package, _, name = srv_type.split("/")
    return f"{package}/srv/msg/{name}_{part}"


@cache
def register() -> Any:
    """The type store with the four services' requests and responses (once per process)."""
    from rosbags.typesys import get_types_from_msg

    ts = store()
    types: dict[str, Any] = {}
    for name, text in REQUESTS.items():
        srv_type = f"{PACKAGE}/srv/{name}"
        types |= get_types_from_msg(text, store_name(srv_type, "Request"))
        types |= get_types_from_msg(EMPTY_RESPONSE, store_name(srv_type, "Response"))
    ts.register(types)
    return ts


@dataclass(frozen=True)
class Service:
    """One service of the run: its kind, fully qualified ``name`` and drone (None: ``/all``)."""

    kind: Srv
    name: str
    agent: str | None

    @property
    def srv_type(self) -> str:
        return SRV_TYPES[self.kind]

    @property
    def type_hash(self) -> str:
        return SERVICE_HASHES[self.srv_type]

    def key(self, domain_id: int) -> str:
        return topic_key(domain_id, self.name, self.srv_type, self.type_hash)


def run_services(namespace: str, agent_ids: list[str]) -> list[Service]:
    """Every service of a run: each of :class:`Srv` per drone and for ``all``."""
    return [
        Service(k, fqn(namespace, who, k.value), a) for a in [*agent_ids, None] for who in [a or "all"] for k in Srv
    ]


def decode_request(data: bytes, srv_type: str) -> Any:
    try:
        return register().deserialize_cdr(data, store_name(srv_type, "Request"))
    except Exception as exc:  # rosbags raises several types on a short or garbled payload
        raise DecodeError(f"not a {srv_type} request ({type(exc).__name__})") from None


def encode_request(srv_type: str, **fields: Any) -> bytes:
    """A request's CDR (for tests and tools)."""
    ts = register()
    name = store_name(srv_type, "Request")
    return bytes(ts.serialize_cdr(ts.types[name](**fields), name))


def empty_response(srv_type: str) -> bytes:
    """The CDR of the service's (empty) response."""
    ts = register()
    name = store_name(srv_type, "Response")
    return bytes(ts.serialize_cdr(ts.types[name](structure_needs_at_least_one_member=0), name))
