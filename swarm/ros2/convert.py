"""Swarm records to ROS 2 messages and back (pure; rosbags' message classes).

Frames and units as ROS expects them (REP-103): metres, seconds, the world frame
``frame_id`` (x, y, z as the swarm's world), quaternions (x, y, z, w) body to world, the
same order as :mod:`swarm.rotation`. Stamps are sim time, so a pose matches the recorded
measurement of the same ``t`` and ROS 2 nodes run with ``use_sim_time`` on ``/clock``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from swarm.errors import DecodeError
from swarm.net.ros2.interfaces import store
from swarm.rotation import FloatArray, quat_to_R
from swarm.safety.monitor import BREACH_NAMES, Action

OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/msg/DiagnosticStatus levels


def _t() -> Any:
    return store().types


def stamp(t_s: float) -> Any:
    """builtin_interfaces/msg/Time of sim time ``t_s`` [s] (>= 0)."""
    ns = round(max(t_s, 0.0) * 1e9)
    return _t()["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_s(time_msg: Any) -> float:
    return float(time_msg.sec) + 1e-9 * float(time_msg.nanosec)


def _header(t_s: float, frame_id: str) -> Any:
    return _t()["std_msgs/msg/Header"](stamp=stamp(t_s), frame_id=frame_id)


def _point(x: Any) -> Any:
    return _t()["geometry_msgs/msg/Point"](x=float(x[0]), y=float(x[1]), z=float(x[2]))


def _vector(x: Any) -> Any:
    return _t()["geometry_msgs/msg/Vector3"](x=float(x[0]), y=float(x[1]), z=float(x[2]))


def _quat(q: Any) -> Any:
    return _t()["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))


def pose_stamped(t_s: float, frame_id: str, x_w: FloatArray, q: FloatArray) -> Any:
    """geometry_msgs/msg/PoseStamped: position ``x_w`` [m, world], attitude ``q`` (x, y, z, w)."""
    t = _t()
    return t["geometry_msgs/msg/PoseStamped"](
        header=_header(t_s, frame_id), pose=t["geometry_msgs/msg/Pose"](position=_point(x_w), orientation=_quat(q))
    )


def twist_stamped(t_s: float, frame_id: str, v_w: FloatArray, w_b: FloatArray, q: FloatArray) -> Any:
    """geometry_msgs/msg/TwistStamped in the world frame: velocity ``v_w`` [m/s] and the body
    rates ``w_b`` [rad/s, body] turned into the world frame by ``q``."""
    t = _t()
    w_w = quat_to_R(np.asarray(q, float)) @ np.asarray(w_b, float)
    return t["geometry_msgs/msg/TwistStamped"](
        header=_header(t_s, frame_id), twist=t["geometry_msgs/msg/Twist"](linear=_vector(v_w), angular=_vector(w_w))
    )


def tf_message(t_s: float, frame_id: str, ids: list[str], x_w: FloatArray, q: FloatArray) -> Any:
    """tf2_msgs/msg/TFMessage: ``frame_id`` -> each drone's body frame (named by its id),
    rows of ``x_w`` (n, 3) [m] and ``q`` (n, 4)."""
    t = _t()
    head = _header(t_s, frame_id)
    return t["tf2_msgs/msg/TFMessage"](
        transforms=[
            t["geometry_msgs/msg/TransformStamped"](
                header=head,
                child_frame_id=name,
                transform=t["geometry_msgs/msg/Transform"](translation=_vector(x_w[i]), rotation=_quat(q[i])),
            )
            for i, name in enumerate(ids)
        ]
    )


def clock(t_s: float) -> Any:
    return _t()["rosgraph_msgs/msg/Clock"](clock=stamp(t_s))


def filter_status(agent_id: str, command: dict[str, Any]) -> Any:
    """diagnostic_msgs/msg/DiagnosticStatus of an agent's last command record (its filter's
    report and its safety monitor's verdict): level OK for a clean solve, WARN for any other
    status or a monitor that slows or holds the drone, ERROR for ``failed`` or a monitor that
    lands it; the message is the status (and the monitor's action when it acts); the values
    are the report's numbers, the monitor's action and breaches (their names, comma-joined) and
    the live margin [m]."""
    t = _t()
    status = str(command["status"])
    level = OK if status == "ok" else ERROR if status == "failed" else WARN
    action = Action(min(max(int(command.get("monitor", 0)), 0), Action.LAND))
    if action >= Action.LAND:
        level = ERROR
    elif action >= Action.SLOW:
        level = max(level, WARN)
    bits = int(command.get("breaches", 0))
    kv = t["diagnostic_msgs/msg/KeyValue"]
    h = np.asarray(command.get("h_rows", ()), float)
    values = {
        "intervention": f"{float(command['intervention']):.6g}",
        "solve_us": f"{float(command['solve_us']):.1f}",
        "min_h": f"{float(command['min_h']):.6g}",
        "min_row_h": f"{float(h.min()):.6g}" if h.size else "",
        "rows": str(len(command.get("row_ids", ()))),
        "infeasible_ticks": str(int(command["infeasible"])),
        "goal_reached": str(bool(command["goal_reached"])).lower(),
        "monitor": action.name.lower(),
        "breaches": ",".join(name for b, name in BREACH_NAMES.items() if bits & b),
        "live_margin_m": f"{float(command.get('live_margin', 0.0)):.4g}",
        "t_s": f"{float(command['t']):.4f}",
    }
    return t["diagnostic_msgs/msg/DiagnosticStatus"](
        level=level,
        name=f"{agent_id}/safety_filter",
        message=status if action < Action.SLOW else f"{status}, monitor: {action.name.lower()}",
        hardware_id=agent_id,
        values=[kv(key=k, value=v) for k, v in values.items()],
    )


def _axis_quat(a: FloatArray) -> FloatArray:
    """The quaternion (x, y, z, w) that turns the z axis onto unit ``a``."""
    a = np.asarray(a, float)
    n = float(np.linalg.norm(a))
    if n < 1e-12:
        return np.array([0.0, 0.0, 0.0, 1.0])
    a = a / n
    c = float(a[2])
    if c < -1.0 + 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    axis = np.array([-a[1], a[0], 0.0])  # z x a
    w = 1.0 + c
    q = np.array([axis[0], axis[1], axis[2], w])
    return q / np.linalg.norm(q)


def marker_array(t_s: float, frame_id: str, items: list[dict[str, Any]], lengths_m: dict[str, float]) -> Any:
    """visualization_msgs/msg/MarkerArray of the obstacles (the clock's ``items``): a sphere
    or a cylinder along its axis (``lengths_m`` by id, as the world builds it), namespace
    ``obstacles``, one id per obstacle, grey."""
    t = _t()
    marker = t["visualization_msgs/msg/Marker"]
    color = t["std_msgs/msg/ColorRGBA"](r=0.55, g=0.55, b=0.6, a=0.8)
    dur = t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
    pose_t = t["geometry_msgs/msg/Pose"]
    out = []
    for i, o in enumerate(items):
        d = 2.0 * float(o["r"])
        cyl = o["shape"] == "cylinder"
        out.append(
            marker(
                header=_header(t_s, frame_id),
                ns="obstacles",
                id=i,
                type=marker.CYLINDER if cyl else marker.SPHERE,
                action=marker.ADD,
                pose=pose_t(position=_point(o["c"]), orientation=_quat(_axis_quat(o["a"]) if cyl else [0, 0, 0, 1])),
                scale=_vector([d, d, lengths_m.get(o["id"], 20.0) if cyl else d]),
                color=color,
                lifetime=dur,
                frame_locked=False,
                points=[],
                colors=[],
                texture_resource="",
                texture=t["sensor_msgs/msg/CompressedImage"](
                    header=_header(0.0, ""), format="", data=np.zeros(0, np.uint8)
                ),
                uv_coordinates=[],
                text=o["id"],
                mesh_resource="",
                mesh_file=t["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
                mesh_use_embedded_materials=False,
            )
        )
    return t["visualization_msgs/msg/MarkerArray"](markers=out)


def empty() -> Any:
    return _t()["std_msgs/msg/Empty"]()


def goal_position(msg: Any, frame_id: str) -> FloatArray:
    """The goal [m, world] of a geometry_msgs/msg/PoseStamped from ROS 2: its position,
    which must be finite and in ``frame_id`` (an empty frame id is taken as it);
    DecodeError otherwise. The orientation is not used (the drones keep their yaw)."""
    frame = str(msg.header.frame_id)
    if frame not in ("", frame_id):
        raise DecodeError(f"goal: frame_id {frame!r}, expected {frame_id!r}")
    p = msg.pose.position
    x = np.array([p.x, p.y, p.z], dtype=float)
    if not all(math.isfinite(v) for v in x.tolist()):
        raise DecodeError("goal: position not finite")
    return x
