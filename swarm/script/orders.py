"""A script's orders to a drone (pure): what each asks, whether a run takes it, and the goal
and cruise speed a drone flies for it.

Both ends check an order: the client before it sends one (a :class:`swarm.errors.RefusedError`
naming what is wrong), the agent again when it takes one (a refusal in its report). What
the agent then flies still passes its safety filter: an order only moves the reference.
"""

from __future__ import annotations

import math
from enum import StrEnum
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from swarm.errors import RefusedError
from swarm.rotation import FloatArray

if TYPE_CHECKING:
    from swarm.config import AgentConfig, ScenarioConfig


class Action(StrEnum):
    TAKEOFF = "takeoff"  # climb to a height straight above where the drone is
    GOTO = "goto"  # fly to a position
    LAND = "land"  # straight down: a real Crazyflie lands, a simulated one to its floor
    STOP = "stop"  # hold where it is


class Order(NamedTuple):
    """One order to one drone. ``x_w`` [m, world]: the goal of a go-to, the height (``x_w[2]``)
    of a take-off, unused by land and stop; ``speed_mps`` [m/s] its cruise speed (0: the
    drone's own ``speed_mps``)."""

    order: int  # the script's number of it (one sequence per client)
    action: Action
    x_w: FloatArray  # (3,) m, world
    yaw_rad: float = 0.0  # rad, world: asked, not flown (the drones hold their yaw)
    speed_mps: float = 0.0


class Taken(NamedTuple):
    """What a drone flies for an order: its goal and cruise speed."""

    goal_w: FloatArray  # (3,) m, world
    speed_mps: float  # m/s, at most the drone's own speed_mps


def steerable(cfg: ScenarioConfig, drone: str) -> None:
    """Raise :class:`RefusedError` unless a script may steer ``drone`` in ``cfg``'s run."""
    ids = [a.id for a in cfg.agents]
    if drone not in ids:
        raise RefusedError(f"no drone {drone!r} in run {cfg.name!r} (drones: {', '.join(ids)})")
    if drone not in cfg.steerable:
        raise RefusedError(
            f"drone {drone!r} is not one a script may steer (script.drones: {', '.join(cfg.steerable) or 'none'})"
        )


def check_point(cfg: ScenarioConfig, drone: str, x_w: FloatArray, what: str = "goal") -> FloatArray:
    """``x_w`` [m, world] as a (3,) float array if ``drone`` may be sent there: finite, inside
    ``script.bounds_m``, at or above its floor (``filter.floor_z_m``); else :class:`RefusedError`."""
    try:
        x = np.asarray(x_w, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise RefusedError(f"{drone}: {what} {x_w!r} is not a position (x, y, z) [m]") from None
    if not np.all(np.isfinite(x)):
        raise RefusedError(f"{drone}: {what} {x.tolist()} is not finite")
    lo, hi = (np.asarray(b, dtype=float) for b in cfg.script.bounds_m)
    if np.any(x < lo) or np.any(x > hi):
        raise RefusedError(f"{drone}: {what} {x.tolist()} is outside script.bounds_m {lo.tolist()} .. {hi.tolist()}")
    me = cfg.agent(drone)
    floor = me.filter.floor_z_m if me.filter.enabled else None
    if floor is not None and x[2] < floor:
        raise RefusedError(f"{drone}: {what} z = {x[2]:.3f} m is below its floor (filter.floor_z_m {floor} m)")
    return x


def cruise_speed(
    me: AgentConfig, distance_m: float, duration_s: float | None, speed_mps: float | None, min_mps: float
) -> float:
    """The cruise speed [m/s] of a move of ``distance_m`` [m]: ``speed_mps``, or the speed that
    covers it in ``duration_s`` [s], at least ``min_mps`` and at most the drone's own
    ``speed_mps`` (0: its own). Raises :class:`RefusedError` on a non-positive or
    non-finite duration or speed."""
    if duration_s is not None and speed_mps is not None:
        raise RefusedError("give a duration or a speed, not both")
    if duration_s is not None:
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise RefusedError(f"duration {duration_s} s is not a positive number")
        v = distance_m / duration_s
    elif speed_mps is not None:
        if not (math.isfinite(speed_mps) and speed_mps > 0):
            raise RefusedError(f"speed {speed_mps} m/s is not a positive number")
        v = speed_mps
    else:
        return 0.0
    return float(min(max(v, min_mps), me.speed_mps))


def taken(cfg: ScenarioConfig, drone: str, order: Order, x_w: FloatArray) -> Taken:
    """What ``drone`` at ``x_w`` [m, world] flies for ``order`` (checked again here: an order
    from a session the router let through is still only an order); :class:`RefusedError`
    if it may not."""
    from swarm.ros2.goals import landing_goal

    me = cfg.agent(drone)
    speed = order.speed_mps if math.isfinite(order.speed_mps) and order.speed_mps > 0 else 0.0
    speed = min(speed, me.speed_mps)
    here = np.asarray(x_w, dtype=float)
    if order.action is Action.GOTO:
        return Taken(check_point(cfg, drone, order.x_w), speed)
    if order.action is Action.TAKEOFF:
        goal = check_point(cfg, drone, np.array([here[0], here[1], float(order.x_w[2])]), "take-off height")
        return Taken(goal, speed)
    if order.action is Action.LAND:
        return Taken(landing_goal(me, here), speed)
    return Taken(here.copy(), 0.0)
