"""The ORCA baseline (RVO2 and RVO2-3D, the reference implementations) on a scenario config.

ORCA is the reference algorithm of reciprocal avoidance: every agent is a holonomic disc
(or ball) that picks, each step, the velocity closest to its preferred one among the
velocities that avoid every neighbour for ``time_horizon_s`` if the neighbour does its
half. Here each agent of the config becomes such a disc at its start, with the
Crazyflie's maximum speed (its target speed) and radius (its airframe radius plus half the
filter margin, so a pair keeps the same distance as C3BF's neighbour rows), and a
preferred velocity towards its goal at target speed (slowing within ``kp`` of it, as the
quadrotor's tracker does).

Two backends, picked by the scenario:

* planar (RVO2 through ``pyrvo``): every agent keeps its start's altitude; obstacles must
  be static vertical cylinders (RVO2 polygons);
* spatial (RVO2-3D through ``jt-pyrvo23d``): some agent changes altitude (a sphere swap);
  RVO2-3D has no obstacles, so a spatial scenario with obstacles is refused.

A planar scenario stays planar (the disc model ORCA's papers and the 2-D benchmarks use),
although RVO2-3D could also fly it with altitude changes.

The run writes the same records a real run would (measurements, agent states with the
per-agent solve time, collisions, a final status), so ``swarm.offline.metrics.compute`` gives
exactly the same metrics, into ``metrics.json`` of the run folder.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from swarm.config import AgentConfig, ScenarioConfig, dump
from swarm.offline.metrics import compute
from swarm.rotation import FloatArray


def _polygon(centre: list[float], radius_m: float, sides: int = 24) -> list[tuple[float, float]]:
    """A disc [m, world x-y] as RVO2's counter-clockwise polygon, circumscribed (its edges
    stay outside the disc)."""
    r = radius_m / math.cos(math.pi / sides)
    return [
        (centre[0] + r * math.cos(2 * math.pi * k / sides), centre[1] + r * math.sin(2 * math.pi * k / sides))
        for k in range(sides)
    ]


NOT_MEASURED = {
    "min_row_h": "ORCA has no barrier rows (its min_h, the exact C3BF barrier from the measured states, is)",
    "infeasible_ticks": "ORCA's linear program always returns a velocity (its fallback minimises the violation)",
    "real_time_factor": "ORCA steps in one process, against no clock",
}


class _Planar:
    """RVO2 (``pyrvo``): discs at their starts' altitudes."""

    def __init__(self, cfg: ScenarioConfig, dt: float, horizon_s: float, neighbour_dist_m: float, max_nb: int) -> None:
        import pyrvo

        self.z = np.array([a.start[2] for a in cfg.agents], dtype=float)  # m: the altitudes kept
        self.sim = sim = pyrvo.RVOSimulator()
        sim.set_time_step(dt)
        for o in cfg.obstacles:
            if o.shape != "cylinder" or o.axis is None or math.hypot(o.axis[0], o.axis[1]) > 1e-9 or any(o.velocity):
                raise ValueError(f"ORCA is planar with obstacles: obstacle {o.id} is not a static vertical cylinder")
            sim.add_obstacle(_polygon(o.center[:2], o.radius_m))
        if cfg.obstacles:
            sim.process_obstacles()
        for a in cfg.agents:
            i = sim.add_agent(
                (float(a.start[0]), float(a.start[1])),
                neighbour_dist_m,
                max_nb,
                horizon_s,
                horizon_s,
                _radius(a),
                float(a.speed_mps),
            )
            sim.set_agent_velocity(i, (float(a.start_velocity[0]), float(a.start_velocity[1])))

    def state(self) -> tuple[FloatArray, FloatArray]:
        """Positions [m] and velocities [m/s] (n, 3), world."""
        n = len(self.z)
        P = np.array([self.sim.get_agent_position(i).to_tuple() for i in range(n)])
        V = np.array([self.sim.get_agent_velocity(i).to_tuple() for i in range(n)])
        return np.column_stack([P, self.z]), np.column_stack([V, np.zeros(n)])

    def step(self, pref_w: FloatArray) -> None:
        """One step with preferred velocities ``pref_w`` (n, 3) [m/s, world]; z is dropped."""
        for i, v in enumerate(pref_w):
            self.sim.set_agent_pref_velocity(i, (float(v[0]), float(v[1])))
        self.sim.do_step()

    def set_state(self, P: FloatArray, V: FloatArray) -> None:
        """Every agent at positions ``P`` [m] with velocities ``V`` [m/s] (n, 3), world; z dropped."""
        for i in range(len(self.z)):
            self.sim.set_agent_position(i, (float(P[i, 0]), float(P[i, 1])))
            self.sim.set_agent_velocity(i, (float(V[i, 0]), float(V[i, 1])))


class _Spatial:
    """RVO2-3D (``jt-pyrvo23d``'s ``rvo23d``): balls in space; no obstacles."""

    def __init__(self, cfg: ScenarioConfig, dt: float, horizon_s: float, neighbour_dist_m: float, max_nb: int) -> None:
        import rvo23d

        if cfg.obstacles:
            raise ValueError("ORCA in 3-D (RVO2-3D) has no obstacles: this scenario changes altitude and has some")
        a0 = cfg.agents[0]
        # the constructor takes the agent defaults: time step, neighbour distance, max neighbours,
        # time horizon, radius, max speed (rvo23d.pyx, wrapping RVO2-3D's RVOSimulator)
        self.sim = sim = rvo23d.PyRVOSimulator(dt, neighbour_dist_m, max_nb, horizon_s, _radius(a0), a0.speed_mps)
        for a in cfg.agents:
            sim.addAgent(
                tuple(float(c) for c in a.start),
                neighbour_dist_m,
                max_nb,
                horizon_s,
                _radius(a),
                float(a.speed_mps),
                tuple(float(c) for c in a.start_velocity),
            )
        self.n = len(cfg.agents)

    def state(self) -> tuple[FloatArray, FloatArray]:
        """Positions [m] and velocities [m/s] (n, 3), world."""
        P = np.array([self.sim.getAgentPosition(i) for i in range(self.n)], dtype=float)
        V = np.array([self.sim.getAgentVelocity(i) for i in range(self.n)], dtype=float)
        return P, V

    def step(self, pref_w: FloatArray) -> None:
        """One step with preferred velocities ``pref_w`` (n, 3) [m/s, world]."""
        for i, v in enumerate(pref_w):
            self.sim.setAgentPrefVelocity(i, (float(v[0]), float(v[1]), float(v[2])))
        self.sim.doStep()

    def set_state(self, P: FloatArray, V: FloatArray) -> None:
        """Every agent at positions ``P`` [m] with velocities ``V`` [m/s] (n, 3), world."""
        for i in range(self.n):
            self.sim.setAgentPosition(i, tuple(float(c) for c in P[i]))
            self.sim.setAgentVelocity(i, tuple(float(c) for c in V[i]))


def _radius(agent: AgentConfig) -> float:
    """An agent's ORCA radius [m]: airframe radius plus half the filter margin."""
    return agent.airframe.params().body_radius_m + 0.5 * agent.filter.margin_m


def planar(cfg: ScenarioConfig) -> bool:
    """Whether every agent of ``cfg`` keeps its start's altitude (ORCA's planar backend)."""
    return all(abs(a.final_goal[2] - a.start[2]) <= 1e-6 for a in cfg.agents)


WAYPOINT_REACHED_M = 0.3
"""ORCA with paths: an agent this close [m] to its next waypoint aims at the one after."""


def _next_waypoints(paths: list[FloatArray], nxt: list[int], P: FloatArray) -> FloatArray:
    """Each agent's waypoint to aim at (advancing ``nxt`` in place past reached ones)."""
    out = np.empty_like(P)
    for i, W in enumerate(paths):
        while nxt[i] < len(W) - 1 and np.linalg.norm(W[nxt[i]] - P[i]) <= WAYPOINT_REACHED_M:
            nxt[i] += 1
        out[i] = W[min(nxt[i], len(W) - 1)]
    return out


def run_orca(
    cfg: ScenarioConfig,
    out: Path,
    *,
    time_horizon_s: float = 2.0,
    neighbour_dist_m: float = 3.0,
    max_neighbours: int = 16,
    kp_per_s: float = 1.5,
    paths: list[FloatArray] | None = None,
    seen_delay_ticks: int = 0,
    command_delay_ticks: int = 0,
) -> dict[str, Any]:
    """Simulate ``cfg`` with ORCA at its control rate (the planar backend if every agent
    keeps its altitude, else the spatial one); write ``config.yaml`` and ``metrics.json``
    into ``out``; return the metrics. A scenario neither backend can fly raises ValueError.
    Each agent's preferred velocity points at its goal, or with ``paths`` (one (k, 3)
    waypoint array [m, world] per agent, from its start) at its next waypoint, taken as
    reached within ``WAYPOINT_REACHED_M``.

    Delays (the sweeps' analogue of the filters' late links, ``tools.bench_imperfections``):
    with ``seen_delay_ticks`` every agent computes its velocity from every position and velocity
    (its own included) as they were that many ticks ago, and with ``command_delay_ticks`` the
    velocity it chose flies that many ticks later (each agent holds the last one it flew till
    then). ORCA has no estimator or predictor: it takes what it sees as the present."""
    delayed = seen_delay_ticks > 0 or command_delay_ticks > 0
    if seen_delay_ticks < 0 or command_delay_ticks < 0:
        raise ValueError("run_orca: delays are whole ticks, at least 0")
    dt = 1.0 / cfg.time.control_hz
    backend = (_Planar if planar(cfg) else _Spatial)(cfg, dt, time_horizon_s, neighbour_dist_m, max_neighbours)
    ids = [a.id for a in cfg.agents]
    goals = np.array([a.final_goal for a in cfg.agents], dtype=float)
    body = [a.airframe.params().body_radius_m for a in cfg.agents]
    n = len(ids)
    speed = np.array([a.speed_mps for a in cfg.agents])
    l_m = np.array([a.airframe.params().l_m for a in cfg.agents])
    records: list[dict[str, Any]] = []
    touching: set[tuple[int, int]] = set()
    q = [0.0, 0.0, 0.0, 1.0]
    steps = round(cfg.duration_s * cfg.time.control_hz)
    nxt = [1] * n  # each agent's next waypoint (with paths)
    k = 0
    P, V = backend.state()
    seen: list[tuple[FloatArray, FloatArray]] = []  # (P, V) of the last ticks, oldest first
    flying: list[FloatArray] = []  # the velocities chosen and not yet flown, oldest first
    for k in range(steps + 1):
        t = k * dt
        if not delayed:
            P, V = backend.state()
        for i, aid in enumerate(ids):
            records.append(
                {
                    "kind": "measurement",
                    "agent": aid,
                    "t": t,
                    "k": k,
                    "q": q,
                    "w": [0.0, 0.0, 0.0],
                    "x": P[i].tolist(),
                    "v": V[i].tolist(),
                }
            )
        centres = P + np.outer(l_m, [0.0, 0.0, 1.0])
        d = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=2)
        for i in range(n):
            for j in range(i + 1, n):
                if d[i, j] < body[i] + body[j] and (i, j) not in touching:
                    touching.add((i, j))
                    records.append({"kind": "collision", "t": t, "k": k, "a": ids[i], "b": ids[j]})
        arrived = np.linalg.norm(goals - P, axis=1) <= cfg.goal_tolerance_m
        if cfg.stop_when_all_reached and arrived.all() or k == steps:
            break
        aim = goals if paths is None else _next_waypoints(paths, nxt, P)
        to_aim = aim - P
        dist = np.linalg.norm(to_aim, axis=1)
        slow = np.linalg.norm(goals - P, axis=1)  # slowing within kp of the goal, not of a waypoint
        pref = to_aim * (np.minimum(speed, kp_per_s * slow) / np.maximum(dist, 1e-9))[:, None]
        t0 = time.perf_counter()
        if delayed:
            seen = [*seen[-seen_delay_ticks:], (P.copy(), V.copy())] if seen_delay_ticks else [(P.copy(), V.copy())]
            backend.set_state(*seen[0])  # (what every agent sees: as it was seen_delay_ticks ago)
        backend.step(pref)
        per_agent_us = (time.perf_counter() - t0) * 1e6 / n
        if delayed:  # the velocity chosen flies command_delay_ticks later; the true state moves by what flies now
            flying.append(backend.state()[1])
            if len(flying) > command_delay_ticks:
                V = flying.pop(0)
            P = P + V * dt
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
        a["min_row_h"] = a["infeasible_ticks"] = None
    metrics["not_measured"] = NOT_MEASURED
    metrics["method"] = "orca"
    metrics["complete"] = True
    metrics["stop_reason"] = "every agent at its goal" if arrived.all() else "the scenario's duration"
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.yaml").write_text(dump(cfg))
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics
