"""Liveness benchmark: swarms that start at rest, C3BF (live rows, the default) beside
ORCA on the same scenes. Prints one JSON line per scene family point.

Each point flies its scenes in one process (``swarm.offline.closed_loop.fly_scenario``: a
lockstep run of the processes, bit for bit: the agents as ``swarm agent`` builds them, the
firmware's attitude loop, the world's PyBullet bodies, each agent's neighbours' states of the
tick before) for every seed, and reports the success rate (every
agent at its goal, no contact), collisions (contacts: pairs and obstacle contacts), margin
violations (pairs and agent-obstacles ever inside the safety radius, body radii plus the
margin), deadlocked agents (``swarm.offline.metrics.deadlock_at``, the same rule for ORCA), infeasible
agent ticks (every filter status but OK), and the mean and worst time
to goal over the straight-line time (distance / target speed). ORCA (``swarm.offline.orca``: RVO2
on planar scenes, RVO2-3D on the sphere swaps) runs the same scene at rho = 1, with its
figures under ``orca``; ``null`` where it cannot (3-D with obstacles) and at rho = 0.5.

    python -m tools.bench_liveness                 # every family (about 15 min on 2 cores)
    python -m tools.bench_liveness --quick         # one seed, smaller swarms
    python -m tools.bench_liveness --family circle --jobs 2
    python -m tools.bench_liveness --engine ray --address HEAD:6379   # each scene a Ray task

    python -m tools.bench_liveness --horizon-s 2   # with the live rows' horizon allowance
    python -m tools.bench_liveness --buffer-mps 0  # without the live rows' velocity buffer
    python -m tools.bench_liveness --contact-s 0   # without the neighbour rows' contact horizon
    python -m tools.bench_liveness --no-free-braking   # neighbour rows price braking as the cone does
    python -m tools.bench_liveness --no-ellipsoid  # drones' rows keep the sphere, not the keep-out ellipsoid
    python -m tools.bench_liveness --gamma 1       # the paper's gain, as hand-written configs fly
    python -m tools.bench_liveness --gamma 1 --sensing-radius-m 3   # ... and their sensing radius

Keys (stable): family, scene, n, rho, exact, runs, success_rate, collisions, margin_violations,
min_h and negative_h_ticks (the exact C3BF barrier, ``swarm.offline.metrics``), downwash_pairs,
downwash_pair_ticks and min_downwash_distance (pairs inside their downwash keep-out ellipsoid,
``swarm.offline.metrics``; summed, and the smallest scaled distance), deadlocks,
infeasible_ticks, mean_time_ratio, worst_time_ratio (against the straight line),
mean_free_time_ratio, worst_free_time_ratio (against the shortest path that keeps the safety radius
from the static obstacles: :func:`free_times`), per_run (each seed's success, collisions,
margin_violations, deadlocks, infeasible ticks and time ratios), orca, orca_path (ORCA along the
paths the C3BF agents plan, among walls), horizon_s, buffer_mps, contact_s, free_braking, gamma,
sensing_radius_m, ellipsoid (null: the default), realism (``--realism``: the world's preset),
estimate_error_p95_m (the worst run's 95th percentile of |estimate - truth|, m; null without motion
capture), estimate_error_max_m (the largest), monitor_ticks (agent ticks the safety monitor slowed,
held and landed, ``swarm.safety.monitor``), landed_by_monitor (agents it landed),
home_or_landed_rate (runs with no contact in which every agent reached its goal or was landed by
its monitor), unguarded_ticks (agent ticks an estimate's true error exceeded its live bound while
the monitor was not acting), agent_ticks (agents x ticks flown), max_live_margin_m (the largest
live noise margin a row kept).

    python -m tools.bench_liveness --realism crazyflie_lab --no-orca   # the same scenes in the lab
    python -m tools.bench_liveness --realism crazyflie_lab_bad_day --no-orca   # and on its bad day

Families among walls (``doorway`` 2 to 8 abreast, ``corridor`` two flows of 4, ``trap``,
``forest`` at two densities, ``swarm.offline.scenario``) fly the paths each agent plans
(``swarm.planning``), as every agent does by default where there are static obstacles.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from swarm.build import path_of
from swarm.config import ScenarioConfig, resolve
from swarm.offline.closed_loop import fly_scenario, outcome
from swarm.offline.scenario import (
    SwapSettings,
    circle_swap,
    corridor,
    doorway,
    forest,
    formation,
    pillar_swap,
    sphere_field,
    sphere_swap,
    trap,
)
from swarm.planning import PlannerSettings, StaticObstacles, plan
from swarm.safety.monitor import Action

PERTURB_M = 0.05  # perturbed swaps: starts and goals moved up to this much per axis


@dataclass(frozen=True)
class Point:
    """One line of output: a family, its scene parameters, and the seeds it runs."""

    family: str
    scene: str
    n: int
    rho: float
    exact: bool
    make: Callable[[int], dict]  # seed -> raw scenario
    seeds: tuple[int, ...]


def _with_filter(raw: dict, rho: float, **fields: float | bool | None) -> dict:
    """``raw`` with every agent's responsibility share ``rho`` and the other filter
    ``fields`` (``horizon_s`` [s], ``buffer_mps`` [m/s], ``contact_s`` [s],
    ``free_braking``, ``gamma`` [1/s], ``sensing_radius_m`` [m], ``ellipsoid``; None: unset,
    the config's own)."""
    filt = raw["defaults"].setdefault("filter", {})
    filt["rho"] = rho
    filt.update({k: v for k, v in fields.items() if v is not None})
    return raw


def _field(k: int, seed: int) -> dict:
    return sphere_field(k, SwapSettings(seed=seed))


def _circle(n: int, perturbed: bool, seed: int) -> dict:
    return circle_swap(n, 2.0 if n <= 16 else 3.0, SwapSettings(perturb_m=PERTURB_M, seed=seed) if perturbed else None)


def _sphere(n: int, radius_m: float, seed: int) -> dict:
    return sphere_swap(n, radius_m)


def _formation(seed: int) -> dict:
    return formation(4)


def _pillar(perturbed: bool, seed: int) -> dict:
    return pillar_swap(8, settings=SwapSettings(perturb_m=PERTURB_M, seed=seed) if perturbed else None)


def _doorway(n: int, seed: int) -> dict:
    return doorway(n)


def _corridor(n: int, seed: int) -> dict:
    return corridor(n)


def _trap(seed: int) -> dict:
    return trap()


def _forest(density: float, seed: int) -> dict:
    return forest(4, density, SwapSettings(seed=seed))


WALLS = ("doorway", "corridor", "trap", "forest")
"""The families among walls (their time ratios are against the shortest free path)."""


def points(quick: bool, seeds: int) -> Iterator[Point]:
    few = (0,) if quick else tuple(range(seeds))
    for rho in (1.0, 0.5):
        for density, k in (("sparse", 5), ("medium", 10), ("dense", 20)):
            yield Point("sphere_field", density, 1, rho, False, partial(_field, k), few)
        for n in (2, 4, 8) if quick else (2, 4, 8, 16, 32):
            yield Point("circle", f"circle_{n}", n, rho, True, partial(_circle, n, False), (0,))
            yield Point("circle", f"circle_{n}", n, rho, False, partial(_circle, n, True), few)
        for n in (8,) if quick else (8, 12, 16, 32):
            for radius in (2.0, 1.5):
                yield Point("sphere", f"sphere_{n}_r{radius:g}", n, rho, True, partial(_sphere, n, radius), (0,))
        yield Point("formation", "formation_4", 4, rho, True, _formation, (0,))
        yield Point("pillar", "pillar_8", 8, rho, True, partial(_pillar, False), (0,))
        yield Point("pillar", "pillar_8", 8, rho, False, partial(_pillar, True), few)
        for n in (2, 6) if quick else (2, 4, 6, 8):
            yield Point("doorway", f"doorway_{n}", n, rho, True, partial(_doorway, n), (0,))
        yield Point("corridor", "corridor_4x2", 8, rho, True, partial(_corridor, 4), (0,))
        yield Point("trap", "trap", 1, rho, True, _trap, (0,))
        for trees in (0.3, 0.6):
            yield Point("forest", f"forest_4_d{trees:g}", 4, rho, False, partial(_forest, trees), few)


def _c3bf(cfg: ScenarioConfig) -> dict[str, Any]:
    log = fly_scenario(cfg)
    err = log.estimate_error_m
    o = outcome(cfg, log)
    free = free_times(cfg)
    return {
        "free_ratios": [t / f for t, f in zip(log.time_to_goal_s, free, strict=True) if t is not None and f > 0],
        "success": o.success,
        "collisions": o.collisions,
        "margin_violations": o.margin_violations,
        "min_h": o.min_h,
        "negative_h_ticks": o.negative_h_ticks,
        "downwash_pairs": o.downwash_pairs,
        "downwash_pair_ticks": o.downwash_pair_ticks,
        "min_downwash_distance": o.min_downwash_distance,
        "deadlocks": o.deadlocked,
        "infeasible": o.infeasible_ticks,
        "ratios": o.time_ratios,
        "estimate_error_p95_m": None if err is None else float(np.percentile(err, 95)),
        "estimate_error_max_m": None if err is None else float(err.max()),
        "commands_lost": log.commands_lost,
        "states_lost": log.states_lost,
        "monitor_ticks": {a.name.lower(): log.action_ticks(a) for a in (Action.SLOW, Action.HOLD, Action.LAND)},
        "breach_ticks": {k: v for k, v in log.breach_ticks.items() if v},
        "landed_by_monitor": sum(log.landed_by_monitor),
        "home_or_landed": o.collisions == 0
        and all(t is not None or landed for t, landed in zip(log.time_to_goal_s, log.landed_by_monitor, strict=True)),
        "unguarded_ticks": log.unguarded_ticks,
        "agent_ticks": int(log.x_b_w.shape[0] * log.x_b_w.shape[1]),
        "max_live_margin_m": None if log.live_margin_m is None else float(log.live_margin_m.max()),
    }


def free_times(cfg: ScenarioConfig) -> list[float]:
    """Each agent's time [s] at its target speed along the shortest path that keeps its
    safety radius from every static vertical cylinder, isolated ones too (the grid planner
    with no clearance, 5 cm cells: a few per cent longer than the exact shortest path at
    most); the straight line where that is clear."""
    still = StaticObstacles.of(list(cfg.obstacles))
    fine = PlannerSettings(resolution_m=0.05, clearance_m=0.0)
    out = []
    for a in cfg.agents:
        r = a.airframe.params().body_radius_m + a.filter.margin_m
        shortest = plan(np.array(a.start), np.array(a.final_goal), still, r, fine, walls_only=False)
        out.append(shortest.length_m / a.speed_mps)
    return out


def _orca(cfg: ScenarioConfig, with_paths: bool = False) -> dict[str, Any] | None:
    """ORCA on ``cfg``, its preferred velocity at the goal, or with ``with_paths`` along the
    path each C3BF agent plans (swarm.planning); None where ORCA cannot fly the scene."""
    from swarm.offline.orca import run_orca

    still = StaticObstacles.of(list(cfg.obstacles))
    paths = [path_of(a, still)[0] for a in cfg.agents] if with_paths else None
    with tempfile.TemporaryDirectory() as tmp:
        try:
            m = run_orca(cfg, Path(tmp), paths=paths)
        except ValueError:  # a scene neither RVO2 nor RVO2-3D can fly
            return None
    ratios = [
        a["time_to_goal_s"] / (a["straight_line_m"] / cfg.agents[i].speed_mps)
        for i, a in enumerate(m["agents"].values())
        if a["time_to_goal_s"] is not None
    ]
    free = free_times(cfg)
    return {
        "free_ratios": [
            a["time_to_goal_s"] / free[i]
            for i, a in enumerate(m["agents"].values())
            if a["time_to_goal_s"] is not None and free[i] > 0
        ],
        "success": bool(m["all_reached_goal"]) and m["collisions"] == 0,
        "collisions": m["collisions"],
        "margin_violations": m["margin_violations"],
        "min_h": m["min_h"],
        "negative_h_ticks": m["negative_h_ticks"],
        "downwash_pairs": m["downwash_pairs"],
        "downwash_pair_ticks": m["downwash_pair_ticks"],
        "min_downwash_distance": m["min_downwash_distance"],
        "deadlocks": len(m["deadlocked_agents"]),
        "infeasible": None,
        "ratios": ratios,
    }


def _run(args: tuple[dict, bool]) -> tuple[dict[str, Any], dict[str, Any] | None, dict[str, Any] | None]:
    """One scene: C3BF, and with ``with_orca`` ORCA (and, among walls, ORCA along the
    planned paths)."""
    raw, with_orca = args
    cfg = resolve(raw)
    walls = any(not any(o.velocity) for o in cfg.obstacles) and cfg.name.split("_")[0] in WALLS
    return (
        _c3bf(cfg),
        _orca(cfg) if with_orca else None,
        _orca(cfg, with_paths=True) if with_orca and walls else None,
    )


def _summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The figures of one point over its runs, with each run's own (``per_run``: every mean
    and count can be recomputed from them)."""
    ratios = [r for run in runs for r in run["ratios"]]
    free = [r for run in runs for r in run["free_ratios"]]
    infeasible = [run["infeasible"] for run in runs]
    return {
        "runs": len(runs),
        "success_rate": sum(r["success"] for r in runs) / len(runs),
        "collisions": sum(r["collisions"] for r in runs),
        "margin_violations": sum(r["margin_violations"] for r in runs),
        "min_h": min((r["min_h"] for r in runs if r["min_h"] is not None), default=None),
        "negative_h_ticks": sum(r["negative_h_ticks"] for r in runs),
        "downwash_pairs": sum(r["downwash_pairs"] for r in runs),
        "downwash_pair_ticks": sum(r["downwash_pair_ticks"] for r in runs),
        "min_downwash_distance": min(
            (r["min_downwash_distance"] for r in runs if r["min_downwash_distance"] is not None), default=None
        ),
        "deadlocks": sum(r["deadlocks"] for r in runs),
        "infeasible_ticks": None if None in infeasible else sum(infeasible),
        "mean_time_ratio": round(float(np.mean(ratios)), 3) if ratios else None,
        "worst_time_ratio": round(float(np.max(ratios)), 3) if ratios else None,
        "mean_free_time_ratio": round(float(np.mean(free)), 3) if free else None,
        "worst_free_time_ratio": round(float(np.max(free)), 3) if free else None,
        "estimate_error_p95_m": max((r.get("estimate_error_p95_m") or 0.0 for r in runs), default=0.0) or None,
        "estimate_error_max_m": max((r.get("estimate_error_max_m") or 0.0 for r in runs), default=0.0) or None,
        "monitor_ticks": {k: sum(r.get("monitor_ticks", {}).get(k, 0) for r in runs) for k in ("slow", "hold", "land")},
        "landed_by_monitor": sum(r.get("landed_by_monitor", 0) for r in runs),
        "home_or_landed_rate": sum(bool(r.get("home_or_landed", r["success"])) for r in runs) / len(runs),
        "unguarded_ticks": sum(r.get("unguarded_ticks", 0) for r in runs),
        "agent_ticks": sum(r.get("agent_ticks", 0) for r in runs),
        "max_live_margin_m": max((r.get("max_live_margin_m") or 0.0 for r in runs), default=0.0) or None,
        "per_run": runs,
    }


class _Pool:
    """Where the scenes fly: ``local``, a process pool of ``jobs``; ``ray``, one Ray task per
    scene (one CPU each) on the cluster at ``address`` or a local one (swarm.runs.ray_engine)."""

    def __init__(self, engine: str, jobs: int, address: str | None) -> None:
        self.engine, self.jobs, self.address = engine, jobs, address

    def __enter__(self) -> _Pool:
        if self.engine == "ray":
            from swarm.runs.ray_engine import import_ray

            self.ray = import_ray()
            self.ray.init(address=self.address, ignore_reinit_error=True, include_dashboard=False, log_to_driver=False)
            self.task = self.ray.remote(num_cpus=1, max_retries=1)(_run)
        else:
            self.pool = ProcessPoolExecutor(max_workers=self.jobs)
        return self

    def map(self, args: list[tuple[dict, bool]]) -> list[tuple[dict[str, Any], dict[str, Any] | None, Any]]:
        if self.engine == "ray":
            return list(self.ray.get([self.task.remote(a) for a in args]))
        return list(self.pool.map(_run, args))

    def __exit__(self, *exc: object) -> None:
        if self.engine != "ray":
            self.pool.shutdown()


@dataclass(frozen=True)
class Knobs:
    """Filter settings given to every agent of every scene (None: the config's own)."""

    horizon_s: float | None = None  # [s]
    buffer_mps: float | None = None  # [m/s]
    contact_s: float | None = None  # [s]
    free_braking: bool | None = None
    gamma: float | None = None  # [1/s]
    sensing_radius_m: float | None = None  # [m]
    ellipsoid: bool | None = None


def main(
    quick: bool = False,
    seeds: int = 3,
    family: str | None = None,
    jobs: int = 2,
    orca: bool = True,
    knobs: Knobs | None = None,
    engine: str = "local",
    address: str | None = None,
    realism: str = "ideal",
) -> None:
    """Print one JSON line per point of the families chosen (``family``; None: every one), in
    the world ``realism`` (``world.realism``'s preset; ORCA flies only the ideal one)."""
    todo = [p for p in points(quick, seeds) if family is None or p.family == family]
    fields = asdict(knobs or Knobs())
    with _Pool(engine, jobs, address) as pool:
        for p in todo:
            raws = [_with_filter(p.make(s), p.rho, **fields) | {"world": {"realism": realism}} for s in p.seeds]
            results = pool.map([(raw, orca and p.rho == 1.0 and realism == "ideal") for raw in raws])
            line = {"family": p.family, "scene": p.scene, "n": p.n, "rho": p.rho, "exact": p.exact}
            line |= _summary([c for c, _, _ in results])
            orca_runs = [o for _, o, _ in results if o is not None]
            line["orca"] = _summary(orca_runs) if orca_runs else None
            orca_paths = [o for _, _, o in results if o is not None]
            line["orca_path"] = _summary(orca_paths) if orca_paths else None
            line |= fields
            line["realism"] = realism
            print(json.dumps(line), flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="one seed, smaller swarms")
    ap.add_argument("--seeds", type=int, default=3, help="seeds per perturbed scene")
    ap.add_argument(
        "--family",
        choices=["sphere_field", "circle", "sphere", "formation", "pillar", "doorway", "corridor", "trap", "forest"],
    )
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--no-orca", action="store_true")
    ap.add_argument("--horizon-s", type=float, help="filter.horizon_s of every agent (default: none)")
    ap.add_argument("--buffer-mps", type=float, help="filter.buffer_mps of every agent (default: the config's)")
    ap.add_argument("--contact-s", type=float, help="filter.contact_s of every agent (default: the config's)")
    ap.add_argument("--no-free-braking", action="store_true", help="filter.free_braking false for every agent")
    ap.add_argument("--no-ellipsoid", action="store_true", help="filter.ellipsoid false for every agent")
    ap.add_argument("--gamma", type=float, help="filter.gamma of every agent (default: the config's)")
    ap.add_argument(
        "--sensing-radius-m", type=float, help="filter.sensing_radius_m of every agent (default: the config's)"
    )
    ap.add_argument(
        "--realism",
        choices=["ideal", "crazyflie_lab", "crazyflie_lab_bad_day"],
        default="ideal",
        help="world.realism of every scene (crazyflie_lab: no ORCA, which takes velocities, not commands)",
    )
    ap.add_argument("--engine", choices=["local", "ray"], default="local", help="ray: each scene a Ray task")
    ap.add_argument("--address", help="--engine ray: the Ray cluster's address (default: a local cluster)")
    a = ap.parse_args()
    main(
        a.quick,
        a.seeds,
        a.family,
        a.jobs,
        orca=not a.no_orca,
        knobs=Knobs(
            horizon_s=a.horizon_s,
            buffer_mps=a.buffer_mps,
            contact_s=a.contact_s,
            free_braking=False if a.no_free_braking else None,
            gamma=a.gamma,
            sensing_radius_m=a.sensing_radius_m,
            ellipsoid=False if a.no_ellipsoid else None,
        ),
        engine=a.engine,
        address=a.address,
        realism=a.realism,
    )
