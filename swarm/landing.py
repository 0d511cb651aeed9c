"""Landing on request: ``swarm run``'s first Ctrl-C (or SIGTERM, SIGHUP) lands every drone
and ends the run once they are down; a second one is the emergency stop.

Pure: who counts as down (:func:`down`), and the launcher's state machine over the stop
signals it has received (:func:`stop_for`). The launcher publishes the request on
``swarm/<run>/land`` (``swarm.net.transport.Keys.land``); each agent lands its drone (a real
one by its flight plan, motors off on the ground; a simulated one straight down to its
floor, ``swarm.ros2.goals.landing_goal``) and the world ends the run when every simulated
drone is down, then relays the real drones' motion capture until they have landed
(``time.land_timeout_s``).
"""

from __future__ import annotations

from enum import Enum
from typing import TYPE_CHECKING

import numpy as np

from swarm.rotation import FloatArray

if TYPE_CHECKING:
    from swarm.config import AgentConfig

DOWN_ABOVE_M = 0.1
"""A simulated drone is down within this height [m] above its landing height ..."""
DOWN_SPEED_MPS = 0.1
"""... and slower than this [m/s]."""
LANDED = "landed on request"
"""A run's ``stop_reason`` when it ended so (every drone down after the first Ctrl-C)."""
LANDING_BANNER = (
    "Ctrl-C lands every drone and ends the run when they are down; "
    "a second Ctrl-C is the emergency stop (motors off where they fly)"
)
"""What ``swarm run`` prints where the run starts."""
LANDING_NOW = "landing every drone (Ctrl-C again: emergency stop, motors off where they fly)"
"""What ``swarm run`` prints on the first stop signal."""


def landing_height_m(me: AgentConfig) -> float:
    """The height [m, world z] a simulated drone lands to: the lowest its filter keeps
    (``filter.floor_z_m``), 0.05 m at least and with the floor off."""
    floor = me.filter.floor_z_m if me.filter.enabled and me.filter.floor_z_m is not None else 0.05
    return max(floor, 0.05)


def down(x_w: FloatArray, v_w: FloatArray, land_z_m: FloatArray) -> bool:
    """Whether every drone is down: positions ``x_w`` (n, 3) m and velocities ``v_w`` (n, 3)
    m/s, world, each within :data:`DOWN_ABOVE_M` above its landing height ``land_z_m`` (n,) m
    and slower than :data:`DOWN_SPEED_MPS`. True for no drone."""
    x = np.asarray(x_w, float).reshape(-1, 3)
    v = np.asarray(v_w, float).reshape(-1, 3)
    low = x[:, 2] <= np.asarray(land_z_m, float) + DOWN_ABOVE_M
    slow = np.linalg.norm(v, axis=1) <= DOWN_SPEED_MPS
    return bool(np.all(low & slow))


class Stop(Enum):
    """What the launcher does about the stop signals it has had."""

    FLY = "fly"  # none: fly on
    LAND = "land"  # one, while drones fly: land them, end the run when they are down
    NOW = "now"  # a second one, or one before any drone flies: stop every process now


def stop_for(signals: int, flying: bool) -> Stop:
    """The launcher's answer to ``signals`` stop signals received, ``flying`` whether the
    world has ticked (a drone may be in the air)."""
    if signals == 0:
        return Stop.FLY
    if signals == 1 and flying:
        return Stop.LAND
    return Stop.NOW
