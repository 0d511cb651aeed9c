"""An agent's route: its path planned round the walls (:mod:`swarm.planning`) and the rules it
applies on it every tick (docs/design.md, "Reference paths"): give way at a narrow passage
(:func:`gives_way`, :meth:`Route.hold`), brake before it turns away from a wall
(:meth:`Route.turns`), replan from where it is when it has stalled (:meth:`Route.update`).
These change the reference only; the filter keeps the agent safe whatever they say."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from swarm.planning import (
    CUT_STEP_M,
    Passage,
    Plan,
    PlannerSettings,
    StaticObstacles,
    _sampled,
    keep_right,
    narrow_stretches,
    plan,
)
from swarm.rotation import FloatArray

WAIT_M = 1.0
"""An agent that gives way waits this far [m] before the passage's entry, or where it is."""
TIE_M = 0.05
"""Two agents whose distances to the passage differ by less than this [m] are tied."""
COMING_MPS = 0.1
"""An agent beyond the passage counts once it flies towards it faster than this [m/s]."""
AGAINST_MPS = 0.05
"""An agent in the passage moving along it slower than this [m/s] either way is stopped
there; faster against another's way, it comes against that one."""
MAX_WAIT_S = 8.0
"""An agent gives way at most this long [s] per passage, then goes (two agents whose
passages differ can each see the other first)."""
TURN_REACH_M = 0.5
"""An agent whose velocity runs into a wall within this [m] (its safety radius kept) ...
(:meth:`Route.turns`)."""
TURN_ANGLE_DEG = 30.0
"""... while its path asks for a velocity at least this far [degrees] from it brakes ..."""
TURN_REST_MPS = 0.01
"""... down to this speed [m/s]: under ``swarm.safety.barriers.LIVE_W_HI_MPS``, where an
obstacle's row begins to follow the reference's direction rather than the velocity's."""


def gives_way(
    passage: Passage,
    s_m: float,
    x_w: FloatArray,
    others_x_w: FloatArray,
    others_v_w: FloatArray,
    inside: np.ndarray | None = None,
) -> bool:
    """Whether an agent ``s_m`` [m] along its path, at ``x_w`` [m, world], waits before its
    ``passage`` for the other agents at ``others_x_w`` (k, 3) moving at ``others_v_w`` (k,
    3) [m/s, world]: it does while, within :data:`WAIT_M` of the entry, another agent in
    the passage flies through it against it, or one is nearer its end of the passage than
    this agent is to its own (a tie goes to the agent whose position is first in (x, y, z)
    order) and is either stopped in the passage or outside it on the far side, flying
    towards it, unless an agent in the passage flies through it this agent's way (then it
    follows). Two agents waiting at the two mouths, each inside the other's passage, thus
    never both wait. Agents that go the same way follow each
    other. Every agent decides from positions and velocities it hears, by the same rule,
    so two agents at the two ends of a passage never both go (docs/design.md, "Reference
    paths"). ``inside``: ``passage.holds(others_x_w)`` when the caller has it already."""
    if not (passage.s_in_m - WAIT_M <= s_m < passage.s_in_m) or not len(others_x_w):
        return False
    mine = float(np.linalg.norm(x_w - passage.entry_w))
    if inside is None:
        inside = passage.holds(others_x_w)
    v_along = others_v_w @ passage.along_w
    to_exit = np.linalg.norm(others_x_w - passage.exit_w, axis=1)
    to_entry = np.linalg.norm(others_x_w - passage.entry_w, axis=1)
    towards = (passage.exit_w - others_x_w) / np.maximum(to_exit, 1e-9)[:, None]
    coming = np.sum(others_v_w * towards, axis=1) > COMING_MPS  # flying at its end (not parked at a goal)
    first = (to_exit < mine - TIE_M) | ((np.abs(to_exit - mine) <= TIE_M) & _before(others_x_w, x_w))
    far_side = (to_exit < to_entry) & ~inside & coming & first
    in_against = inside & (v_along < -AGAINST_MPS)  # flying through it against this agent
    in_stopped = inside & (np.abs(v_along) <= AGAINST_MPS) & first  # stopped in it, nearer its end
    if np.any(inside & (v_along > AGAINST_MPS)):  # its own way's flow holds the passage: follow it
        return bool(np.any(in_against))
    return bool(np.any(in_against) or np.any(in_stopped) or np.any(far_side))


def keeps_passage(along_w: FloatArray) -> bool:
    """Whether a flow through a passage in the direction ``along_w`` (3,) keeps it when it
    meets the opposite flow inside: the one heading towards larger x (then y, then z) does,
    the other backs out. Both agents decide it from their own direction alone, and two
    opposite directions never both keep it."""
    for k in range(3):
        if abs(float(along_w[k])) > 1e-6:
            return float(along_w[k]) > 0.0
    return True


def _before(others_x_w: FloatArray, x_w: FloatArray) -> np.ndarray:
    """(k,) whether each other position comes before ``x_w`` in (x, y, z) order."""
    out = np.zeros(others_x_w.shape[0], dtype=bool)
    undecided = np.ones(others_x_w.shape[0], dtype=bool)
    for d in range(3):
        out |= undecided & (others_x_w[:, d] < x_w[d])
        undecided &= others_x_w[:, d] == x_w[d]
    return out


class Route:
    """An agent's path with replanning: :meth:`update` says when the agent has not come
    closer to its goal along the path by ``progress_m`` within ``stall_s`` and gives a new
    plan from where it is (None otherwise). It also keeps the path's first narrow passage
    (:attr:`passage`) and says when to give way there (:meth:`hold`: waiting before it,
    backing out of it at ``back_mps`` [m/s])."""

    def __init__(
        self,
        obstacles: StaticObstacles,
        radius_m: float,
        settings: PlannerSettings | None = None,
        stall_s: float = 4.0,
        progress_m: float = 0.3,
        back_mps: float = 0.3,
    ) -> None:
        self.obstacles, self.radius_m, self.settings = obstacles, radius_m, settings or PlannerSettings()
        self.stall_s, self.progress_m, self.back_mps = stall_s, progress_m, back_mps
        self._best = math.inf  # least remaining path length [m] seen since the last plan
        self._since = 0.0  # sim time [s] of the last progress
        self.replans = 0
        self.passage: Passage | None = None  # the current path's first narrow passage without two lanes
        self.lanes = False  # the current path flies a lane of a two-lane passage (keep_right)
        self.length_m = 0.0  # the current path's length [m]
        self.cut_m = 0.0  # how far [m] a tracker may cut the current path's corners (corner_cut_m)
        self._waiting_since: float | None = None  # sim time [s] it began to give way at this passage

    def first(self, start_w: FloatArray, goal_w: FloatArray, t_s: float = 0.0) -> Plan:
        self._best, self._since = math.inf, t_s
        p = plan(start_w, goal_w, self.obstacles, self.radius_m, self.settings)
        if self.settings.lanes:
            p = replace(p, waypoints_w=keep_right(p.waypoints_w, self.obstacles, self.radius_m))
        self.follow(p.waypoints_w)
        return p

    def follow(self, waypoints_w: FloatArray) -> None:
        """The path now flown (its passage and length)."""
        stretches = narrow_stretches(waypoints_w, self.obstacles, self.radius_m if self.settings.lanes else None)
        self.passage = next((p for p in stretches if not p.lanes), None)
        self.lanes = any(p.lanes for p in stretches)
        self.length_m = float(np.linalg.norm(np.diff(waypoints_w, axis=0), axis=1).sum())
        self._waiting_since = None
        walls = self.obstacles.clustered(2 * (self.radius_m + self.settings.clearance_m))
        spare = float(walls.clearance(_sampled(waypoints_w, CUT_STEP_M)[0]).min()) - self.radius_m
        self.cut_m = min(self.settings.clearance_m, max(spare, 0.0))

    def hold(
        self,
        t_s: float,
        remaining_m: float,
        x_w: FloatArray,
        others_x_w: FloatArray,
        others_v_w: FloatArray,
        v_w: FloatArray | None = None,
        v_path_w: FloatArray | None = None,
    ) -> FloatArray | None:
        """The velocity [m/s, world] the agent flies this tick in place of its path, or None
        to fly the path, at sim time ``t_s`` [s] on the current path with ``remaining_m``
        [m] of it left, among the other agents at ``others_x_w`` (k, 3) [m] moving at
        ``others_v_w`` (k, 3) [m/s]: where it gives way (:meth:`_giving_way`), that;
        else, given its velocity ``v_w`` and its path's ``v_path_w`` [m/s, world], zeros
        while it brakes before it turns away from a wall (:meth:`turns`)."""
        out = self._giving_way(t_s, remaining_m, x_w, others_x_w, others_v_w)
        if out is None and v_w is not None and v_path_w is not None and self.turns(x_w, v_w, v_path_w):
            out = np.zeros(3)
        return out

    def _giving_way(
        self, t_s: float, remaining_m: float, x_w: FloatArray, others_x_w: FloatArray, others_v_w: FloatArray
    ) -> FloatArray | None:
        """:meth:`hold`'s giving way at the path's passage, or None:

        * backing out of its passage at ``back_mps`` along it, while it is in the passage
          or within ``WAIT_M / 2`` of it, its own flow does not keep the passage
          (:func:`keeps_passage`) and an agent ahead of it in the passage comes against it
          or stands still there (one behind it, of its own flow, does not); then hovering
          (zeros) within ``WAIT_M`` of the passage while that agent is still in it;
        * else hovering while it gives way before the passage (:func:`gives_way`), for at
          most :data:`MAX_WAIT_S` at this passage.

        Time spent giving way does not count as a stall."""
        p = self.passage
        if p is None or not len(others_x_w):
            return None
        along = p.along_w
        s_m = self.length_m - remaining_m
        mine = float(np.min(np.linalg.norm(p.points_w - x_w, axis=1)))  # m from the passage
        inside = p.holds(others_x_w)
        ahead = (others_x_w - x_w) @ along > 0.0  # between it and the passage's exit
        against = inside & ahead & (others_v_w @ along <= AGAINST_MPS)
        out: FloatArray | None = None
        if against.any() and s_m < p.s_out_m and not keeps_passage(along):
            if mine < 0.5 * WAIT_M:
                out = -self.back_mps * along
            elif mine < WAIT_M:
                out = np.zeros(3)
        if out is None:
            if self._waiting_since is not None and t_s - self._waiting_since > MAX_WAIT_S:
                return None  # waited long enough: go
            if not gives_way(p, s_m, x_w, others_x_w, others_v_w, inside):
                return None
            out = np.zeros(3)
        self._since = t_s
        if self._waiting_since is None:
            self._waiting_since = t_s
        return out

    def turns(self, x_w: FloatArray, v_w: FloatArray, v_path_w: FloatArray) -> bool:
        """Whether the agent at ``x_w`` [m, world] flying ``v_w`` [m/s, world] brakes this
        tick (hovers in place of its path) before it turns to its path's velocity
        ``v_path_w`` [m/s, world]: while its horizontal velocity, faster than
        :data:`TURN_REST_MPS`, runs into a wall within :data:`TURN_REACH_M` (inflated by its
        safety radius) and the path asks for a velocity at least :data:`TURN_ANGLE_DEG` away
        from it.

        Why (docs/design.md, "Braking to turn away from a wall"): a velocity pointed at the
        junction of two touching pillars is outside both their cones (their horizon
        allowances), and as the allowances shrink each pillar's row turns it towards the
        other: the rows admit neither turn, only braking, and braking the reference does not
        ask for is paid at the gain's rate (h falls with the speed), so the agent coasted
        towards the wall for seconds. Asked to brake, free braking stops it within a few
        tenths of a second; slow, the rows follow the reference's direction, and it leaves
        along its path."""
        v = np.array([v_w[0], v_w[1], 0.0])
        speed = float(np.linalg.norm(v))
        want = np.array([v_path_w[0], v_path_w[1], 0.0])
        n = float(np.linalg.norm(want))
        if speed < TURN_REST_MPS or n < 1e-9 or float(v @ want) > speed * n * math.cos(math.radians(TURN_ANGLE_DEG)):
            return False
        ray = np.asarray(x_w, dtype=float) + np.outer(np.arange(0.0, TURN_REACH_M + 1e-9, CUT_STEP_M), v / speed)
        return bool((self.obstacles.clearance(ray) < self.radius_m).any())

    def update(self, t_s: float, x_w: FloatArray, goal_w: FloatArray, remaining_m: float) -> Plan | None:
        """At sim time ``t_s`` [s], the agent at ``x_w`` with ``remaining_m`` [m] of path
        left: a new plan if it has stalled, else None."""
        if remaining_m < self._best - self.progress_m:
            self._best, self._since = remaining_m, t_s
            return None
        if t_s - self._since < self.stall_s or remaining_m < self.progress_m or not len(self.obstacles):
            return None
        self.replans += 1
        return self.first(x_w, goal_w, t_s)


def corner_cut_m(route: Route | None) -> float:
    """How far [m] the tracker of an agent on ``route`` may cut its path's corners
    (``swarm.control.PathTracker``'s ``cut_m``): the clearance the path keeps from the walls
    beyond the agent's safety radius (at most the planner's ``clearance_m``; a few
    centimetres on a path through a lane, which runs that close to a wall), so the cut
    reference still keeps the safety radius; 0 without a route (a configured path is flown
    corner by corner)."""
    return 0.0 if route is None else route.cut_m


class PathSpec(NamedTuple):
    """What the planner takes of an agent, as plain values (``swarm.build.path_spec`` reads them
    off its config)."""

    points_w: FloatArray  # (k, 3) m, world: its start, then its configured waypoints or goal
    safety_radius_m: float  # m: its body's radius plus its filter's margin
    planner: PlannerSettings | None  # how its paths are planned; None: its configured path, straight
    stall_s: float  # s: a route replans after this long without progress


def plans_round_walls(spec: PathSpec, obstacles: StaticObstacles) -> bool:
    """Whether the agent of ``spec`` flies a path planned round walls among ``obstacles``
    (obstacles closer together than two of its clearances), with a :class:`Route`; else it flies
    its configured path straight."""
    if spec.planner is None or len(spec.points_w) < 2:
        return False
    return bool(len(obstacles.clustered(2 * (spec.safety_radius_m + spec.planner.clearance_m))))


def follows(route: Route | None) -> bool:
    """Whether the right-hand tie-break of an agent on ``route`` follows the agents ahead
    flying its way rather than turn from them (``swarm.control.right_hand_bias``): on a path
    through a lane (:func:`swarm.planning.keep_right`). A lane is single file with a wall on its
    right, where turning right from the agent ahead pushes a flow's followers out of its queue;
    the lanes themselves keep opposite flows apart. Elsewhere the tie-break turns from the agents
    ahead (docs/design.md, "Reference paths"; the measurements in EXPERIMENTS.md section 4)."""
    return route is not None and route.lanes


def path_for(spec: PathSpec, obstacles: StaticObstacles) -> tuple[FloatArray, Route | None]:
    """The waypoints (k, 3) [m, world] the agent of ``spec`` flies from its start (each leg of
    its configured path planned around ``obstacles``), and its :class:`Route` for replanning
    (None unless it :func:`plans_round_walls`)."""
    pts = np.asarray(spec.points_w, dtype=float)
    if spec.planner is None or not plans_round_walls(spec, obstacles):  # no wall: the straight path, as ever
        return pts, None
    route = Route(obstacles, spec.safety_radius_m, spec.planner, spec.stall_s)
    legs = [route.first(a, b).waypoints_w for a, b in zip(pts[:-1], pts[1:], strict=True)]
    path = np.vstack([legs[0], *(leg[1:] for leg in legs[1:])])
    route.follow(path)
    return path, route
