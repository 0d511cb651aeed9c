"""Swarms that start at rest, as a user spawns them, move and reach every goal: real
processes in lockstep with the default (live) filter and no tie-break."""

from __future__ import annotations

import json

import numpy as np
import pytest

from swarm.config import TiebreakSettings, resolve
from swarm.offline.scenario import SwapSettings, circle_swap, sphere_swap, trap

BODY = 0.07  # Crazyflie bounding radius [m]
MARGIN = 0.02  # filter margin [m]


def sphere_field(seed: int = 3) -> dict:
    """One drone at rest at (0, 0, 1) m, its goal 7 m ahead, eight static spheres
    (radius 0.15 to 0.3 m) scattered between x = 1 and 6 m."""
    rng = np.random.default_rng(seed)
    c = np.column_stack([rng.uniform(1, 6, 8), rng.uniform(-1, 1, 8), 1 + rng.uniform(-0.5, 0.5, 8)])
    r = rng.uniform(0.15, 0.3, 8)
    return {
        "version": 1,
        "name": "sphere_field",
        "duration_s": 16.0,
        "goal_tolerance_m": 0.15,
        "time": {"mode": "lockstep", "physics_hz": 300, "control_hz": 100},
        "defaults": {"speed_mps": 1.0, "command_level": "attitude"},
        "agents": [{"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [7.0, 0.0, 1.0]}],
        "obstacles": [
            {"id": f"s{i}", "shape": "sphere", "center": [round(float(v), 4) for v in c[i]], "radius_m": float(r[i])}
            for i in range(8)
        ],
    }


SCENES = {
    "sphere_8_radius_1p5": lambda: sphere_swap(8, 1.5),
    "exact_two_drone_swap": lambda: circle_swap(2, 2.0, SwapSettings(duration_s=14.0)),
    "drone_before_a_sphere_field": sphere_field,
    "drone_in_a_u_shaped_trap": trap,  # out through the opening on its planned path (swarm.planning)
}


@pytest.mark.parametrize("name", list(SCENES))
def test_a_swarm_at_rest_reaches_every_goal_without_collision(start_run, name):
    raw = SCENES[name]()
    cfg = resolve(raw)
    assert all(a.filter.live and a.tiebreak == TiebreakSettings() for a in cfg.agents)  # the defaults
    assert all(a.planner.kind == "grid" for a in cfg.agents)
    assert all(a.start_velocity == [0.0, 0.0, 0.0] for a in cfg.agents)  # from rest
    h = start_run(cfg, name)
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["collisions"] == 0
    assert m["all_reached_goal"] and not m["deadlocked_agents"], m
    if len(cfg.agents) > 1:
        assert m["min_separation_m"] >= 2 * BODY + MARGIN - 2e-3
    if m["min_obstacle_clearance_m"] is not None:
        assert m["min_obstacle_clearance_m"] >= BODY + MARGIN - 2e-3
