"""Crazyswarm2's services on the ROS 2 bridge without processes (swarm.net.ros2.services,
swarm.ros2.services): the
shipped type hashes against zenoh-ros2-sdk's computation (itself checked against rmw_zenoh's
own example and a published std_srvs hash), the keys and tokens against rmw_zenoh's design
examples and the sdk's builders, the requests' CDR and what each asks of the drones, the goal
an agent flies for them, and who may call them at the router."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.config import load
from swarm.errors import DecodeError
from swarm.net import access
from swarm.net.ros2 import graph
from swarm.net.ros2.services import (
    REQUESTS,
    SERVICE_HASHES,
    SERVICE_QOS,
    Srv,
    decode_request,
    empty_response,
    encode_request,
    register,
    run_services,
)
from swarm.net.ros2.topics import ros2_keys
from swarm.ros2.goals import GOAL, GOAL_RELATIVE, LAND, TAKEOFF, goal_of, move_speed
from swarm.ros2.services import ask_of
from tests.integration.conftest import CONFIGS
from tests.unit.test_ros2 import MSGS

from .test_access import _may_publish

ADD_TWO_INTS = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"  # rmw_zenoh docs/design.md
TRIGGER = "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"  # std_srvs/srv/Trigger (Jazzy)


def test_the_shipped_service_hashes_are_what_zenoh_ros2_sdk_computes_from_the_definitions():
    sdk_utils = pytest.importorskip("zenoh_ros2_sdk.utils")
    from zenoh_ros2_sdk.message_registry import MessageRegistry

    srv_hash = sdk_utils.compute_service_type_hash
    assert srv_hash("example_interfaces/srv/AddTwoInts", "int64 a\nint64 b", "int64 sum") == ADD_TWO_INTS
    assert srv_hash("std_srvs/srv/Trigger", "# empty", "bool success\nstring message") == TRIGGER  # an empty side
    registry = MessageRegistry(str(MSGS))
    assert len(SERVICE_HASHES) == len(REQUESTS) == 4
    for name, request in REQUESTS.items():
        srv_type = f"crazyflie_interfaces/srv/{name}"
        deps = sdk_utils.load_dependencies_recursive(f"{srv_type}_Request", request, registry)
        assert srv_hash(srv_type, request, "# empty", deps) == SERVICE_HASHES[srv_type], srv_type


def test_service_keys_and_tokens_are_rmw_zenohs_and_the_sdks():
    keyexpr = pytest.importorskip("zenoh_ros2_sdk.keyexpr")
    from zenoh_ros2_sdk.entity import EndpointEntity, EntityKind, NodeEntity
    from zenoh_ros2_sdk.utils import ros2_to_dds_type

    # ros2/rmw_zenoh docs/design.md, "Graph Cache": the add_two_ints server's token
    server = graph.Node(2, "f9980ee0495eaafb3e38f0d19e2eae12", 0, "add_two_ints_server")
    token = server.endpoint_token(
        10, graph.Entity.SERVICE, "/add_two_ints", "example_interfaces/srv/AddTwoInts", SERVICE_QOS, ADD_TWO_INTS
    )
    assert token == (
        "@ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/%add_two_ints/"
        f"example_interfaces::srv::dds_::AddTwoInts_/{ADD_TWO_INTS}/::,10:,:,:,,"
    )
    assert graph.topic_key(2, "/add_two_ints", "example_interfaces/srv/AddTwoInts", ADD_TWO_INTS) == (
        f"2/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/{ADD_TWO_INTS}"
    )
    node = graph.Node(0, "8b20917502ee955ac4476e0266340d5c", 0, "c3swarm_bridge")
    theirs = NodeEntity(domain_id=0, session_id=node.zid, node_id=0, node_name=node.name, namespace="/")
    services = run_services("", ["cf1", "cf2"])
    assert {s.name for s in services} == {
        f"/{who}/{k}" for who in ("cf1", "cf2", "all") for k in ("takeoff", "land", "go_to", "notify_setpoints_stop")
    }
    for i, sv in enumerate(services, start=40):
        dds = ros2_to_dds_type(sv.srv_type)
        ep = EndpointEntity(
            node=theirs, entity_id=i, kind=EntityKind.SERVICE, name=sv.name, dds_type_name=dds,
            type_hash=sv.type_hash, qos=SERVICE_QOS,
        )  # fmt: skip
        ours = node.endpoint_token(i, graph.Entity.SERVICE, sv.name, sv.srv_type, SERVICE_QOS, sv.type_hash)
        assert ours == keyexpr.endpoint_liveliness_keyexpr(ep)
        assert sv.key(0) == keyexpr.topic_keyexpr(0, sv.name, dds, sv.type_hash)


def test_requests_round_trip_and_say_what_they_ask():
    ts = register()
    dur = ts.types["builtin_interfaces/msg/Duration"]
    point = ts.types["geometry_msgs/msg/Point"]
    data = encode_request(
        "crazyflie_interfaces/srv/Takeoff", group_mask=0, height=1.0, duration=dur(sec=2, nanosec=5 * 10**8)
    )
    ask = ask_of(Srv.TAKEOFF, decode_request(data, "crazyflie_interfaces/srv/Takeoff"))
    assert ask is not None and ask.action == TAKEOFF and ask.x_w[2] == 1.0 and ask.duration_s == pytest.approx(2.5)
    go = dict(group_mask=0, relative=True, goal=point(x=0.5, y=0.0, z=0.0), yaw=0.0, duration=dur(sec=1, nanosec=0))
    ask = ask_of(
        Srv.GO_TO,
        decode_request(encode_request("crazyflie_interfaces/srv/GoTo", **go), "crazyflie_interfaces/srv/GoTo"),
    )
    assert ask is not None and ask.action == GOAL_RELATIVE and ask.x_w.tolist() == [0.5, 0.0, 0.0]
    absolute = ask_of(
        Srv.GO_TO,
        decode_request(
            encode_request("crazyflie_interfaces/srv/GoTo", **{**go, "relative": False}),
            "crazyflie_interfaces/srv/GoTo",
        ),
    )
    assert absolute is not None and absolute.action == GOAL
    land = decode_request(
        encode_request("crazyflie_interfaces/srv/Land", group_mask=0, height=0.04, duration=dur(sec=2, nanosec=0)),
        "crazyflie_interfaces/srv/Land",
    )
    ask = ask_of(Srv.LAND, land)
    assert ask is not None and ask.action == LAND
    stop = encode_request("crazyflie_interfaces/srv/NotifySetpointsStop", group_mask=0, remain_valid_millisecs=100)
    assert (
        ask_of(Srv.NOTIFY_SETPOINTS_STOP, decode_request(stop, "crazyflie_interfaces/srv/NotifySetpointsStop")) is None
    )
    assert empty_response("crazyflie_interfaces/srv/GoTo") == b"\x00\x01\x00\x00\x00"  # CDR header and the one member
    with pytest.raises(DecodeError, match="not a crazyflie_interfaces/srv/GoTo request"):
        decode_request(b"\x00\x01\x00\x00", "crazyflie_interfaces/srv/GoTo")
    with pytest.raises(DecodeError, match="group"):
        ask_of(
            Srv.TAKEOFF,
            decode_request(
                encode_request(
                    "crazyflie_interfaces/srv/Takeoff", group_mask=2, height=1.0, duration=dur(sec=1, nanosec=0)
                ),
                "crazyflie_interfaces/srv/Takeoff",
            ),
        )
    bad = {**go, "goal": point(x=math.nan, y=0.0, z=1.0)}
    with pytest.raises(DecodeError, match="not finite"):
        ask_of(
            Srv.GO_TO,
            decode_request(encode_request("crazyflie_interfaces/srv/GoTo", **bad), "crazyflie_interfaces/srv/GoTo"),
        )


def test_the_goal_an_agent_flies_for_a_service():
    me = load(CONFIGS / "ros2_swap_2.yaml").agent("cf1")  # floor 0.25 m, speed 1 m/s
    here = np.array([1.0, 2.0, 1.0])
    np.testing.assert_allclose(goal_of(me, GOAL_RELATIVE, np.array([0.5, 0.0, 0.2]), here), [1.5, 2.0, 1.2])
    np.testing.assert_allclose(goal_of(me, TAKEOFF, np.array([0.0, 0.0, 1.5]), here), [1.0, 2.0, 1.5])
    np.testing.assert_allclose(goal_of(me, GOAL, np.array([0.0, 0.0, 1.5]), here), [0.0, 0.0, 1.5])
    assert goal_of(me, GOAL_RELATIVE, np.array([0.0, 0.0, -0.9]), here) is None  # below the floor
    assert goal_of(me, TAKEOFF, np.array([0.0, 0.0, math.nan]), here) is None
    assert move_speed(me, 1.0, 2.0) == pytest.approx(0.5)
    assert move_speed(me, 5.0, 1.0) == pytest.approx(1.0)  # never faster than its own
    assert move_speed(me, 1.0, 0.0) is None  # no duration: its own speed


def test_at_the_router_only_a_ros2_participant_calls_the_services():
    keys = ros2_keys(0, "", ["cf1"])
    rules = access.acl("r", ["cf1"], flies_commands=False, router="router", ros2=keys)
    call = next(k for k in keys.services if "/go_to/" in k)

    def may_query(user: str, key: str) -> bool:
        by_id = {r["id"]: r for r in rules["rules"]}
        subjects = {s["id"]: s for s in rules["subjects"]}
        for pol in rules["policies"]:
            for sid in pol["subjects"]:
                names = subjects[sid].get("usernames")
                if names is not None and user not in names:
                    continue
                for rid in pol["rules"]:
                    r = by_id[rid]
                    if "ingress" in r["flows"] and "query" in r["messages"] and key in r["key_exprs"]:
                        return True
                    if "ingress" in r["flows"] and "query" in r["messages"] and "0/**" in r["key_exprs"]:
                        return True
        return False

    assert may_query("ros2", call)
    for user in ("script", "observer", "agent-cf1", "recorder"):
        assert not may_query(user, call), user
    assert not may_query("ros2", "0/cf1/pose/geometry_msgs::msg::dds_::PoseStamped_/h")
    assert not _may_publish(rules, "ros2", call, False)  # a call is a query, not a put
