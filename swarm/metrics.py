"""Run metrics from recorded messages (pure: lists of message dicts in, a dict out).

Distances are between body centres (``x + l R e3``), as the barriers use them;
obstacle clearance is to the obstacle surface (cylinders as infinite)."""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Any

import numpy as np

from swarm.config import ScenarioConfig
from swarm.messages import measurement_agent
from swarm.rotation import quat_to_R
from swarm.scenario import items_to_arrays, min_pair_distance, surface_clearance

SUMMARY_KEYS = (
    "collisions",
    "min_separation_m",
    "min_obstacle_clearance_m",
    "all_reached_goal",
    "duration_s",
    "real_time_factor",
    "late_ticks",
    "dropped_messages",
    "lost_agents",
    "stop_reason",
)
"""The run-level metrics a summary shows (``swarm run``'s printout, ``swarm report``'s table)."""


def path_deviation(points_w: np.ndarray, path_w: np.ndarray) -> float:
    """Largest distance [m] of any point from the polyline ``path_w`` (k, 3)."""
    if len(points_w) == 0:
        return 0.0
    if len(path_w) == 1:
        return float(np.linalg.norm(points_w - path_w[0], axis=1).max())
    best = np.full(len(points_w), np.inf)
    for a, b in zip(path_w[:-1], path_w[1:], strict=True):
        d = b - a
        L2 = float(d @ d)
        t = np.clip((points_w - a) @ d / L2, 0.0, 1.0) if L2 > 0 else np.zeros(len(points_w))
        best = np.minimum(best, np.linalg.norm(points_w - (a + t[:, None] * d), axis=1))
    return float(best.max())


def deadlock_start(
    t_s: np.ndarray,
    x_w: np.ndarray,
    v_w: np.ndarray,
    goal_w: np.ndarray,
    tolerance_m: float,
    *,
    speed_mps: float = 0.05,
    hold_s: float = 2.0,
) -> float | None:
    """When [s] an agent became deadlocked, or None.

    Deadlocked: outside ``tolerance_m`` of its goal and slower than ``speed_mps`` without
    a break for at least ``hold_s`` seconds (up to the end of the record). An agent that
    arrives, or that stops only briefly (a yield), is not deadlocked.
    """
    if len(t_s) == 0:
        return None
    stalled = (np.linalg.norm(x_w - goal_w, axis=1) > tolerance_m) & (np.linalg.norm(v_w, axis=1) < speed_mps)
    start: float | None = None
    for t, s in zip(t_s, stalled, strict=True):
        if not s:
            start = None
        elif start is None:
            start = float(t)
        if start is not None and t - start >= hold_s:
            return start
    return None


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) and abs(x) < 1e8 else None


def compute(cfg: ScenarioConfig, records: list[dict[str, Any]], recorder_dropped: int = 0) -> dict[str, Any]:
    """Metrics of one run. ``records`` are decoded messages (``swarm.messages.to_json``)."""
    l_m = {a.id: a.airframe.params().l_m for a in cfg.agents}
    meas: dict[str, list[tuple[float, int, np.ndarray, np.ndarray]]] = defaultdict(list)
    by_tick: dict[int, dict[str, np.ndarray]] = defaultdict(dict)
    obstacles_at: dict[int, Any] = {}
    last_report: dict[str, dict[str, Any]] = {}
    min_h: dict[str, float] = defaultdict(lambda: math.inf)
    solve_us: dict[str, list[float]] = defaultdict(list)
    statuses: list[dict[str, Any]] = []
    collisions: list[dict[str, Any]] = []  # among live agents' drones and obstacles
    dead_contacts: list[dict[str, Any]] = []  # of a dead agent's drone
    stalls: list[dict[str, Any]] = []
    for r in records:
        kind = r["kind"]
        if kind == "measurement":
            aid = measurement_agent(r)
            x, q = np.asarray(r["x"]), np.asarray(r["q"])
            meas[aid].append((r["t"], r["k"], x, np.asarray(r["v"])))
            by_tick[r["k"]][aid] = x + l_m.get(aid, 0.0) * quat_to_R(q)[:, 2]
        elif kind == "obstacles":
            obstacles_at[r["k"]] = r["items"]
        elif kind == "command":
            last_report[r["src"]] = r
            min_h[r["src"]] = min(min_h[r["src"]], r["min_h"])
            solve_us[r["src"]].append(r["solve_us"])
        elif kind == "status":
            statuses.append(r)
        elif kind == "collision":
            (dead_contacts if r.get("dead") else collisions).append(r)
        elif kind == "stall":
            stalls.append({"t_s": r["t"], "k": r["k"], "agents": r["agents"], "wait_s": r["wait_s"]})

    min_sep, min_clear = math.inf, math.inf
    for k, bodies in by_tick.items():
        pts = np.array(list(bodies.values()))
        min_sep = min(min_sep, min_pair_distance(pts))
        if obstacles_at.get(k):
            min_clear = min(min_clear, float(surface_clearance(pts, items_to_arrays(obstacles_at[k])).min()))

    agents: dict[str, Any] = {}
    for a in cfg.agents:
        m = sorted(meas.get(a.id, []), key=lambda e: e[1])
        xs = np.array([e[2] for e in m]) if m else np.zeros((0, 3))
        vs = np.array([e[3] for e in m]) if m else np.zeros((0, 3))
        goal = np.asarray(a.final_goal)
        ts = np.array([e[0] for e in m])
        motion = _motion(ts, vs, np.asarray(a.path(), dtype=float))
        dl = cfg.deadlock
        stuck = deadlock_start(ts, xs, vs, goal, cfg.goal_tolerance_m, speed_mps=dl.speed_mps, hold_s=dl.hold_s)
        us = np.asarray(solve_us.get(a.id, []))
        d = np.linalg.norm(xs - goal, axis=1) if len(xs) else np.zeros(0)
        hit = np.flatnonzero(d <= cfg.goal_tolerance_m)
        st = last_report.get(a.id, {})
        agents[a.id] = {
            "reached_goal": bool(hit.size),
            "time_to_goal_s": float(m[hit[0]][0]) if hit.size else None,
            "path_length_m": float(np.sum(np.linalg.norm(np.diff(xs, axis=0), axis=1))) if len(xs) > 1 else 0.0,
            "straight_line_m": float(np.linalg.norm(goal - np.asarray(a.start))),
            "max_path_deviation_m": path_deviation(xs, np.asarray(a.path(), dtype=float)),
            "min_h": _finite_or_none(min_h[a.id]),
            "infeasible_ticks": int(st.get("infeasible", 0)),
            "dropped_messages": int(st.get("dropped", 0)),
            "last_tick": int(m[-1][1]) if m else None,
            "deadlock_at_s": stuck,
            "solve_us_mean": float(us.mean()) if us.size else None,  # filter call per tick [us]
            "solve_us_p99": float(np.percentile(us, 99)) if us.size else None,
            **motion,
        }
    final = statuses[-1] if statuses else {}
    live_ever = {x for s in statuses for x in s["live"]}
    lost = sorted(live_ever - set(final.get("live", [])))
    return {
        "scenario": cfg.name,
        "mode": cfg.time.mode.value,
        "collisions": len(collisions),
        "collision_pairs": sorted({f"{c['a']}|{c['b']}" for c in collisions}),
        "dead_agent_contacts": len(dead_contacts),  # a dead agent's drone touched something (apart from collisions)
        "dead_agent_contact_pairs": sorted({f"{c['a']}|{c['b']}" for c in dead_contacts}),
        "stalls": len(stalls),  # lockstep ticks that waited longer than time.stall_warn_fraction of the timeout
        "stall_events": stalls,
        "min_separation_m": _finite_or_none(min_sep),
        "min_obstacle_clearance_m": _finite_or_none(min_clear),
        "all_reached_goal": all(v["reached_goal"] for v in agents.values()),
        "deadlocked_agents": sorted(k for k, v in agents.items() if v["deadlock_at_s"] is not None),
        "duration_s": float(final.get("t", 0.0)),
        "finished": bool(final.get("done", False)),  # the world's last status said the run is over
        "real_time_factor": float(final.get("rtf", 0.0)),
        "late_ticks": int(final.get("late", 0)),
        "dropped_messages": int(final.get("dropped", 0))
        + sum(v["dropped_messages"] for v in agents.values())
        + recorder_dropped,
        "lost_agents": lost,
        "agents": agents,
    }


def _motion(t_s: np.ndarray, v_w: np.ndarray, path_w: np.ndarray) -> dict[str, Any]:
    """How the agent moved along its first path leg (the direction it was sent).

    ``min_along_speed_mps`` and ``final_along_speed_mps`` are the velocity [m/s] along
    that direction (negative: backwards); ``backward_time_s`` [s] is how long it moved
    backwards faster than 2 cm/s; ``final_speed_mps`` is |v| at the last measurement.
    """
    if len(v_w) == 0:
        return {
            "min_along_speed_mps": None,
            "final_along_speed_mps": None,
            "backward_time_s": 0.0,
            "final_speed_mps": None,
        }
    leg = path_w[1] - path_w[0] if len(path_w) > 1 else np.zeros(3)
    n = float(np.linalg.norm(leg))
    along = v_w @ (leg / n) if n > 1e-9 else np.zeros(len(v_w))
    dt = np.diff(t_s, append=t_s[-1])
    return {
        "min_along_speed_mps": float(along.min()),
        "final_along_speed_mps": float(along[-1]),
        "backward_time_s": float(dt[along < -0.02].sum()),
        "final_speed_mps": float(np.linalg.norm(v_w[-1])),
    }
