"""The run's Foxglove scene, channel schemas and layout, built from records (no processes)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory

from swarm.net.messages import SCHEMAS, json_schema
from swarm.runs.foxglove_layout import run_layout_json
from swarm.runs.foxglove_scene import CYLINDER_LENGTH_M, LOG_TOPIC, SCENE_TOPIC, TF_TOPIC, Scene

ROOT = Path(__file__).resolve().parents[2]


def decode(msg):
    """A foxglove-sdk message through its published schema, as Foxglove would read it."""
    s = type(msg).get_schema()
    decoder = DecoderFactory().decoder_for("protobuf", Schema(id=1, name=s.name, encoding=s.encoding, data=s.data))
    return decoder(msg.encode())


def clock(t, xs, items=(), q=None):
    ids = [f"d{i}" for i in range(len(xs))]
    xvr = np.hstack([np.asarray(xs, float), np.zeros((len(xs), 3)), np.full((len(xs), 1), 0.07)]).ravel()
    meas = (
        []
        if q is None
        else np.hstack(
            [np.asarray(xs, float), np.zeros((len(xs), 3)), np.tile(q, (len(xs), 1)), np.zeros((len(xs), 3))]
        ).ravel()
    )
    return {
        "kind": "clock",
        "t": t,
        "ids": ids,
        "xvr": xvr,
        "meas_ids": ids if q is not None else [],
        "meas": meas,
        "items": list(items),
    }


SPHERE = {"id": "ball", "shape": "sphere", "c": [2.5, 0.0, 1.0], "cd": [0.0, 0.0, 0.0], "r": 0.3, "a": [0, 0, 0]}
POLE = {"id": "pole", "shape": "cylinder", "c": [0.0, 2.0, 0.0], "cd": [0.5, 0.0, 0.0], "r": 0.1, "a": [0, 1.0, 0]}


def test_a_frame_per_drone_at_its_body_centre_with_its_attitude() -> None:
    q = np.array([0.0, 0.0, math.sin(0.3), math.cos(0.3)])
    out = dict(Scene().on_clock(clock(0.5, [[1, 2, 3], [4, 5, 6]], q=q)))
    tf = decode(out[TF_TOPIC])
    assert [t.child_frame_id for t in tf.transforms] == ["d0", "d1"]
    assert {t.parent_frame_id for t in tf.transforms} == {"world"}
    assert (tf.transforms[1].translation.x, tf.transforms[1].translation.z) == (4.0, 6.0)
    assert math.isclose(tf.transforms[0].rotation.z, q[2]) and math.isclose(tf.transforms[0].rotation.w, q[3])
    assert tf.transforms[0].timestamp.seconds == 0 and tf.transforms[0].timestamp.nanos == 500_000_000


def test_obstacles_to_scale_and_moving_ones_where_they_are() -> None:
    sc = decode(dict(Scene().on_clock(clock(0.0, [[0, 0, 1]], [SPHERE, POLE])))[SCENE_TOPIC])
    by_id = {e.id: e for e in sc.entities}
    ball = by_id["obstacle/ball"].spheres[0]
    assert (ball.size.x, ball.size.y, ball.size.z) == (0.6, 0.6, 0.6) and ball.pose.position.x == 2.5
    pole = by_id["obstacle/pole"].cylinders[0]
    assert math.isclose(pole.size.x, 0.2) and pole.size.z == CYLINDER_LENGTH_M
    o = pole.pose.orientation  # takes +z onto the pole's axis (+y)
    qv, w = np.array([o.x, o.y, o.z]), o.w
    z = np.array([0.0, 0.0, 1.0])
    rotated = z + 2 * w * np.cross(qv, z) + 2 * np.cross(qv, np.cross(qv, z))
    assert np.allclose(rotated, [0, 1, 0])
    moved = {**POLE, "c": [0.5, 2.0, 0.0]}
    later = decode(dict(Scene().on_clock(clock(1.0, [[0, 0, 1]], [moved])))[SCENE_TOPIC])
    assert later.entities[0].cylinders[0].pose.position.x == 0.5


def test_drones_trails_and_the_scene_rate() -> None:
    scene = Scene(trail_s=1.0, scene_hz=10.0)
    topics = []
    for k in range(31):  # 100 Hz clocks for 0.3 s
        topics += [t for t, _ in scene.on_clock(clock(0.01 * k, [[0.1 * k, 0, 1]]))]
    assert topics.count(TF_TOPIC) == 31 and topics.count(SCENE_TOPIC) == 4  # t = 0, 0.1, 0.2, 0.3
    sc = decode(scene._scene(0.3, ["d0"], []))
    by_id = {e.id: e for e in sc.entities}
    assert by_id["drone/d0"].frame_id == "d0" and len(by_id["drone/d0"].cubes) == 2
    assert math.isclose(by_id["drone/d0"].spheres[0].size.x, 0.14)
    trail = by_id["trail/d0"].lines[0]
    assert len(trail.points) == 7 and math.isclose(trail.points[-1].x, 3.0)  # a point every 0.05 s


def test_one_persistent_marker_per_collision_and_log_levels() -> None:
    scene = Scene()
    scene.on_clock(clock(1.0, [[1, 1, 1], [1.1, 1, 1]]))
    marks = []
    for k, (a, b) in enumerate([("d0", "d1"), ("d0", "ball")]):
        ((topic, msg),) = scene.on_collision({"kind": "collision", "t": 1.0 + k, "a": a, "b": b, "dead": False})
        marks.append(decode(msg).entities[0])
    assert [m.id for m in marks] == ["collision/1", "collision/2"]
    assert math.isclose(marks[0].spheres[0].pose.position.x, 1.05)  # between the two drones
    assert marks[1].spheres[0].pose.position.x == 1.0  # at the drone (the obstacle has no frame)
    assert not marks[0].HasField("lifetime") or marks[0].lifetime.seconds == 0  # 0: forever
    assert scene.on_collision({"kind": "collision", "t": 3.0, "a": "x", "b": "y", "dead": False}) == []
    topic, log = Scene.log(2.0, "world", "WORLD_SUMMARY {}")
    assert topic == LOG_TOPIC and decode(log).name == "world" and decode(log).level == 2  # INFO
    assert decode(Scene.log(2.0, "agent-cf1", "Traceback (most recent call last):")[1]).level == 4  # ERROR


def test_every_message_kind_has_a_json_schema_with_every_field_described() -> None:
    for kind, fields in SCHEMAS.items():
        s = json_schema(kind)
        assert s["title"] == f"c3swarm.{kind}" and set(fields) <= set(s["properties"])
        assert all(p.get("description") for p in s["properties"].values()), kind
    cmd = json_schema("command")["properties"]
    assert cmd["h_rows"]["type"] == "array" and "[m^2/s]" in cmd["h_rows"]["description"]
    assert cmd["solve_us"]["type"] == "number" and "[us]" in cmd["solve_us"]["description"]
    assert json_schema("state")["properties"]["x"]["maxItems"] == 3


def test_the_shipped_layout_is_the_layout_of_the_default_swap() -> None:
    shipped = (ROOT / "docs" / "foxglove_layout.json").read_text()
    assert json.loads(shipped) == json.loads(run_layout_json(["cf1", "cf2"]))
    text = json.dumps(json.loads(shipped))
    for needle in (
        '"panelType": "ThreeDee"',
        "/agent/cf2/command.min_h",
        "/agent/cf1/command.intervention",
        '"panelType": "StateTransitions"',
        '"topicToRender": "/log"',
        "/agent/cf1/command.monitor",  # the safety monitor's action, and the live margin it widened rows by
        "/agent/cf2/command.live_margin",
    ):
        assert needle in text, needle
