"""Reference paths around the static world (docs/design.md, "Reference paths").

A reactive filter with a straight-line reference stops where its reference points into
a wall: a doorway beside it, a U-shaped trap around its goal. Each agent therefore flies
a path planned around the obstacles it knows that do not move, and the C3BF-QP keeps it
safe whatever the path: the path only shapes the reference.

The plan is a shortest path on an 8-connected grid at the agent's altitude (networkx's
A*), over the cells whose centres keep ``keep_m`` (the agent's safety radius plus a
clearance) from every static obstacle's surface, shortened by line of sight into a few
waypoints. A start or goal that is itself closer than ``keep_m`` joins the grid at its
nearest free cell. Where no wall (obstacles closer together than two clearances) crosses
the straight line, the plan is the straight line and no grid is made: the filter passes an
isolated obstacle on its own. The world is planar: its walls are static vertical cylinders
(infinite, as the barrier treats them); spheres and tilted cylinders are left to the filter,
which can pass over or under them. Long passages wide enough for two are flown in their
right-hand lane (:func:`keep_right`); the narrow ones are found (:func:`narrow_stretches`) for
the per-tick rules of :mod:`swarm.route` (giving way, braking to turn, replanning).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from swarm.errors import InputError
from swarm.rotation import FloatArray, IntArray

if TYPE_CHECKING:
    import networkx as nx


@dataclass(frozen=True)
class StaticObstacles:
    """The obstacles that do not move: centres ``c_w`` (m, 3) [m, world], radii ``r_m``
    (m,) [m] and unit cylinder axes ``axis_w`` (m, 3) [world] (zero rows for spheres)."""

    c_w: FloatArray
    r_m: FloatArray
    axis_w: FloatArray

    @classmethod
    def of(cls, obstacles: list) -> StaticObstacles:
        """The planar world's walls and pillars among :class:`swarm.config.ObstacleConfig`
        items: static vertical cylinders. A sphere or a tilted cylinder can be passed over
        or under, which the filter does; a plan at one altitude would only go round it."""
        still = [
            o
            for o in obstacles
            if not any(o.velocity) and o.axis is not None and math.hypot(o.axis[0], o.axis[1]) < 1e-9 * abs(o.axis[2])
        ]
        if not still:
            return cls(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
        axes = np.tile([0.0, 0.0, 1.0], (len(still), 1))
        return cls(np.array([o.center for o in still], dtype=float), np.array([o.radius_m for o in still]), axes)

    def subset(self, keep: np.ndarray) -> StaticObstacles:
        return StaticObstacles(self.c_w[keep], self.r_m[keep], self.axis_w[keep])

    def clustered(self, gap_m: float) -> StaticObstacles:
        """The obstacles with another closer than ``gap_m`` [m] surface to surface: walls,
        where an agent cannot pass between two of them. An isolated obstacle is left to the
        filter, whose live rows pass a convex obstacle on their own."""
        n = len(self)
        if n < 2:
            return self.subset(np.zeros(n, dtype=bool))
        d = np.linalg.norm((self.c_w[:, None, :2] - self.c_w[None, :, :2]), axis=2) - self.r_m[:, None] - self.r_m[None]
        np.fill_diagonal(d, math.inf)
        return self.subset(d.min(axis=1) < gap_m)

    def __len__(self) -> int:
        return int(self.r_m.shape[0])

    def clearance(self, points_w: FloatArray) -> FloatArray:
        """(k,) distance [m] from each point (k, 3) to the nearest obstacle surface (inf
        with no obstacle; negative inside one)."""
        points_w = np.asarray(points_w, dtype=float).reshape(-1, 3)
        if not len(self):
            return np.full(points_w.shape[0], math.inf)
        return self.gaps(points_w).min(axis=1)

    def gaps(self, points_w: FloatArray) -> FloatArray:
        """(k, m) distance [m] from each point (k, 3) to each obstacle's surface, across its
        axis (negative inside it)."""
        d = _across(self.c_w[None, :, :] - np.asarray(points_w, dtype=float).reshape(-1, 3)[:, None, :], self.axis_w)
        return np.linalg.norm(d, axis=2) - self.r_m[None, :]


def _across(v: FloatArray, axes_w: FloatArray) -> FloatArray:
    """``v`` (..., m, 3) without its part along each unit axis of ``axes_w`` (m, 3) (zero
    rows, spheres: ``v`` itself)."""
    return v - np.sum(v * axes_w, axis=-1, keepdims=True) * axes_w


@dataclass(frozen=True)
class PlannerSettings:
    """How paths are planned. Units in the names."""

    resolution_m: float = 0.1  # grid cell size
    clearance_m: float = 0.1  # kept from obstacles beyond the agent's safety radius
    pad_m: float = 2.0  # the grid reaches this far beyond the start, the goal and the obstacles
    max_cells: int = 250_000  # larger grids are refused (a coarser resolution is needed)
    lanes: bool = True  # two-lane passages flown in the right-hand lane (keep_right); False: all in turn

    def __post_init__(self) -> None:
        for name in ("resolution_m", "pad_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"PlannerSettings.{name}: must be a finite number > 0, got {v!r}")
        if not (math.isfinite(self.clearance_m) and self.clearance_m >= 0):
            raise InputError(f"PlannerSettings.clearance_m: must be a finite number >= 0, got {self.clearance_m!r}")


@dataclass(frozen=True)
class Plan:
    """A planned path: ``waypoints_w`` (k >= 2, 3) [m, world] from the start to the goal;
    ``found`` False when no free path exists (then the straight line), with ``reason``."""

    waypoints_w: FloatArray
    found: bool
    reason: str

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.waypoints_w, axis=0), axis=1).sum())


def _segment_points(a: FloatArray, b: FloatArray, step_m: float) -> FloatArray:
    n = max(2, math.ceil(float(np.linalg.norm(b - a)) / step_m) + 1)
    s = np.linspace(0.0, 1.0, n)[:, None]
    return a[None] + s * (b - a)[None]


def clear(a: FloatArray, b: FloatArray, obstacles: StaticObstacles, keep_m: float) -> bool:
    """Whether the segment from ``a`` to ``b`` [m, world] keeps ``keep_m`` from every
    obstacle surface, exactly: each obstacle's nearest point of the segment, in the plane
    across its axis (a sphere's: in space)."""
    if not len(obstacles):
        return True
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    d = _across(np.broadcast_to(b - a, obstacles.axis_w.shape), obstacles.axis_w)  # (m, 3)
    rel = _across(obstacles.c_w - a, obstacles.axis_w)
    dd = np.sum(d * d, axis=1)
    t = np.clip(np.divide(np.sum(rel * d, axis=1), dd, out=np.zeros_like(dd), where=dd > 0.0), 0.0, 1.0)
    gap = np.linalg.norm(rel - t[:, None] * d, axis=1) - obstacles.r_m
    return bool(gap.min() >= keep_m)


class _Grid:
    """The free cells of a plane at altitude ``z_m`` over a box, as a networkx graph."""

    def __init__(self, lo: FloatArray, hi: FloatArray, z_m: float, res: float) -> None:
        self.lo, self.res, self.z = lo, res, z_m
        self.nx, self.ny = int(math.ceil((hi[0] - lo[0]) / res)) + 1, int(math.ceil((hi[1] - lo[1]) / res)) + 1

    def centres(self) -> FloatArray:
        ix, iy = np.meshgrid(np.arange(self.nx), np.arange(self.ny), indexing="ij")
        return np.column_stack([self.lo[0] + ix.ravel() * self.res, self.lo[1] + iy.ravel() * self.res,
                                np.full(ix.size, self.z)])  # fmt: skip

    def graph(self, free: np.ndarray) -> nx.Graph:
        """8-connected graph of the free cells (node: flat index), edges weighted [m]."""
        import networkx as nx  # (imported only where a path must be planned: 0.2 s)

        g = nx.Graph()
        ok = free.reshape(self.nx, self.ny)
        g.add_nodes_from(np.flatnonzero(free).tolist())
        idx = np.arange(self.nx * self.ny).reshape(self.nx, self.ny)
        for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):  # each cell to its neighbour at (+dx, +dy)
            j0, j1 = max(0, -dy), self.ny - max(0, dy)
            a = idx[0 : self.nx - dx, j0:j1]
            b = idx[dx : self.nx, j0 + dy : j1 + dy]
            both = ok.ravel()[a] & ok.ravel()[b]
            w = self.res * math.hypot(dx, dy)
            g.add_weighted_edges_from(zip(a[both].tolist(), b[both].tolist(), [w] * int(both.sum()), strict=True))
        return g


def plan(
    start_w: FloatArray,
    goal_w: FloatArray,
    obstacles: StaticObstacles,
    radius_m: float,
    settings: PlannerSettings | None = None,
    *,
    walls_only: bool = True,
) -> Plan:
    """A path from ``start_w`` to ``goal_w`` [m, world] that keeps the agent's safety radius
    ``radius_m`` [m] plus the settings' clearance from every static obstacle (module
    docstring): the straight line where no wall crosses it (with ``walls_only`` False:
    where no obstacle does). Never raises for a blocked world: a goal with no free path
    gives the straight line with ``found`` False."""
    st = settings or PlannerSettings()
    a, b = np.asarray(start_w, dtype=float), np.asarray(goal_w, dtype=float)
    keep = radius_m + st.clearance_m
    across = obstacles.clustered(2 * keep) if walls_only else obstacles
    if clear(a, b, across, keep):  # no wall across the way: the filter passes the rest
        return Plan(np.vstack([a, b]), True, "straight")
    z = 0.5 * (a[2] + b[2])
    near = obstacles.c_w[:, :2]
    lo = np.minimum(np.minimum(a[:2], b[:2]), near.min(axis=0)) - st.pad_m
    hi = np.maximum(np.maximum(a[:2], b[:2]), near.max(axis=0)) + st.pad_m
    lo = np.maximum(lo, np.minimum(a[:2], b[:2]) - 4 * st.pad_m - 10.0)  # (an infinite cylinder's centre may be far)
    hi = np.minimum(hi, np.maximum(a[:2], b[:2]) + 4 * st.pad_m + 10.0)
    grid = _Grid(lo, hi, z, st.resolution_m)
    if grid.nx * grid.ny > st.max_cells:
        raise InputError(
            f"planner: a {grid.nx} x {grid.ny} grid exceeds max_cells = {st.max_cells}; use a coarser resolution_m"
        )
    centres = grid.centres()
    # a cell is free where the grid's edges from it keep the clearance too: a chord of an
    # edge's length (the diagonal's) between two points at sqrt(R^2 + (L/2)^2) from a centre
    # comes no nearer than R = r + keep to it
    half = 0.5 * math.sqrt(2.0) * st.resolution_m
    reach = np.sqrt((obstacles.r_m + keep) ** 2 + half * half) - obstacles.r_m  # (m,) m from each surface
    free = np.all(obstacles.gaps(centres) >= reach[None, :], axis=1)
    if not free.any():
        return Plan(np.vstack([a, b]), False, "no free cell")
    g = grid.graph(free)
    free_idx = np.flatnonzero(free)
    ends = [int(free_idx[np.argmin(np.sum((centres[free_idx, :2] - p[:2]) ** 2, axis=1))]) for p in (a, b)]
    for p, e in zip((a, b), ends, strict=True):  # a start or goal inside the clearance joins its nearest free cell
        if not clear(p, centres[e], obstacles, radius_m):  # ... unless that way crosses an obstacle
            return Plan(np.vstack([a, b]), False, "start or goal walled in")

    def dist(u: int, v: int) -> float:
        return float(math.dist(centres[u, :2], centres[v, :2]))

    import networkx as nx

    try:
        cells = nx.astar_path(g, ends[0], ends[1], heuristic=dist, weight="weight")
    except nx.NetworkXNoPath:
        return Plan(np.vstack([a, b]), False, "no free path")
    pts = [a, *centres[cells], b]
    way = _shorten(pts, obstacles, keep)
    frac = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(way[:, :2], axis=0), axis=1))])
    way[:, 2] = a[2] + (b[2] - a[2]) * frac / max(frac[-1], 1e-9)  # altitude from start to goal along the path
    return Plan(way, True, "planned")


def _shorten(pts: list[FloatArray], obstacles: StaticObstacles, keep_m: float) -> FloatArray:
    """Line-of-sight shortcuts: from each kept point, the farthest later point in sight
    (the next point when none is: the grid's own step)."""
    out = [pts[0]]
    i = 0
    while i < len(pts) - 1:
        j = len(pts) - 1
        while j > i + 1 and not clear(pts[i], pts[j], obstacles, keep_m):
            j -= 1
        out.append(pts[j])
        i = j
    return np.array(out, dtype=float)


NARROW_M = 0.45
"""A path point with obstacle surfaces closer than this [m] on both sides is in a narrow
passage: two drones, each keeping its safety radius and the planner's clearance, cannot pass
there side by side."""


@dataclass(frozen=True)
class Passage:
    """A narrow stretch of a path: its sample points ``points_w`` (k, 3) [m, world]
    and where it starts and ends, ``s_in_m`` and ``s_out_m`` [m] of path from the start."""

    points_w: FloatArray
    s_in_m: float
    s_out_m: float
    lanes: bool = False  # it has two lanes (has_lanes), each flow in its right-hand one

    @property
    def entry_w(self) -> FloatArray:
        return self.points_w[0]

    @property
    def exit_w(self) -> FloatArray:
        return self.points_w[-1]

    @cached_property
    def along_w(self) -> FloatArray:
        """(3,) unit direction from the entry to the exit (computed once per passage)."""
        along = self.exit_w - self.entry_w
        return along / max(float(np.linalg.norm(along)), 1e-9)

    def holds(self, others_x_w: FloatArray) -> np.ndarray:
        """(k,) whether each position (k, 3) [m, world] is in the passage (within
        :data:`NARROW_M` of one of its points)."""
        return np.min(np.linalg.norm(others_x_w[:, None, :] - self.points_w[None], axis=2), axis=1) < NARROW_M


def _sides(P: FloatArray, T: FloatArray, obstacles: StaticObstacles) -> tuple[FloatArray, FloatArray]:
    """(k,) distances [m] from each point of ``P`` (k, 3), heading along ``T`` (k, 3), to
    the nearest obstacle surface on its left and on its right (inf where there is none)."""
    rel = obstacles.c_w[None, :, :2] - P[:, None, :2]  # (k, m, 2)
    dist = np.linalg.norm(rel, axis=2) - obstacles.r_m[None]
    side = T[:, None, 0] * rel[..., 1] - T[:, None, 1] * rel[..., 0]  # > 0: on the left
    left = np.where(side > 0, dist, math.inf).min(axis=1)
    right = np.where(side < 0, dist, math.inf).min(axis=1)
    return left, right


def _sampled(waypoints_w: FloatArray, step_m: float) -> tuple[FloatArray, FloatArray, FloatArray, IntArray]:
    """The path ``waypoints_w`` (k, 3) sampled every ``step_m`` [m] or less: the points (n,
    3) [m, world], their unit headings (n, 3), their path length [m] from the start (n,)
    and the leg each point ends or lies on (n,) (the first point: leg 0)."""
    W = waypoints_w
    pts, tangents, legs = [W[:1]], [W[1:2] - W[:1]], [np.zeros(1, dtype=np.intp)]
    for k, (a, b) in enumerate(zip(W[:-1], W[1:], strict=True)):
        seg = _segment_points(a, b, step_m)[1:]
        pts.append(seg)
        tangents.append(np.repeat((b - a)[None], len(seg), axis=0))
        legs.append(np.full(len(seg), k, dtype=np.intp))
    P, T = np.vstack(pts), np.vstack(tangents)
    T = T / np.maximum(np.linalg.norm(T, axis=1), 1e-12)[:, None]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
    return P, T, s, np.concatenate(legs)


def _stretches(narrow: np.ndarray) -> list[tuple[int, int]]:
    """The runs of True in ``narrow`` as (first, one past the last) index pairs."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], narrow.astype(np.int8), [0]])))
    return [(int(i), int(j)) for i, j in zip(edges[::2], edges[1::2], strict=True)]


LANE_MARGIN_M = 0.04
"""A narrow passage has two lanes where two agents abreast, each at a third of what the
width leaves (:func:`lane_wall_m`), keep at least this [m] beyond their safety radii from
its walls and from each other."""
LANE_MIN_LENGTH_M = 2.0
"""Only a narrow stretch at least this long [m] is flown in lanes: a shorter one (a doorway)
is crossed in turn in a moment, and a crowd going one way uses its whole width."""


def lane_wall_m(width_m: float | FloatArray, radius_m: float) -> float | FloatArray:
    """How far [m] from its right-hand wall an agent of safety radius ``radius_m`` [m] flies in
    a passage ``width_m`` [m] wide between surfaces, so that its spare distance to the wall
    and to an agent of the same radius in the other lane are equal: ``a - r = w - 2 a - 2 r``."""
    return (width_m - radius_m) / 3.0


def has_lanes(width_m: FloatArray, length_m: float, radius_m: float) -> bool:
    """Whether a narrow stretch ``length_m`` [m] long, ``width_m`` (k,) [m] wide at its
    points, is flown in two lanes by agents of safety radius ``radius_m`` [m]: it is at least
    :data:`LANE_MIN_LENGTH_M` long and two lanes keep :data:`LANE_MARGIN_M` everywhere."""
    spare = lane_wall_m(float(np.min(width_m)), radius_m) - radius_m
    return bool(length_m >= LANE_MIN_LENGTH_M and spare >= LANE_MARGIN_M)


def keep_right(
    waypoints_w: FloatArray, obstacles: StaticObstacles, radius_m: float, step_m: float = 0.05
) -> FloatArray:
    """The path ``waypoints_w`` (k, 3) [m, world] with every narrow stretch that has two lanes
    (:func:`has_lanes`) flown in its right-hand lane, :func:`lane_wall_m` from the wall on
    the right: opposite flows then pass each other there, each in its lane, rather than
    take the passage in turn. The lane reaches :data:`LANE_LEAD_M` beyond each end of its
    stretch, on its own line, and is entered and left by the straightest way that keeps
    ``radius_m`` from every obstacle (a stretch with no such way is flown as planned). Paths
    with no such stretch come back as they are."""
    W = np.asarray(waypoints_w, dtype=float)
    if W.shape[0] < 2 or not len(obstacles):
        return W
    P, T, s, legs = _sampled(W, step_m)
    left, right = _sides(P, T, obstacles)
    narrow = (left < NARROW_M) & (right < NARROW_M)
    out: list[FloatArray] = []
    done = 0  # waypoints W[:done] are in ``out``
    for i, j in _stretches(narrow):
        width = left[i:j] + right[i:j]
        if not has_lanes(width, float(s[j - 1] - s[i]), radius_m):
            continue
        normal = np.column_stack([T[i:j, 1], -T[i:j, 0], np.zeros(j - i)])  # (k, 3) unit, to the right
        lane = _simplified(P[i:j] + (right[i:j] - lane_wall_m(width, radius_m))[:, None] * normal, LANE_TOL_M)
        before, after = int(legs[i]), int(legs[j - 1]) + 1  # W[before] precedes the stretch, W[after] follows it
        lane = _led(lane, W[before], W[after], obstacles, radius_m)
        way_in, way_out = clear(W[before], lane[0], obstacles, radius_m), clear(lane[-1], W[after], obstacles, radius_m)
        if before < done or not (way_in and way_out):
            continue  # no straight way into or out of the lane: the stretch as planned
        out.extend(W[done : before + 1])
        out.extend(lane)
        done = after
    if not out:
        return W
    out.extend(W[done:])
    return _tidy(np.array(out, dtype=float))


LANE_TOL_M = 0.01
"""A lane's waypoints stay within this [m] of the lane."""
LANE_LEAD_M = 0.25
"""A lane is entered this far [m] before its narrow stretch, on its own line, and left this far
after it, where that is clear: a flow's agents are in their lane before they meet the other
flow, not still converging on it at the mouth (two agents half-way there are on a collision
course)."""


def _led(
    lane: FloatArray, before_w: FloatArray, after_w: FloatArray, obstacles: StaticObstacles, radius_m: float
) -> FloatArray:
    """``lane`` (k, 3) [m] extended by :data:`LANE_LEAD_M` at each end along its direction over
    its first (last) metre, where the extension keeps ``radius_m`` from every obstacle and
    the path's point before (``before_w``) or after it (``after_w``) is more than two leads
    away."""
    ends = []
    for pts, other in ((lane, before_w), (lane[::-1], after_w)):
        reach = np.linalg.norm(pts - pts[0], axis=1)
        far = pts[int(np.argmax(reach >= 1.0))] if reach.max() >= 1.0 else pts[-1]
        d = (pts[0] - far) / max(float(np.linalg.norm(pts[0] - far)), 1e-9)
        lead = pts[0] + LANE_LEAD_M * d
        ok = float(np.linalg.norm(other - pts[0])) > 2 * LANE_LEAD_M and clear(lead, pts[0], obstacles, radius_m)
        ends.append(lead if ok else None)
    first, last = ends
    return np.vstack([x for x in (first, *lane, last) if x is not None])


def _simplified(P: FloatArray, tol_m: float) -> FloatArray:
    """Few of the points ``P`` (k, 3), from the first to the last, such that every point of
    ``P`` lies within ``tol_m`` [m] of the polyline through them."""
    out, i, k = [P[0]], 0, len(P)
    while i < k - 1:
        j = k - 1
        while j > i + 1 and _deviation(P[i : j + 1]) > tol_m:
            j -= 1
        out.append(P[j])
        i = j
    return np.array(out)


def _deviation(P: FloatArray) -> float:
    """The largest distance [m] of the points ``P`` (k, 3) from the segment between the first and last."""
    a, d = P[0], P[-1] - P[0]
    t = np.clip((P - a) @ d / max(float(d @ d), 1e-12), 0.0, 1.0)
    return float(np.linalg.norm(P - a - t[:, None] * d, axis=1).max())


def _tidy(W: FloatArray) -> FloatArray:
    """``W`` (k, 3) without inner points within a millimetre of the one before or where the
    path turns back (a lane's first point can lie a little behind the corner it replaces)."""
    out = [W[0]]
    for k in range(1, len(W) - 1):
        if np.linalg.norm(W[k] - out[-1]) > 1e-3 and float((W[k] - out[-1]) @ (W[k + 1] - W[k])) > 0.0:
            out.append(W[k])
    out.append(W[-1])
    return np.array(out)


def _flown_in_lane(width_m: FloatArray, right_m: FloatArray, length_m: float, radius_m: float) -> bool:
    """Whether a walled stretch ``length_m`` [m] long, ``width_m`` (k,) [m] wide, whose path
    points are ``right_m`` (k,) [m] from the wall on their right, is flown in the right-hand
    lane of two by an agent of safety radius ``radius_m`` (see :func:`narrow_stretches`)."""
    if not has_lanes(width_m, length_m + 2 * LANE_LEAD_M, radius_m):
        return False
    return float(np.mean(np.abs(right_m - lane_wall_m(width_m, radius_m)) <= 3 * LANE_TOL_M)) >= 0.8


def narrow_stretches(
    waypoints_w: FloatArray, obstacles: StaticObstacles, radius_m: float | None = None, step_m: float = 0.05
) -> list[Passage]:
    """The stretches of the path ``waypoints_w`` (k, 3) whose points have an obstacle closer
    than :data:`NARROW_M` on both sides (one-lane passages, ``lanes`` False), in order; with
    ``radius_m`` (the agent's safety radius [m]), the stretches the path flies in the
    right-hand lane of two (:func:`keep_right`) instead, with ``lanes`` True. A lane runs off
    its passage's middle, so a lane stretch is judged by the passage's width (less than
    twice :data:`NARROW_M` between walls on both sides), :func:`has_lanes` (its length with
    :data:`LANE_LEAD_M` at each end as slack: a lane's own stretch is a little shorter or
    longer than the one it was made from) and most of its points within ``3 LANE_TOL_M`` of
    the lane; a one-lane stretch within it is no passage."""
    W = np.asarray(waypoints_w, dtype=float)
    if W.shape[0] < 2 or not len(obstacles):
        return []
    P, T, s, _ = _sampled(W, step_m)
    left, right = _sides(P, T, obstacles)
    width = left + right
    lane = np.zeros(len(P), dtype=bool)
    out = []
    if radius_m is not None:
        for i, j in _stretches(width < 2 * NARROW_M):
            if _flown_in_lane(width[i:j], right[i:j], float(s[j - 1] - s[i]), radius_m):
                lane[i:j] = True
                out.append(Passage(P[i:j], float(s[i]), float(s[j - 1]), True))
    for i, j in _stretches((left < NARROW_M) & (right < NARROW_M) & ~lane):
        out.append(Passage(P[i:j], float(s[i]), float(s[j - 1]), False))
    return sorted(out, key=lambda p: p.s_in_m)


CUT_STEP_M = 0.05
"""The step [m] at which a path's clearance from the walls is measured (``swarm.route.Route``)."""
