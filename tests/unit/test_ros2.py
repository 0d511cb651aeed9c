"""The ROS 2 side of a run without processes (swarm.ros2): the type hashes against three
independent sources, rmw_zenoh's keys, tokens and attachment against the examples in its
design document and against zenoh-ros2-sdk's own builders, the messages' CDR round trip,
the goal's checks and the new course it gives an agent, the config's rules, the
participant's environment and the access-control rules of the run's router."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from swarm.config import resolve
from swarm.errors import ConfigError, DecodeError
from swarm.net import access
from swarm.net.ros2 import graph
from swarm.net.ros2.interfaces import TYPE_HASHES, deserialize, message_definition, serialize
from swarm.net.ros2.topics import TYPES, Kind, ros2_keys, run_topics
from swarm.planning import StaticObstacles
from swarm.ros2 import convert
from swarm.ros2.goals import course, landing_goal
from swarm.ros2.participant import read_env, write_env, zenoh_override
from swarm.rotation import quat_to_R

from .test_access import _may_publish

MSGS = Path(__file__).resolve().parents[1] / "data" / "ros2_msgs"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"  # rmw_zenoh docs/design.md


@pytest.mark.parametrize("store", ["ROS2_JAZZY", "ROS2_KILTED"])
def test_the_shipped_hashes_are_rosbags_own_for_jazzy_and_kilted(store):
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(getattr(Stores, store))
    assert ts.hash_rihs01("std_msgs/msg/String") == STRING_HASH
    for ros_type, h in TYPE_HASHES.items():
        assert ts.hash_rihs01(ros_type) == h, ros_type


def test_the_shipped_hashes_are_what_zenoh_ros2_sdk_computes_from_the_upstream_msg_files():
    sdk_utils = pytest.importorskip("zenoh_ros2_sdk.utils")
    from zenoh_ros2_sdk.message_registry import MessageRegistry

    registry = MessageRegistry(str(MSGS))
    assert sdk_utils.get_type_hash("std_msgs/msg/String", (MSGS / "std_msgs/msg/String.msg").read_text()) == STRING_HASH
    for ros_type, h in TYPE_HASHES.items():
        text = registry.get_msg_file_path(ros_type).read_text()
        deps = sdk_utils.load_dependencies_recursive(ros_type, text, registry)
        assert sdk_utils.get_type_hash(ros_type, msg_definition=text, dependencies=deps) == h, ros_type


def test_keys_and_tokens_are_rmw_zenohs_design_examples():
    # ros2/rmw_zenoh docs/design.md, "Topic and Service name mapping" and "Graph Cache"
    key = graph.topic_key(0, "/robot1/chatter", "std_msgs/msg/String", STRING_HASH)
    assert key == f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    listener = graph.Node(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "listener")
    assert listener.token() == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    sub = listener.endpoint_token(
        10, graph.Entity.SUBSCRIPTION, "/chatter", "std_msgs/msg/String", graph.qos_key(10), STRING_HASH
    )
    assert sub == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/"
        f"{STRING_HASH}/::,10:,:,:,,"
    )
    assert graph.qos_key(7) == "::,7:,:,:,,"  # the talker's
    assert graph.qos_key(42) == "::,:,:,:,,"  # rmw_zenoh's own default depth is left out
    assert graph.qos_key(5, best_effort=True) == "2::,5:,:,:,,"


def test_keys_and_tokens_are_what_zenoh_ros2_sdk_builds():
    keyexpr = pytest.importorskip("zenoh_ros2_sdk.keyexpr")
    from zenoh_ros2_sdk.entity import EndpointEntity, EntityKind, NodeEntity
    from zenoh_ros2_sdk.utils import ros2_to_dds_type

    node = graph.Node(3, "8b20917502ee955ac4476e0266340d5c", 1, "c3swarm_bridge", namespace="/lab")
    theirs = NodeEntity(domain_id=3, session_id=node.zid, node_id=1, node_name=node.name, namespace="/lab")
    assert node.token() == keyexpr.node_liveliness_keyexpr(theirs)
    for i, t in enumerate(run_topics("lab", ["cf1"]), start=2):
        kind = graph.Entity.SUBSCRIPTION if t.inbound else graph.Entity.PUBLISHER
        ep = EndpointEntity(
            node=theirs,
            entity_id=i,
            kind=EntityKind(kind.value),
            name=t.name,
            dds_type_name=ros2_to_dds_type(t.ros_type),
            type_hash=TYPE_HASHES[t.ros_type],
            qos=t.qos,
        )
        assert node.endpoint_token(i, kind, t.name, t.ros_type, t.qos) == keyexpr.endpoint_liveliness_keyexpr(ep)
        assert t.key(3) == keyexpr.topic_keyexpr(3, t.name, ros2_to_dds_type(t.ros_type), TYPE_HASHES[t.ros_type])
    names = {t.name for t in run_topics("lab", ["cf1"])}
    assert {"/lab/cf1/pose", "/lab/cf1/goal", "/lab/all/land", "/lab/obstacles", "/tf", "/clock"} <= names


def test_the_attachment_is_rmw_zenohs_and_the_sdk_reads_it():
    attachment = pytest.importorskip("zenoh_ros2_sdk.attachment")
    gid = graph.gid("@ros2_lv/0/abc/0/1/MP/%/%/n/%t/std_msgs::msg::dds_::Empty_/h/::,10:,:,:,,")
    assert len(gid) == graph.GID_BYTES and gid != graph.gid("@ros2_lv/0/abc/0/2/MP/%/%/n/%t/x/h/q")
    data = graph.attachment(7, 1_700_000_000_123_456_789, gid)
    assert len(data) == 8 + 8 + 1 + 16  # docs/design.md, "Publishers"
    assert graph.read_attachment(data) == (7, 1_700_000_000_123_456_789, gid)
    theirs = attachment.Attachment.from_bytes(data)
    assert (theirs.sequence_id, theirs.timestamp_ns, theirs.gid) == (7, 1_700_000_000_123_456_789, gid)
    with pytest.raises(DecodeError):
        graph.read_attachment(data[:-1])


def test_messages_round_trip_through_cdr_with_their_units_and_frames():
    q = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])  # 90 degrees about z
    pose = deserialize(
        serialize(convert.pose_stamped(2.5, "world", np.array([1.0, -2.0, 0.5]), q), _type("POSE")),
        _type("POSE"),
    )
    assert (pose.header.stamp.sec, pose.header.stamp.nanosec, pose.header.frame_id) == (2, 500_000_000, "world")
    assert [pose.pose.position.x, pose.pose.position.y, pose.pose.position.z] == [1.0, -2.0, 0.5]
    twist = convert.twist_stamped(0.0, "world", np.array([0.1, 0.2, 0.3]), np.array([1.0, 0.0, 0.0]), q)
    ang = twist.twist.angular
    np.testing.assert_allclose([ang.x, ang.y, ang.z], [0.0, 1.0, 0.0], atol=1e-12)  # body x is world y
    tf = convert.tf_message(1.0, "world", ["cf1", "cf2"], np.zeros((2, 3)), np.tile(q, (2, 1)))
    back = deserialize(serialize(tf, _type("TF")), _type("TF"))
    assert [t.child_frame_id for t in back.transforms] == ["cf1", "cf2"]
    items = [{"id": "p", "shape": "cylinder", "r": 0.2, "c": [1.0, 0, 0], "cd": [0, 0, 0], "a": [1.0, 0, 0]}]
    marker = convert.marker_array(0.0, "world", items, {"p": 4.0}).markers[0]
    assert (marker.type, marker.scale.x, marker.scale.z) == (3, 0.4, 4.0)  # CYLINDER, diameter, length
    o = marker.pose.orientation
    R = quat_to_R(np.array([o.x, o.y, o.z, o.w]))
    np.testing.assert_allclose(R @ [0, 0, 1.0], [1.0, 0, 0], atol=1e-12)  # the marker's z along the axis
    assert "MSG: builtin_interfaces/Time" in message_definition("geometry_msgs/msg/PoseStamped")


def test_filter_status_carries_the_monitor_and_its_level_follows_the_monitors_action():
    from swarm.safety.monitor import Action, Breach

    base = {"t": 1.25, "status": "ok", "intervention": 0.5, "solve_us": 80.0, "min_h": 0.2, "row_ids": ["cf2"],
            "h_rows": [0.3], "infeasible": 0, "goal_reached": False, "monitor": 0, "breaches": 0,
            "live_margin": 0.0}  # fmt: skip

    def status(**over):
        msg = deserialize(serialize(convert.filter_status("cf1", {**base, **over}), _type("STATUS")), _type("STATUS"))
        return msg.level, msg.message, {kv.key: kv.value for kv in msg.values}

    level, message, values = status()
    assert (level, message) == (convert.OK, "ok")
    assert (values["monitor"], values["breaches"], values["live_margin_m"]) == ("none", "", "0")
    level, _, values = status(monitor=int(Action.WARN), breaches=int(Breach.TICK_OVERRUN))
    assert level == convert.OK and values["monitor"] == "warn" and values["breaches"] == "tick_overrun"
    both = int(Breach.ESTIMATE_STD | Breach.NEIGHBOUR_AGE)
    level, message, values = status(monitor=int(Action.SLOW), breaches=both, live_margin=0.0375)
    assert (level, message) == (convert.WARN, "ok, monitor: slow")
    assert values["breaches"] == "estimate_std,neighbour_age" and values["live_margin_m"] == "0.0375"
    assert status(monitor=int(Action.HOLD), breaches=int(Breach.ESTIMATE_AGE))[0] == convert.WARN
    level, message, values = status(monitor=int(Action.LAND), breaches=int(Breach.ESTIMATE_LOST))
    assert (level, message, values["monitor"]) == (convert.ERROR, "ok, monitor: land", "land")
    assert status(status="infeasible", monitor=int(Action.LAND))[0] == convert.ERROR
    assert status(status="failed", monitor=int(Action.SLOW))[0] == convert.ERROR  # the filter's own ERROR kept
    old = {k: v for k, v in base.items() if k not in ("monitor", "breaches", "live_margin")}
    assert convert.filter_status("cf1", old).level == convert.OK  # a record from before the monitor
    # the bridge keeps the monitor's fields of the commands it decodes
    from swarm.net.messages import CommandBody, decode, encode_command, record_of
    from swarm.ros2.bridge import STATUS_FIELDS

    body = CommandBody("attitude", np.zeros(4), "ok", monitor=int(Action.LAND), breaches=int(Breach.DISTURBANCE))
    m = decode(encode_command("r", "cf1", 1, 0.5, 60, body), "r", ("command",), STATUS_FIELDS)
    bridged = convert.filter_status("cf1", record_of(m))
    assert bridged.level == convert.ERROR and {kv.key: kv.value for kv in bridged.values}["breaches"] == "disturbance"


def _type(name: str) -> str:
    return TYPES[Kind[name]]


def test_a_goal_is_taken_only_finite_and_in_the_fixed_frame():
    goal = convert.pose_stamped(0.0, "world", np.array([1.0, 2.0, 1.0]), np.array([0, 0, 0, 1.0]))
    np.testing.assert_array_equal(convert.goal_position(goal, "world"), [1.0, 2.0, 1.0])
    goal.header.frame_id = ""
    np.testing.assert_array_equal(convert.goal_position(goal, "world"), [1.0, 2.0, 1.0])
    goal.header.frame_id = "map"
    with pytest.raises(DecodeError, match="frame_id"):
        convert.goal_position(goal, "world")
    goal.header.frame_id = "world"
    goal.pose.position.x = float("nan")
    with pytest.raises(DecodeError, match="finite"):
        convert.goal_position(goal, "world")
    with pytest.raises(Exception):  # noqa: B017 (rosbags raises its own types on a truncated payload)
        deserialize(b"\x00\x01\x00\x00\x01", _type("GOAL"))


def _cfg(**over):
    raw = {
        "version": 1,
        "name": "r",
        "duration_s": 5.0,
        "ros2": {"enabled": True},
        "agents": [{"id": "cf1", "start": [0, 0, 1], "goal": [1, 0, 1]}, {"id": "cf2", "start": [0, 2, 1]}],
    }
    return resolve(raw | over)


def test_a_new_goal_is_planned_from_where_the_agent_is_as_at_its_start():
    walls = [
        {"id": f"w{i}", "shape": "cylinder", "center": [2.0, y, 0.0], "radius_m": 0.2, "axis": [0, 0, 1]}
        for i, y in enumerate([-0.6, -0.3, 0.0, 0.3, 0.6])
    ]
    cfg = _cfg(obstacles=walls, agents=[{"id": "cf1", "start": [0, 0, 1], "goal": [0, 1.5, 1]}])
    me = cfg.agent("cf1")
    still = StaticObstacles.of(list(cfg.obstacles))
    c = course(me, still, me.command_level, np.array([0.5, 0.0, 1.0]), np.array([3.5, 0.0, 1.0]))
    np.testing.assert_array_equal(c.path_w[0], [0.5, 0.0, 1.0])
    np.testing.assert_array_equal(c.path_w[-1], [3.5, 0.0, 1.0])
    assert c.route is not None and len(c.path_w) > 2  # round the wall, not through it
    assert still.clearance(c.path_w).min() > 0.0
    open_sky = course(me, StaticObstacles.of([]), me.command_level, np.zeros(3) + 1.0, np.array([2.0, 1.0, 1.0]))
    assert open_sky.route is None and len(open_sky.path_w) == 2  # straight, as a configured goal is flown
    np.testing.assert_array_equal(landing_goal(me, np.array([1.0, 2.0, 1.5])), [1.0, 2.0, me.filter.floor_z_m])


def test_the_config_puts_ros2_through_the_router_and_refuses_what_it_cannot_name():
    assert _cfg().topology == "router"
    assert resolve(_cfg().model_dump(mode="json") | {"ros2": {"enabled": False}}).topology == "star"
    with pytest.raises(ConfigError, match="ros2.enabled.*router"):
        _cfg(network={"topology": "star"})
    with pytest.raises(ConfigError, match="not a ROS 2 name"):
        _cfg(agents=[{"id": "cf-1", "start": [0, 0, 1]}])
    with pytest.raises(ConfigError, match="ros2.namespace"):
        _cfg(ros2={"enabled": True, "namespace": "/lab"})


def test_the_participants_environment_joins_the_router_with_the_ros2_credentials(tmp_path):
    cfg = _cfg(network={"port": 7499})
    secrets = access.make_secrets(tmp_path / "s", ["cf1", "cf2"])
    env = read_env(write_env(cfg, secrets, secrets))
    assert env["RMW_IMPLEMENTATION"] == "rmw_zenoh_cpp" and env["ROS_DOMAIN_ID"] == "0"
    assert env["ZENOH_CONFIG_OVERRIDE"] == zenoh_override(cfg, secrets)
    pairs = dict(p.split("=", 1) for p in env["ZENOH_CONFIG_OVERRIDE"].split(";"))
    assert pairs["connect/endpoints"] == '["tcp/127.0.0.1:7499"]' and pairs["mode"] == '"client"'
    assert pairs["transport/auth/usrpwd/user"] == '"ros2"'
    assert pairs["transport/auth/usrpwd/password"] == f'"{access.password(secrets, "ros2")}"'
    assert (secrets / "ros2.env").stat().st_mode & 0o077 == 0


def test_at_the_router_a_ros2_participant_may_publish_only_goals_land_and_stop():
    keys = ros2_keys(0, "", ["cf1", "cf2"])
    rules = access.acl("r", ["cf1", "cf2"], flies_commands=False, router="router", ros2=keys)
    topics = {(t.kind, t.agent): t.key(0) for t in run_topics("", ["cf1", "cf2"])}
    for inbound in ((Kind.GOAL, "cf1"), (Kind.GOAL, "cf2"), (Kind.LAND, None), (Kind.STOP, None)):
        assert _may_publish(rules, access.ROS2, topics[inbound], False), inbound
    for out in ((Kind.POSE, "cf1"), (Kind.TF, None), (Kind.CLOCK, None), (Kind.STATUS, "cf2")):
        assert not _may_publish(rules, access.ROS2, topics[out], False), out
        assert _may_publish(rules, access.ROS2_BRIDGE, topics[out], False), out
        assert not _may_publish(rules, "agent-cf1", topics[out], False), out
    for key in ("swarm/r/agent/cf1/command", "swarm/r/ros2/goal/cf1", "swarm/r/world/clock", "0/cf1/anything"):
        assert not _may_publish(rules, access.ROS2, key, False), key
    assert _may_publish(rules, access.ROS2_BRIDGE, "swarm/r/ros2/goal/cf1", False)
    assert not _may_publish(rules, access.ROS2_BRIDGE, "swarm/r/agent/cf1/command", False)
    without = access.acl("r", ["cf1", "cf2"], flies_commands=False, router="router")
    assert not _may_publish(without, access.ROS2, topics[(Kind.GOAL, "cf1")], False)  # ros2 off: nothing
