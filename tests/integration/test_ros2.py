"""The swarm seen and steered from ROS 2 (issue 54), against a ROS 2 client no one here
wrote: zenoh-ros2-sdk (pure-Python ROS 2 over rmw_zenoh's Zenoh mapping), joining the run's
router with the run's ``ros2`` credentials exactly as ``<run>/secrets/ros2.env`` tells a user
to. It lists the topics with their types from the liveliness tokens, takes a drone's poses
(which are the positions the recording holds for the same sim time), publishes a goal that
the drone then flies to, and lands the swarm; the access control lets the ROS 2 participant
publish the goal, land and stop topics and nothing else. Every wait is on liveliness or on
messages, with a deadline."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from swarm.net import transport as tp
from swarm.net.messages import encode
from swarm.ros2.participant import ENV_FILE, read_env
from swarm.runs.runfiles import read_records

from .conftest import scenario

sdk = pytest.importorskip("zenoh_ros2_sdk")
MSGS = Path(__file__).resolve().parents[1] / "data" / "ros2_msgs"  # upstream .msg files (README there)


class Poses:
    """A zenoh-ros2-sdk subscription to a PoseStamped topic: (stamp [s], position) in order."""

    def __init__(self, topic: str) -> None:
        self.got: list[tuple[float, np.ndarray]] = []
        self.cond = threading.Condition()
        self.sub = sdk.ROS2Subscriber(topic, "geometry_msgs/msg/PoseStamped", self._on, node_name="c3swarm_test")

    def _on(self, msg) -> None:
        p, s = msg.pose.position, msg.header.stamp
        with self.cond:
            self.got.append((s.sec + 1e-9 * s.nanosec, np.array([p.x, p.y, p.z])))
            self.cond.notify_all()

    def wait(self, ok, timeout_s: float, what: str) -> tuple[float, np.ndarray]:
        """The first pose from now on for which ``ok(position)`` holds."""
        deadline = time.monotonic() + timeout_s
        with self.cond:
            seen = len(self.got)
            while True:
                for t, x in self.got[seen:]:
                    if ok(x):
                        return t, x
                seen = len(self.got)
                left = deadline - time.monotonic()
                assert left > 0, f"no pose {what} within {timeout_s} s (last: {self.got[-1:]})"
                self.cond.wait(left)


def leave_ros2() -> None:
    """Close zenoh-ros2-sdk's session, while the run's router still runs: closed after the router
    had gone, it blocked for ever now and then, and every Zenoh session opened in this process
    after it too. Bounded: a close that does not return in 15 s fails the test."""
    if sdk.ZenohSession._instance is None:
        return
    closing = threading.Thread(target=sdk.ZenohSession._instance.close, daemon=True)
    closing.start()
    closing.join(15.0)
    sdk.ZenohSession._instance = None
    assert not closing.is_alive(), "zenoh-ros2-sdk's session did not close within 15 s"


@pytest.fixture
def ros2_client(monkeypatch):
    """zenoh-ros2-sdk configured from a run's ros2.env (set by the test through ``join``); a
    test leaves (:func:`leave_ros2`) before it finishes its run, and the fixture after a failure
    (before ``start_run`` finishes the runs)."""
    sdk.get_registry().messages_dir = MSGS  # no network: the upstream definitions shipped with the tests

    def join(h) -> None:
        for k, v in read_env(h.secrets / ENV_FILE).items():
            monkeypatch.setenv(k, v)
        sdk.ZenohSession.get_instance(h.cfg.network.host, h.cfg.network.port)

    yield join
    leave_ros2()


def wait_topics(h, want: dict[str, str], timeout_s: float = 30.0) -> dict[str, list[str]]:
    """``ros2 topic list -t`` (the SDK's, from liveliness tokens) until it lists ``want``."""
    deadline = time.monotonic() + timeout_s
    while True:
        listed = dict(sdk.get_topic_names_and_types(domain_id=h.cfg.ros2.domain_id))
        if all(listed.get(t) == [ty] for t, ty in want.items()) or time.monotonic() > deadline:
            return listed


def test_a_ros2_client_sees_steers_and_lands_the_swarm(start_run, ros2_client):
    # (the shipped config's lab world: the drones' thrust off their model, which the agents estimate)
    cfg = scenario("ros2_swap_2.yaml", duration_s=120.0, stop_when_all_reached=False, time={"mode": "lockstep"})
    h = start_run(cfg, "ros2")
    ros2_client(h)
    want = {
        "/cf1/pose": "geometry_msgs/msg/PoseStamped",
        "/cf2/velocity": "geometry_msgs/msg/TwistStamped",
        "/cf1/filter_status": "diagnostic_msgs/msg/DiagnosticStatus",
        "/cf2/goal": "geometry_msgs/msg/PoseStamped",
        "/all/land": "std_msgs/msg/Empty",
        "/all/stop": "std_msgs/msg/Empty",
        "/tf": "tf2_msgs/msg/TFMessage",
        "/clock": "rosgraph_msgs/msg/Clock",
        "/obstacles": "visualization_msgs/msg/MarkerArray",
    }
    listed = wait_topics(h, want)
    for topic, ros_type in want.items():
        assert listed.get(topic) == [ros_type], (topic, listed)

    poses = Poses("/cf1/pose")
    poses.wait(lambda x: True, 30.0, "at all")
    goal = np.array([2.0, 1.5, 1.4])
    pub = sdk.ROS2Publisher("/cf1/goal", "geometry_msgs/msg/PoseStamped", node_name="c3swarm_test_goal")
    types = pub.session_mgr.store.types
    header = types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="world"
    )
    point = types["geometry_msgs/msg/Point"](x=goal[0], y=goal[1], z=goal[2])
    quat = types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    pub.publish(header=header, pose=types["geometry_msgs/msg/Pose"](position=point, orientation=quat))
    t_goal, x_goal = poses.wait(lambda x: np.linalg.norm(x - goal) < cfg.goal_tolerance_m, 60.0, "at the goal")

    land = sdk.ROS2Publisher("/all/land", "std_msgs/msg/Empty", node_name="c3swarm_test_land")
    land.publish()
    floor = cfg.agents[0].filter.floor_z_m
    t_land, x_land = poses.wait(lambda x: x[2] < floor + 0.05, 60.0, "landed to the floor")
    assert np.linalg.norm(x_land[:2] - goal[:2]) < 0.15  # straight down from where it was
    leave_ros2()
    h.finish("test done")

    # every pose the client took is the recorded measurement of cf1 at the same sim time
    recorded = {
        round(r["t"], 6): np.asarray(r["x"])
        for r in read_records(h.out / "run.mcap")
        if r.get("kind") == "measurement" and r.get("agent") == "cf1"
    }
    matched = [np.array_equal(recorded[round(t, 6)], x) for t, x in poses.got if round(t, 6) in recorded]
    assert len(matched) > 20 and all(matched), (len(matched), len(poses.got))
    bridge_log = (h.out / "logs" / "ros2.log").read_text()
    assert "cf1 goal [2.0, 1.5, 1.4]" in bridge_log and "land for all" in bridge_log, bridge_log[-2000:]


def _ros2_session(h, user: str) -> zenoh.Session:
    """A plain Zenoh session linked to the run's router as ``user`` (the ROS 2 participant's
    credentials, or another process's)."""
    from swarm.net import access

    conf = tp.session_config(mode="client", connect=[f"tcp/{h.cfg.network.host}:{h.cfg.network.port}"])
    conf.insert_json5(
        "transport/auth/usrpwd", f'{{"user": "{user}", "password": "{access.password(h.secrets, user)}"}}'
    )
    return tp.open_session(conf)


def test_a_ros2_participant_may_publish_goals_and_nothing_else(start_run, ros2_client):
    from swarm.net.ros2.topics import Kind, run_topics

    cfg = scenario("ros2_swap_2.yaml", duration_s=120.0, stop_when_all_reached=False, time={"mode": "lockstep"})
    h = start_run(cfg, "ros2_acl")
    h.wait_sim_time(0.5)
    ros2_client(h)  # the bridge's subscription to /cf1/goal is declared (its liveliness token) before any put
    listed = wait_topics(h, {"/cf1/goal": "geometry_msgs/msg/PoseStamped"})
    assert listed.get("/cf1/goal") == ["geometry_msgs/msg/PoseStamped"], listed
    leave_ros2()
    keys = tp.Keys(h.run)
    topics = {(t.kind, t.agent): t.key(0) for t in run_topics("", ["cf1", "cf2"])}
    ros = _ros2_session(h, "ros2")
    try:
        watch = h.session  # the launcher hears everything of the run and of the domain
        heard = {
            "pose": tp.open_channel(watch, topics[(Kind.POSE, "cf1")]),
            "command": tp.open_channel(watch, keys.command("cf1")),
            "to_agent": tp.open_channel(watch, keys.ros2_goal("cf1")),
            "goal": tp.open_channel(watch, topics[(Kind.GOAL, "cf1")]),
        }
        # its own topic, allowed (the bridge drops it), put until the launcher hears it: then the router
        # knows the launcher's subscriptions, declared before it on the same link, and would route a forgery
        s, deadline = None, time.monotonic() + 10.0
        while s is None and time.monotonic() < deadline:
            ros.put(topics[(Kind.GOAL, "cf1")], b"\x00\x01\x00\x00")
            s = tp.wait_sample(heard["goal"], time.monotonic() + 0.2)
        assert s is not None, "the participant's goal topic was refused"
        forged = b"\x00\x01\x00\x00forged"
        for _ in range(3):  # each forgery from the ROS 2 participant's own session, with its credentials
            ros.put(topics[(Kind.POSE, "cf1")], forged)  # a drone's pose: the bridge's topic
            ros.put(keys.command("cf1"), forged)  # a command for cf1: the run's key
            as_bridge = encode("goal", h.run, "ros2-bridge", 1, 0.0, 0, action="goal", x=np.zeros(3))
            ros.put(keys.ros2_goal("cf1"), as_bridge)
            ros.put(topics[(Kind.GOAL, "cf1")], b"\x00\x01\x00\x00")  # its own topic: allowed (the bridge drops it)
        # what the router let through has arrived once the genuine traffic after it has (one link, in order)
        for name in ("pose", "command"):
            got, deadline = [], time.monotonic() + 30.0
            while len(got) < 30 and time.monotonic() < deadline:
                s = tp.wait_sample(heard[name], deadline)
                if s is not None:
                    got.append(tp.payload(s))
            assert len(got) >= 30, f"no genuine {name} messages"
            assert forged not in got, f"a forged {name} went through"
        assert not list(tp.drain(heard["to_agent"])), "the participant reached an agent's goal key"
    finally:  # closed while the router runs (a session left open on a killed router stalled the next open)
        ros.close()
    h.finish("test done")
    log = (h.out / "logs" / "ros2.log").read_text()
    assert "dropped a message on /cf1/goal" in log, log[-2000:]


def test_the_run_as_a_ros2_bag_that_rosbags_reads(start_run):
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    cfg = scenario("ros2_swap_2.yaml", time={"mode": "lockstep"}, ros2={"enabled": True, "bag": True})
    h = start_run(cfg, "ros2_bag")
    assert h.wait() == "completed"
    bag = h.out / "ros2_bag"
    (mcap_file,) = bag.glob("*.mcap")
    with open(mcap_file, "rb") as f:
        summary = make_reader(f).get_summary()
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    recorded = {
        round(r["t"], 6): np.asarray(r["x"])
        for r in read_records(h.out / "run.mcap")
        if r.get("kind") == "measurement" and r.get("agent") == "cf2"
    }
    with AnyReader([bag]) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        assert topics["/cf2/pose"] == "geometry_msgs/msg/PoseStamped" and topics["/tf"] == "tf2_msgs/msg/TFMessage"
        poses = [c for c in reader.connections if c.topic == "/cf2/pose"]
        n = 0
        for conn, t_ns, raw in reader.messages(connections=poses):
            msg = reader.deserialize(raw, conn.msgtype)
            p = msg.pose.position
            t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            assert t_ns == round(t * 1e9)
            np.testing.assert_array_equal(recorded[round(t, 6)], [p.x, p.y, p.z])
            n += 1
    assert n == len(recorded) > 100  # every measurement of the run, each once
