"""The planner protocol a plugin implements (docs/plugins.md, "Your own planner").

A planner is a class registered under the entry-point group ``c3swarm.planners``
(``swarm.plugins``), named by ``planner.kind``. It is built once per agent from a
:class:`PlannerSpec` and asked, before the run (and again for a new goal from ROS 2), for the path
from the agent's start through its configured waypoints: :meth:`plan` gets a
:class:`PlannerInput` and returns a :class:`PlannerOutput`, the waypoints the path tracker then
follows and the reference controller and the safety filter act on. A plugin's path is flown as
it is: no replanning of a stalled path and no lanes (those are the built-in ``grid`` planner's,
``swarm.route``).

The config checks it when it is loaded (``ScenarioConfig``): a planner that raises, or returns a
path that is not finite, not (k, 3), or does not end at the agent's goal, stops the run before
anything flies (exit 2 naming ``agents.N.planner.kind``). Asked again in flight (a new goal), such
a path is replaced by the built-in ``grid`` planner's (:func:`planned_path` returns None).

The built-ins are registered the same way: ``grid`` (:class:`GridPlanner`) and ``none``
(:class:`Straight`), whose ``builtin`` attribute tells ``swarm.build.path_of`` to plan with
``swarm.route.path_for``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import numpy as np
from pydantic import BaseModel

from swarm.model import QuadParams, all_finite
from swarm.planning import StaticObstacles
from swarm.rotation import FloatArray

GOAL_TOL_M = 1e-6
"""How close [m] a planned path's last waypoint must be to the agent's goal."""


@dataclass(frozen=True)
class PlannerSpec:
    """What a planner is built with, once per agent."""

    agent_id: str
    params: QuadParams  # the airframe: body_radius_m ...
    safety_radius_m: float  # m: its body radius plus the filter's margin (what the filter keeps from a surface)
    clearance_m: float  # m: planner.clearance_m, to keep beyond the safety radius
    options: BaseModel | None  # the plugin's validated options (its ``Options`` model), or None


@dataclass(frozen=True)
class PlannerInput:
    """What a planner is asked to plan."""

    start_w: FloatArray  # (3,) m, world: where the agent is (its start)
    targets_w: FloatArray  # (k, 3) m, world: the configured waypoints after the start, the goal last
    obstacles: StaticObstacles  # the walls and pillars: static vertical cylinders (c_w, r_m, axis_w)


class PlannerOutput(NamedTuple):
    """A planner's path: the waypoints (n, 3) [m, world] after the start, its goal last."""

    waypoints_w: FloatArray


class GridPlanner:
    """The built-in planner: A* on a grid round the walls where the straight path is blocked,
    with replanning and lanes (``swarm.route``), ``planner.kind: grid``."""

    builtin: ClassVar[bool] = True

    def plan(self, inp: PlannerInput) -> PlannerOutput:  # (swarm.route.path_for plans a built-in itself)
        return PlannerOutput(inp.targets_w)


class Straight(GridPlanner):
    """The configured path, straight: ``planner.kind: none``."""


def is_builtin(cls: type) -> bool:
    return getattr(cls, "builtin", False) is True


class PlanError(ValueError):
    """A plugin planner's path that cannot be flown (the message says why)."""


class PlanRequest(NamedTuple):
    """What an agent's planner is asked, as plain values (``swarm.build.planner_request`` and the
    config's check read them off its config)."""

    agent_id: str
    kind: str  # planner.kind: a name registered in c3swarm.planners
    options: dict[str, Any]  # planner.options
    params: QuadParams  # its airframe
    safety_radius_m: float  # m: its body radius plus its filter's margin
    clearance_m: float  # m: planner.clearance_m
    points_w: FloatArray  # (k, 3) m, world: its start, then its configured waypoints or goal


def plugin_path(req: PlanRequest, still: StaticObstacles) -> FloatArray:
    """The path (k, 3) [m, world] a plugin planner gives ``req``, from its start (first) to its
    goal (last). Raises :class:`PlanError` when the planner raises or its path is not flyable."""
    from swarm.plugins import PLANNERS, plugin_class, plugin_options

    cls = plugin_class(PLANNERS, req.kind)
    spec = PlannerSpec(
        req.agent_id, req.params, req.safety_radius_m, req.clearance_m, plugin_options(cls, dict(req.options))
    )
    pts = np.asarray(req.points_w, dtype=float)
    try:
        out = cls(spec).plan(PlannerInput(pts[0].copy(), pts[1:].copy(), still))
        W = np.array(out.waypoints_w if isinstance(out, PlannerOutput) else out, dtype=float)
    except Exception as exc:  # a plugin's fault of any kind
        raise PlanError(f"planner {req.kind!r} raised {type(exc).__name__}: {exc}") from None
    if W.ndim != 2 or W.shape[1:] != (3,) or len(W) < 1 or not all_finite(W):
        raise PlanError(f"planner {req.kind!r} returned no (n, 3) finite waypoints (got shape {W.shape})")
    if float(np.linalg.norm(W[-1] - pts[-1])) > GOAL_TOL_M:
        raise PlanError(f"planner {req.kind!r}'s path ends at {W[-1].tolist()}, not the goal {pts[-1].tolist()}")
    return np.vstack([pts[:1], W])


def planned_path(req: PlanRequest, still: StaticObstacles) -> FloatArray | None:
    """The plugin planner's path for ``req`` from its start, or None: a built-in planner (the
    caller plans), or a plugin whose path cannot be flown (said on stderr; the caller flies the
    grid's)."""
    from swarm.plugins import PLANNERS, plugin_class

    if is_builtin(plugin_class(PLANNERS, req.kind)):
        return None
    try:
        return plugin_path(req, still)
    except PlanError as exc:
        print(f"agent {req.agent_id}: {exc}; flying the grid planner's path", file=sys.stderr)
        return None
