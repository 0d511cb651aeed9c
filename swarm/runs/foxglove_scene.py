"""A run's 3-D scene as Foxglove messages, built from the swarm's own messages (no I/O).

The recorder (``swarm.runs.record``) feeds every decoded clock and collision record to a
:class:`Scene` and writes what it returns to ``run.mcap`` (and, with ``--live``, to
Foxglove's WebSocket server). Topics and their Foxglove schemas:

* ``/tf`` ``foxglove.FrameTransforms``: ``world`` to each drone's body frame (its id), at
  every clock (the recorded rate). Simulated drones carry their attitude; a drone the
  clock gives only a position (a real one, through motion capture) is drawn level.
* ``/scene`` ``foxglove.SceneUpdate`` at ``scene_hz``: the obstacles to scale (spheres, and
  cylinders ``CYLINDER_LENGTH_M`` long about their axis), moving ones where they are; each
  drone's airframe (two arms, in its body frame) and its bounding sphere; its trail over
  the last ``trail_s`` (a point every ``TRAIL_DT_S``); and one persistent red marker per collision where it began.
* ``/log`` ``foxglove.Log``: the processes' log lines (:meth:`Scene.log`).

Schemas come from foxglove-sdk (``foxglove.messages``), each message's ``encode()`` is
its protobuf payload and ``get_schema()`` its published schema.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
from typing import Any

import numpy as np
from foxglove import messages as fg

from swarm.net.messages import CLOCK_MEAS, CLOCK_XVR

TF_TOPIC, SCENE_TOPIC, LOG_TOPIC = "/tf", "/scene", "/log"
WORLD_FRAME = "world"
CYLINDER_LENGTH_M = 6.0  # a long obstacle is drawn this long, centred on its given point
TRAIL_DT_S = 0.05  # s of sim time between two points of a trail
ARM_M = 0.092  # Crazyflie 2.1 motor-to-motor diagonal [m], one arm of the X
_OBSTACLE = fg.Color(r=0.55, g=0.6, b=0.7, a=0.9)
_DRONE = fg.Color(r=0.1, g=0.45, b=0.95, a=1.0)
_BOUND = fg.Color(r=0.1, g=0.45, b=0.95, a=0.18)
_TRAIL = fg.Color(r=0.95, g=0.55, b=0.1, a=0.9)
_CONTACT = fg.Color(r=0.9, g=0.05, b=0.05, a=0.9)


def stamp(t_s: float) -> fg.Timestamp:
    """A Foxglove timestamp of sim time ``t_s`` [s] (never negative)."""
    ns = max(0, round(t_s * 1e9))
    return fg.Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def quat_z_to(a: Any) -> np.ndarray:
    """The rotation (x, y, z, w) taking +z to the direction of ``a`` (3,) [world]: a
    cylinder's pose (Foxglove's and Rerun's cylinders lie along their +z)."""
    a = np.asarray(a, dtype=float)
    n = float(np.linalg.norm(a))
    if n < 1e-9:
        return np.array([0.0, 0.0, 0.0, 1.0])
    a = a / n
    if a[2] < -1.0 + 1e-9:  # opposite of z: half a turn about x
        return np.array([1.0, 0.0, 0.0, 0.0])
    q = np.array([-a[1], a[0], 0.0, 1.0 + a[2]])  # (z x a, 1 + z.a), normalised
    return q / np.linalg.norm(q)


def _quat(q: np.ndarray) -> fg.Quaternion:
    return fg.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))


def _yaw(angle_rad: float) -> fg.Quaternion:
    return fg.Quaternion(x=0.0, y=0.0, z=math.sin(angle_rad / 2), w=math.cos(angle_rad / 2))


def _point(v: Any) -> fg.Point3:
    return fg.Point3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _pose(c: Any, q: fg.Quaternion | None = None) -> fg.Pose:
    return fg.Pose(position=fg.Vector3(x=float(c[0]), y=float(c[1]), z=float(c[2])), orientation=q or _IDENTITY)


_IDENTITY = fg.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)


def obstacle_entity(item: dict, t_s: float) -> fg.SceneEntity:
    """One obstacle item of a clock (``id``, ``shape``, centre ``c`` [m], radius ``r`` [m],
    axis ``a``) to scale, in the world frame."""
    d = 2.0 * float(item["r"])
    cylinders, spheres = [], []
    if any(item["a"]):
        size = fg.Vector3(x=d, y=d, z=CYLINDER_LENGTH_M)
        pose = _pose(item["c"], _quat(quat_z_to(item["a"])))
        cylinders.append(fg.CylinderPrimitive(pose=pose, size=size, bottom_scale=1.0, top_scale=1.0, color=_OBSTACLE))
    else:
        spheres.append(fg.SpherePrimitive(pose=_pose(item["c"]), size=fg.Vector3(x=d, y=d, z=d), color=_OBSTACLE))
    return fg.SceneEntity(
        timestamp=stamp(t_s), frame_id=WORLD_FRAME, id=f"obstacle/{item['id']}", cylinders=cylinders, spheres=spheres
    )


def drone_entity(drone_id: str, radius_m: float, t_s: float) -> fg.SceneEntity:
    """A drone's airframe (an X of two arms, ``ARM_M`` tip to tip) and its bounding sphere
    of ``radius_m`` [m], in its body frame (moved by ``/tf``)."""
    arm = fg.Vector3(x=ARM_M * math.sqrt(2.0), y=0.012, z=0.01)
    arms = [
        fg.CubePrimitive(pose=_pose((0, 0, 0), _yaw(a)), size=arm, color=_DRONE) for a in (math.pi / 4, -math.pi / 4)
    ]
    d = 2.0 * radius_m
    bound = fg.SpherePrimitive(pose=_pose((0, 0, 0)), size=fg.Vector3(x=d, y=d, z=d), color=_BOUND)
    label = fg.TextPrimitive(
        pose=_pose((0, 0, radius_m + 0.05)),
        billboard=True,
        font_size=14.0,
        scale_invariant=True,
        color=_DRONE,
        text=drone_id,
    )
    return fg.SceneEntity(
        timestamp=stamp(t_s), frame_id=drone_id, id=f"drone/{drone_id}", cubes=arms, spheres=[bound], texts=[label]
    )


class Scene:
    """Builds ``/tf``, ``/scene`` and ``/log`` messages from a run's clock, collision and log
    records. ``trail_s`` [s] of trail per drone; a scene update at most ``scene_hz`` [Hz]
    of sim time (the transforms go at every clock)."""

    def __init__(self, trail_s: float = 5.0, scene_hz: float = 10.0) -> None:
        self.trail_s = trail_s
        self.scene_dt_s = 1.0 / scene_hz
        self._last_scene_t = -math.inf
        self._trails: dict[str, deque[tuple[float, fg.Point3]]] = {}
        self._radius: dict[str, float] = {}
        self._where: dict[str, np.ndarray] = {}  # drone id -> last body centre [m, world]
        self.collisions = 0

    def on_clock(self, rec: dict) -> list[tuple[str, Any]]:
        """(topic, message) pairs for one decoded clock record."""
        t = float(rec["t"])
        ids = list(rec["ids"])
        xvr = np.asarray(rec["xvr"], dtype=float).reshape(len(ids), CLOCK_XVR)
        attitude = {}
        meas = np.asarray(rec["meas"], dtype=float).reshape(len(rec["meas_ids"]), CLOCK_MEAS)
        for i, name in enumerate(rec["meas_ids"]):
            attitude[name] = meas[i, 6:10]
        transforms = []
        for i, name in enumerate(ids):
            x = xvr[i, 0:3]
            self._where[name] = x
            self._radius[name] = float(xvr[i, 6])
            trail = self._trails.setdefault(name, deque())
            if not trail or t - trail[-1][0] >= TRAIL_DT_S - 1e-9:  # a point each TRAIL_DT_S, made once
                trail.append((t, _point(x)))
            while trail[0][0] < t - self.trail_s:
                trail.popleft()
            q = attitude.get(name)
            rot = _IDENTITY if q is None else _quat(q)
            transforms.append(
                fg.FrameTransform(
                    timestamp=stamp(t),
                    parent_frame_id=WORLD_FRAME,
                    child_frame_id=name,
                    translation=fg.Vector3(x=float(x[0]), y=float(x[1]), z=float(x[2])),
                    rotation=rot,
                )
            )
        out: list[tuple[str, Any]] = [(TF_TOPIC, fg.FrameTransforms(transforms=transforms))]
        if t - self._last_scene_t >= self.scene_dt_s - 1e-9:
            self._last_scene_t = t
            out.append((SCENE_TOPIC, self._scene(t, ids, rec["items"])))
        return out

    def _scene(self, t: float, ids: Iterable[str], items: list[dict]) -> fg.SceneUpdate:
        entities = [obstacle_entity(it, t) for it in items]
        for name in ids:
            entities.append(drone_entity(name, self._radius[name], t))
            pts = [pt for _, pt in self._trails[name]]
            if len(pts) >= 2:
                line = fg.LinePrimitive(
                    type=fg.LinePrimitiveLineType.LineStrip,
                    pose=_pose((0, 0, 0)),
                    thickness=2.0,
                    scale_invariant=True,
                    points=pts,
                    color=_TRAIL,
                )
                entities.append(
                    fg.SceneEntity(timestamp=stamp(t), frame_id=WORLD_FRAME, id=f"trail/{name}", lines=[line])
                )
        return fg.SceneUpdate(entities=entities)

    def on_collision(self, rec: dict) -> list[tuple[str, Any]]:
        """A persistent marker where a contact between ``a`` and ``b`` began (between their
        last known body centres; at one of them when the other is an obstacle)."""
        t = float(rec["t"])
        where = [self._where[n] for n in (rec["a"], rec["b"]) if n in self._where]
        if not where:
            return []
        c = np.mean(where, axis=0)
        self.collisions += 1
        d = 0.12
        mark = fg.SpherePrimitive(pose=_pose(c), size=fg.Vector3(x=d, y=d, z=d), color=_CONTACT)
        text = fg.TextPrimitive(
            pose=_pose(c + np.array([0.0, 0.0, 0.1])),
            billboard=True,
            font_size=14.0,
            scale_invariant=True,
            color=_CONTACT,
            text=f"{rec['a']} x {rec['b']}",
        )
        entity = fg.SceneEntity(
            timestamp=stamp(t), frame_id=WORLD_FRAME, id=f"collision/{self.collisions}", spheres=[mark], texts=[text]
        )
        return [(SCENE_TOPIC, fg.SceneUpdate(entities=[entity]))]

    @staticmethod
    def log(t_s: float, name: str, line: str) -> tuple[str, Any]:
        """One process's log line: level from its words (error, warning, else info)."""
        low = line.lower()
        if "error" in low or "traceback" in low or "failed" in low:
            level = fg.LogLevel.Error
        elif "warn" in low or "stall" in low or "lost" in low:
            level = fg.LogLevel.Warning
        else:
            level = fg.LogLevel.Info
        return LOG_TOPIC, fg.Log(timestamp=stamp(t_s), level=level, message=line, name=name)


SCHEMAS: dict[str, Any] = {TF_TOPIC: fg.FrameTransforms, SCENE_TOPIC: fg.SceneUpdate, LOG_TOPIC: fg.Log}
"""Topic -> its foxglove-sdk message class (``get_schema()`` gives the published schema)."""
