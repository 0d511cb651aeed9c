"""What a call of one of Crazyswarm2's services asks of the drones (pure): the goal message the
bridge sends the agents for it (``swarm.ros2.goals``). The services' names, keys, hashes and CDR
are ``swarm.net.ros2.services``.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from swarm.errors import DecodeError
from swarm.net.ros2.services import Srv
from swarm.rotation import FloatArray


class Ask(NamedTuple):
    """What a request asks of its drones, as a goal message's fields (``swarm.ros2.goals``):
    ``action``, ``x_w`` [m, world; a relative move's offset, a take-off's or landing's height in
    ``x_w[2]``] and ``duration_s`` [s] (0: the drone's own speed); None for a request that asks
    nothing of them (``notify_setpoints_stop``: they take no low-level setpoints from ROS 2)."""

    action: str
    x_w: FloatArray
    duration_s: float


def _seconds(d: Any) -> float:
    return float(d.sec) + 1e-9 * float(d.nanosec)


def ask_of(kind: Srv, req: Any) -> Ask | None:
    """What ``req`` (a decoded request of ``kind``) asks; DecodeError if its values are not
    finite, its duration negative, or its group mask names a group (every drone of a run is
    in none: only ``group_mask`` 0, every drone, is taken)."""
    from swarm.ros2.goals import GOAL, GOAL_RELATIVE, LAND, TAKEOFF

    if int(req.group_mask) != 0:
        raise DecodeError(f"group_mask {int(req.group_mask)}: the run's drones are in no group (use 0: all)")
    if kind is Srv.NOTIFY_SETPOINTS_STOP:
        return None
    duration = _seconds(req.duration)
    if not math.isfinite(duration) or duration < 0:
        raise DecodeError(f"duration {duration} s is not a non-negative number")
    if kind is Srv.GO_TO:
        x = np.array([req.goal.x, req.goal.y, req.goal.z], dtype=float)
        if not np.all(np.isfinite(x)) or not math.isfinite(req.yaw):
            raise DecodeError(f"go_to: goal {x.tolist()} or yaw {req.yaw} is not finite")
        return Ask(GOAL_RELATIVE if req.relative else GOAL, x, duration)
    height = float(req.height)
    if not math.isfinite(height):
        raise DecodeError(f"{kind.value}: height {height} m is not finite")
    return Ask(TAKEOFF if kind is Srv.TAKEOFF else LAND, np.array([0.0, 0.0, height]), duration)
