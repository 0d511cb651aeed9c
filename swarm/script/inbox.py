"""An agent's side of a script (``script.enabled``): its orders, taken once per tick, and its
reports on them.

Orders arrive on ``swarm/<run>/script/order/<id>``, which the run's router accepts from the
``script`` user alone, and only for the drones ``script.drones`` names. Each tick the agent
takes the newest (a malformed one, or one not from a script, is dropped and counted), checks
it again (:func:`swarm.script.orders.taken`), retargets its step at its measured position and
reports on ``swarm/<run>/agent/<id>/report``: ``taken`` with the goal it flies to, or
``refused`` with why; then ``arrived`` once it is within ``goal_tolerance_m`` of that goal.
The reports are recorded, so ``metrics.json`` lists every order's arrival.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from swarm.errors import RefusedError
from swarm.net import access
from swarm.net import transport as tp
from swarm.net.messages import encode
from swarm.rotation import FloatArray
from swarm.script.orders import Action, Order, taken

if TYPE_CHECKING:
    from swarm.config import ScenarioConfig


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
