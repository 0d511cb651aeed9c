"""A new goal for an agent while it flies (a goal, land or stop from ROS 2).

:func:`course` is pure: the path, route, tracker and filter settings an agent flies from
where it is to a new goal, built exactly as the agent builds them for its configured goal
at the start (``swarm.build.path_of``: planned round the walls when it plans round
walls, straight otherwise). :class:`GoalInbox` is the agent process's side: the bridge's
goal messages (``swarm/<run>/ros2/goal/<id>`` and ``.../ros2/all``), queued by Zenoh and
taken once per tick, the newest first (no Python runs per message, nothing wakes the agent).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from swarm.build import cruise_speed_mps, filter_of, path_of
from swarm.control import PathTracker
from swarm.landing import landing_height_m
from swarm.model import CommandLevel
from swarm.net import transport as tp
from swarm.net.access import ROS2_BRIDGE
from swarm.planning import StaticObstacles
from swarm.rotation import FloatArray
from swarm.route import Route, corner_cut_m
from swarm.safety.filter import FilterConfig

if TYPE_CHECKING:
    from swarm.config import AgentConfig
    from swarm.realism.settings import RealismSettings

GOAL, LAND, STOP = "goal", "land", "stop"


class Course(NamedTuple):
    goal_w: FloatArray  # (3,) m, world
    path_w: FloatArray  # (k, 3) m, world, from where the agent is
    route: Route | None  # replanning round the walls (None: a straight path)
    tracker: PathTracker
    filter_config: FilterConfig  # the filter that path needs (its obstacle horizon round walls)


def course(
    me: AgentConfig,
    obstacles: StaticObstacles,
    level: CommandLevel,
    x_w: FloatArray,
    goal_w: FloatArray,
    realism: RealismSettings | None = None,
    control_hz: float | None = None,
) -> Course:
    """The course of agent ``me`` from ``x_w`` [m, world] to ``goal_w`` [m, world] among the
    static ``obstacles``: its configuration with that start and goal, through the planner, in the
    world ``realism`` at ``control_hz`` [Hz] (its delay contract: ``swarm.tuning``)."""
    now = me.model_copy(
        update={"start": [float(v) for v in x_w], "goal": [float(v) for v in goal_w], "waypoints": None}
    )
    path_w, route = path_of(now, obstacles)
    tracker = PathTracker(path_w, cruise_speed_mps(now, realism, control_hz), cut_m=corner_cut_m(route))
    cfg = filter_of(now, obstacles, level, route, realism, control_hz)
    return Course(np.asarray(goal_w, dtype=float), path_w, route, tracker, cfg)


def landing_goal(me: AgentConfig, x_w: FloatArray) -> FloatArray:
    """Where a simulated drone at ``x_w`` lands to: straight below, at the lowest height its
    filter keeps (``filter.floor_z_m``; 0.05 m with the floor off)."""
    return np.array([x_w[0], x_w[1], landing_height_m(me)])


class GoalInbox:
    """An agent's goals from the ROS 2 bridge: :meth:`apply` takes what has arrived and
    retargets the agent at its measured position (the newest message wins; one from a
    sender other than the bridge, or for another agent, or malformed, is dropped and
    counted)."""

    def __init__(self, session: Any, keys: tp.Keys, agent_id: str, run: str, counter: tp.Counter) -> None:
        self.id, self.run, self.counter = agent_id, run, counter
        self.subs = [
            tp.open_channel(session, keys.ros2_goal(agent_id), 16),
            tp.open_channel(session, keys.ros2_all, 16),
        ]
        self.applied = 0

    def newest(self) -> Any:
        newest = None
        for sub in self.subs:
            for s in tp.drain(sub):
                m = tp.decode_sample(s, self.run, self.counter, ("goal",))
                if m is None:
                    continue
                if m.src != ROS2_BRIDGE or m["action"] not in (GOAL, LAND, STOP):
                    self.counter.drop("goal: not from the ROS 2 bridge, or no such action")
                    continue
                if newest is None or m.seq > newest.seq:
                    newest = m
        return newest

    def apply(self, agent: Any, x_w: FloatArray) -> str | None:
        """Retarget ``agent`` (at ``x_w`` [m, world]) by the newest message; its action, or None."""
        m = self.newest()
        if m is None:
            return None
        action = str(m["action"])
        if action == GOAL:
            agent.retarget(x_w, m["x"])
        elif action == STOP:
            agent.retarget(x_w, x_w)
        else:
            agent.land(x_w)
        self.applied += 1
        return action
