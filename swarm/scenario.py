"""Pure helpers shared by the processes: obstacle geometry at time t, separations."""

from __future__ import annotations

import math

import numpy as np

from swarm.config import ObstacleConfig
from swarm.obstacles import ObstacleArrays
from swarm.rotation import FloatArray


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
    """Obstacle arrays of message items (already checked by :func:`swarm.messages.decode`:
    finite, radius >= 0; axes are unit or zero as the world sends them)."""
    if not items:
        return ObstacleArrays.empty()
    n = len(items)
    return ObstacleArrays(
        np.array([i["c"] for i in items], dtype=float), np.array([i["cd"] for i in items], dtype=float),
        np.zeros((n, 3)), np.array([i["r"] for i in items], dtype=float),
        np.array([i["a"] for i in items], dtype=float), np.zeros(n, dtype=bool),
    )  # fmt: skip


def surface_clearance(points_w: FloatArray, obs: ObstacleArrays) -> FloatArray:
    """(n_points, n_obstacles) distance [m] from each point to each obstacle surface."""
    d = obs.c_w[None, :, :] - points_w[:, None, :]
    along = np.sum(d * obs.axis_w[None], axis=2, keepdims=True)
    d = d - along * obs.axis_w[None]
    return np.linalg.norm(d, axis=2) - obs.radius_m[None, :]


def min_pair_distance(points_w: FloatArray) -> float:
    """Smallest distance [m] between any two points, inf with fewer than two."""
    n = len(points_w)
    if n < 2:
        return float("inf")
    i, j = np.triu_indices(n, 1)
    return float(np.linalg.norm(points_w[i] - points_w[j], axis=1).min())


def circle_swap(
    n: int,
    radius_m: float = 2.0,
    *,
    altitude_m: float = 1.0,
    speed_mps: float = 0.8,
    rotation_rad: float = 0.05,
    control_hz: float = 120.0,
    physics_hz: float = 240.0,
    duration_s: float = 20.0,
    mode: str = "lockstep",
    name: str | None = None,
) -> dict:
    """A raw scenario (as :func:`swarm.config.resolve` takes it): ``n`` agents swapping
    antipodal points of a circle. ``rotation_rad`` turns the whole pattern slightly off
    the axes; it does not break the swap's symmetry."""
    agents = []
    for i in range(n):
        th = 2 * math.pi * i / n + rotation_rad
        start = [round(radius_m * math.cos(th), 6), round(radius_m * math.sin(th), 6), altitude_m]
        agents.append({"id": f"cf{i + 1}", "start": start, "goal": [-start[0], -start[1], altitude_m]})
    return {
        "version": 1, "name": name or f"circle_{n}", "duration_s": duration_s, "goal_tolerance_m": 0.15,
        "time": {"mode": mode, "physics_hz": physics_hz, "control_hz": control_hz},
        "defaults": {"speed_mps": speed_mps, "command_level": "attitude", "filter": {"kind": "c3bf", "gamma": 1.0}},
        "agents": agents,
    }  # fmt: skip
