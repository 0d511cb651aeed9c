"""The ORCA baseline (RVO2 through its ``pyrvo`` bindings) on a scenario config.

ORCA is the reference algorithm of reciprocal avoidance: every agent is a holonomic disc
in the plane that picks, each step, the velocity closest to its preferred one among the
velocities that avoid every neighbour for ``time_horizon_s`` if the neighbour does its
half. Here each agent of the config becomes such a disc at its start (x, y), with the
Crazyflie's maximum speed (its target speed) and radius (its airframe radius plus half the
filter margin, so a pair keeps the same distance as C3BF's neighbour rows), and a
preferred velocity towards its goal at target speed (slowing within ``kp`` of it, as the
quadrotor's tracker does). Altitude is kept at the start's; a 3-D (sphere) scenario, or any obstacle but a static
vertical cylinder (an RVO2 polygon), is refused, since RVO2 is planar.

The run writes the same records a real run would (measurements, agent states with the
per-agent solve time, collisions, a final status), so ``swarm.metrics.compute`` gives
exactly the same metrics, into ``metrics.json`` of the run folder.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from swarm.config import ScenarioConfig, dump
from swarm.metrics import compute


def _polygon(centre: list[float], radius_m: float, sides: int = 24) -> list[tuple[float, float]]:
    """A disc [m, world x-y] as RVO2's counter-clockwise polygon, circumscribed (its edges
    stay outside the disc)."""
    r = radius_m / math.cos(math.pi / sides)
    return [
        (centre[0] + r * math.cos(2 * math.pi * k / sides), centre[1] + r * math.sin(2 * math.pi * k / sides))
        for k in range(sides)
    ]


NOT_MEASURED = {
    "min_h": "ORCA has no barrier function",
    "infeasible_ticks": "ORCA's linear program always returns a velocity (its fallback minimises the violation)",
    "real_time_factor": "ORCA steps in one process, against no clock",
}


def run_orca(
    cfg: ScenarioConfig,
    out: Path,
    *,
    time_horizon_s: float = 2.0,
    neighbour_dist_m: float = 3.0,
    max_neighbours: int = 16,
    kp_per_s: float = 1.5,
) -> dict[str, Any]:
    """Simulate ``cfg`` with ORCA at its control rate; write ``config.yaml`` and
    ``metrics.json`` into ``out``; return the metrics."""
    import pyrvo

    z = np.array([a.start[2] for a in cfg.agents])
    for a in cfg.agents:
        if abs(a.final_goal[2] - a.start[2]) > 1e-6:
            raise ValueError(f"ORCA is planar: agent {a.id} changes altitude ({a.start[2]} -> {a.final_goal[2]} m)")
    dt = 1.0 / cfg.time.control_hz
    sim = pyrvo.RVOSimulator()
    sim.set_time_step(dt)
    for o in cfg.obstacles:
        if o.shape != "cylinder" or o.axis is None or math.hypot(o.axis[0], o.axis[1]) > 1e-9 or any(o.velocity):
            raise ValueError(f"ORCA is planar: obstacle {o.id} is not a static vertical cylinder")
        sim.add_obstacle(_polygon(o.center[:2], o.radius_m))
    if cfg.obstacles:
        sim.process_obstacles()
    ids, goals, body = [], [], []
    for a in cfg.agents:
        p = a.airframe.params()
        radius = p.body_radius_m + 0.5 * a.filter.margin_m
        i = sim.add_agent(
            (float(a.start[0]), float(a.start[1])),
            neighbour_dist_m,
            max_neighbours,
            time_horizon_s,
            time_horizon_s,
            radius,
            float(a.speed_mps),
        )
        sim.set_agent_velocity(i, (float(a.start_velocity[0]), float(a.start_velocity[1])))
        ids.append(a.id)
        goals.append(np.array(a.final_goal[:2], dtype=float))
        body.append(p.body_radius_m)
    n = len(ids)
    speed = np.array([a.speed_mps for a in cfg.agents])
    l_m = np.array([a.airframe.params().l_m for a in cfg.agents])
    records: list[dict[str, Any]] = []
    touching: set[tuple[int, int]] = set()
    q = [0.0, 0.0, 0.0, 1.0]
    steps = round(cfg.duration_s * cfg.time.control_hz)
    k = 0
    for k in range(steps + 1):
        t = k * dt
        P = np.array([sim.get_agent_position(i).to_tuple() for i in range(n)])
        V = np.array([sim.get_agent_velocity(i).to_tuple() for i in range(n)])
        for i, aid in enumerate(ids):
            records.append(
                {
                    "kind": "measurement",
                    "agent": aid,
                    "t": t,
                    "k": k,
                    "q": q,
                    "w": [0.0, 0.0, 0.0],
                    "x": [P[i, 0], P[i, 1], z[i]],
                    "v": [V[i, 0], V[i, 1], 0.0],
                }
            )
        centres = np.column_stack([P, z + l_m])
        d = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=2)
        for i in range(n):
            for j in range(i + 1, n):
                if d[i, j] < body[i] + body[j] and (i, j) not in touching:
                    touching.add((i, j))
                    records.append({"kind": "collision", "t": t, "k": k, "a": ids[i], "b": ids[j]})
        to_goal = np.array(goals) - P
        dist = np.linalg.norm(to_goal, axis=1)
        arrived = dist <= cfg.goal_tolerance_m
        if cfg.stop_when_all_reached and arrived.all() or k == steps:
            break
        pref = to_goal * (np.minimum(speed, kp_per_s * dist) / np.maximum(dist, 1e-9))[:, None]
        for i in range(n):
            sim.set_agent_pref_velocity(i, (float(pref[i, 0]), float(pref[i, 1])))
        t0 = time.perf_counter()
        sim.do_step()
        per_agent_us = (time.perf_counter() - t0) * 1e6 / n
        for aid in ids:
            records.append(
                {
                    "kind": "command",
                    "src": aid,
                    "t": t,
                    "k": k,
                    "min_h": math.inf,
                    "solve_us": per_agent_us,
                    "infeasible": 0,
                    "dropped": 0,
                }
            )
    records.append(
        {"kind": "status", "t": k * dt, "k": k, "live": ids, "rtf": 0.0, "late": 0, "dropped": 0, "done": True}
    )
    metrics = compute(cfg, records)
    # what ORCA does not have is left empty, with the reason, not recorded as a measurement
    metrics["real_time_factor"] = None
    for a in metrics["agents"].values():
        a["min_h"] = a["infeasible_ticks"] = None
    metrics["not_measured"] = NOT_MEASURED
    metrics["method"] = "orca"
    metrics["complete"] = True
    metrics["stop_reason"] = "every agent at its goal" if arrived.all() else "the scenario's duration"
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.yaml").write_text(dump(cfg))
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics
