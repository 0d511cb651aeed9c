"""A script's orders to a drone: what each asks, whether a run takes it, the goal and cruise
speed a drone flies for it (pure), and the agent's side of them (:class:`OrderInbox`).

Both ends check an order: the client (``swarm.script``) before it sends one (a
:class:`swarm.errors.RefusedError` naming what is wrong), the agent again when it takes one (a
refusal in its report). What the agent then flies still passes its safety filter: an order only
moves the reference.

Orders arrive on ``swarm/<run>/script/order/<id>``, which the run's router accepts from the
``script`` user alone, and only for the drones ``script.drones`` names. Each tick the agent
takes the newest (a malformed one, or one not from a script, is dropped and counted), checks
it again (:func:`taken`), retargets its step at its measured position and reports on
``swarm/<run>/agent/<id>/report``: ``taken`` with the goal it flies to, or ``refused`` with why;
then ``arrived`` once it is within ``goal_tolerance_m`` of that goal. The reports are recorded,
so ``metrics.json`` lists every order's arrival.
"""

from __future__ import annotations

import math
from enum import StrEnum
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from swarm.errors import RefusedError
from swarm.net import access
from swarm.net import transport as tp
from swarm.net.messages import encode
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


class OrderInbox:
    """One agent's orders and reports. :meth:`apply` before its step, :meth:`after` with the
    step's result."""

    def __init__(self, session: Any, cfg: ScenarioConfig, agent_id: str, run: str, counter: tp.Counter) -> None:
        keys = tp.Keys(run)
        self.cfg, self.id, self.run, self.counter = cfg, agent_id, run, counter
        self.sub = tp.open_channel(session, keys.order(agent_id), 64)
        self.pub = session.declare_publisher(keys.report(agent_id))
        self.seq = 0  # (its own sequence: the commands' is the ledger's)
        self.current: tuple[int, str, FloatArray] | None = None  # the order flown: number, action, goal
        self.reported_arrival = True

    def newest(self) -> Order | None:
        newest = None
        for s in tp.drain(self.sub):
            m = tp.decode_sample(s, self.run, self.counter, ("order",))
            if m is None:
                continue
            if m.src != access.SCRIPT or m["action"] not in tuple(Action):
                self.counter.drop("order: not from a script, or no such action")
                continue
            if newest is None or m["order"] > newest.order:
                newest = Order(int(m["order"]), Action(m["action"]), m["x"], float(m["yaw"]), float(m["speed"]))
        return newest

    def report(self, t_s: float, k: int, order: int, action: str, x_w: Any, state: str, why: str = "") -> None:
        self.seq += 1
        body = encode(
            "report", self.run, self.id, self.seq, t_s, k, order=order, action=action, x=x_w, state=state, why=why
        )
        self.pub.put(body)

    def apply(self, agent: Any, t_s: float, k: int, x_w: FloatArray) -> Order | None:
        """Retarget ``agent`` (at ``x_w`` [m, world], sim time ``t_s`` [s], tick ``k``) by the
        newest order, and report it taken or refused; the order, or None."""
        order = self.newest()
        if order is None:
            return None
        try:
            t = taken(self.cfg, self.id, order, x_w)
        except RefusedError as exc:
            self.report(t_s, k, order.order, order.action.value, order.x_w, "refused", str(exc))
            return order
        if order.action is Action.LAND:
            agent.land(x_w)
        else:
            agent.retarget(x_w, t.goal_w, t.speed_mps or None)
        self.current = (order.order, order.action.value, t.goal_w)
        self.reported_arrival = False
        self.report(t_s, k, order.order, order.action.value, t.goal_w, "taken")
        return order

    def after(self, t_s: float, k: int, arrived: bool, x_w: FloatArray) -> None:
        """Report the order flown arrived once the step says so (``arrived``) or, for a
        landing, once the drone is within the goal tolerance of the ground it lands to."""
        if self.current is None or self.reported_arrival:
            return
        order, action, goal = self.current
        there = arrived
        if action == Action.LAND.value:
            there = arrived or bool(np.linalg.norm(np.asarray(x_w) - goal) <= self.cfg.goal_tolerance_m)
        if there:
            self.reported_arrival = True
            self.report(t_s, k, order, action, goal, "arrived")
