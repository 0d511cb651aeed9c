"""The world's geometry at a sim time, shared by the processes and the offline loop: the
obstacles as message items and as filter rows, distances to their surfaces, the closest
pair of drones."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarm.config import ObstacleConfig
from swarm.rotation import FloatArray
from swarm.safety.obstacles import ObstacleArrays


def obstacle_items(obstacles: list[ObstacleConfig], t_s: float) -> list[dict]:
    """The obstacle message items at sim time ``t_s`` [s] (constant velocity)."""
    out = []
    for o in obstacles:
        c = np.asarray(o.center) + np.asarray(o.velocity) * t_s
        a = np.zeros(3) if o.axis is None else np.asarray(o.axis) / np.linalg.norm(o.axis)
        out.append(
            {"id": o.id, "shape": o.shape, "c": c.tolist(), "cd": list(o.velocity), "r": o.radius_m, "a": a.tolist()}
        )
    return out


def items_to_arrays(items: list[dict]) -> ObstacleArrays:
    """Obstacle arrays of message items (already checked by :func:`swarm.net.messages.decode`:
    finite, radius >= 0; axes are unit or zero as the world sends them)."""
    if not items:
        return ObstacleArrays.empty()
    n = len(items)
    return ObstacleArrays(
        np.array([i["c"] for i in items], dtype=float),
        np.array([i["cd"] for i in items], dtype=float),
        np.zeros((n, 3)),
        np.array([i["r"] for i in items], dtype=float),
        np.array([i["a"] for i in items], dtype=float),
        np.zeros(n, dtype=bool),
    )


def surface_clearance(points_w: FloatArray, obs: ObstacleArrays) -> FloatArray:
    """(n_points, n_obstacles) distance [m] from each point to each obstacle surface."""
    d = obs.c_w[None, :, :] - points_w[:, None, :]
    along = np.sum(d * obs.axis_w[None], axis=2, keepdims=True)
    d = d - along * obs.axis_w[None]
    return np.linalg.norm(d, axis=2) - obs.radius_m[None, :]


def min_pair_distance(points_w: FloatArray) -> float:
    """Smallest distance [m] between any two points, inf with fewer than two."""
    return float(math.sqrt(_min_pair_d2(np.asarray(points_w, dtype=np.float64))))


@njit(cache=True)
def _min_pair_d2(p):
    """Smallest squared distance between two rows of ``p`` (n, 3); inf with n < 2."""
    best = np.inf
    n = p.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            d0, d1, d2 = p[i, 0] - p[j, 0], p[i, 1] - p[j, 1], p[i, 2] - p[j, 2]
            best = min(best, d0 * d0 + d1 * d1 + d2 * d2)
    return best
