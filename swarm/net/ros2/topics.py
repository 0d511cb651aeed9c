"""Which ROS 2 topics a run has (pure): what the bridge publishes, and what a ROS 2
participant may publish into the run (a goal per drone, land and stop for all).

Names follow Crazyswarm2's: a drone's topics under ``/<namespace>/<drone>/``, the fleet's
commands under ``/<namespace>/all/``, and ``/tf`` and ``/clock`` at the root as ROS 2 expects
them (a second run on the same domain would share those: give it its own ``domain_id``).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from swarm.net.ros2 import interfaces as ri
from swarm.net.ros2.graph import fqn, qos_key, topic_key


class Kind(StrEnum):
    POSE = "pose"  # out, per drone: its measured pose (geometry_msgs/msg/PoseStamped)
    VELOCITY = "velocity"  # out, per drone: its measured velocity and body rates (TwistStamped)
    STATUS = "filter_status"  # out, per drone: its safety filter's last report (DiagnosticStatus)
    GOAL = "goal"  # in, per drone: fly there (PoseStamped)
    TF = "tf"  # out: world -> each drone (tf2_msgs/msg/TFMessage)
    CLOCK = "clock"  # out: sim time (rosgraph_msgs/msg/Clock)
    OBSTACLES = "obstacles"  # out: the obstacles (visualization_msgs/msg/MarkerArray)
    LAND = "land"  # in, all drones (std_msgs/msg/Empty)
    STOP = "stop"  # in, all drones: hold where they are (std_msgs/msg/Empty)


TYPES = {
    Kind.POSE: ri.POSE,
    Kind.VELOCITY: ri.TWIST,
    Kind.STATUS: ri.STATUS,
    Kind.GOAL: ri.POSE,
    Kind.TF: ri.TF,
    Kind.CLOCK: ri.CLOCK,
    Kind.OBSTACLES: ri.MARKERS,
    Kind.LAND: ri.EMPTY,
    Kind.STOP: ri.EMPTY,
}
INBOUND = (Kind.GOAL, Kind.LAND, Kind.STOP)
PER_DRONE = (Kind.POSE, Kind.VELOCITY, Kind.STATUS, Kind.GOAL)


@dataclass(frozen=True)
class Topic:
    """One ROS 2 topic of the run: its fully qualified ``name``, message type, QoS part of
    its tokens, the drone it is about (None: the fleet's), and whether ROS 2 publishes it
    into the run (``inbound``) or the bridge publishes it."""

    kind: Kind
    name: str
    agent: str | None

    @property
    def ros_type(self) -> str:
        return TYPES[self.kind]

    @property
    def inbound(self) -> bool:
        return self.kind in INBOUND

    @property
    def qos(self) -> str:
        return qos_key(100 if self.kind is Kind.TF else 10)  # tf2's listener and broadcaster keep 100

    def key(self, domain_id: int) -> str:
        return topic_key(domain_id, self.name, self.ros_type)


def run_topics(namespace: str, agent_ids: list[str]) -> list[Topic]:
    """Every topic of a run with these agents under ``namespace`` ("" for none)."""
    out = [Topic(k, fqn(namespace, a, k.value), a) for a in agent_ids for k in PER_DRONE]
    out += [Topic(Kind.OBSTACLES, fqn(namespace, "obstacles"), None)]
    out += [Topic(k, fqn(namespace, "all", k.value), None) for k in (Kind.LAND, Kind.STOP)]
    out += [Topic(Kind.TF, "/tf", None), Topic(Kind.CLOCK, "/clock", None)]
    return out


@dataclass(frozen=True)
class Ros2Keys:
    """The Zenoh keys of a run's ROS 2 side, for its access-control rules
    (``swarm.net.access.acl``): ``bridge`` the keys the bridge publishes, ``inbound`` the
    keys a ROS 2 participant may publish, ``data`` and ``graph`` everything of the domain
    (subscribing) and its liveliness tokens."""

    bridge: tuple[str, ...]
    inbound: tuple[str, ...]
    data: str
    graph: str


def ros2_keys(domain_id: int, namespace: str, agent_ids: list[str]) -> Ros2Keys:
    ts = run_topics(namespace, agent_ids)
    return Ros2Keys(
        bridge=tuple(t.key(domain_id) for t in ts if not t.inbound),
        inbound=tuple(t.key(domain_id) for t in ts if t.inbound),
        data=f"{domain_id}/**",
        graph=f"@ros2_lv/{domain_id}/**",
    )
