"""Imperfections one at a time: how far can each go before the swarm touches?

Each point flies a scene in one process (``swarm.offline.closed_loop.simulate_swarm``, the same
control step, plant, motion capture and links as the world process) with ONE imperfection of
``world.realism`` raised from zero and everything else ideal, under C3BF and HO-CBF, and prints
one JSON line. The imperfections and their levels:

* ``latency`` [s]: motion-capture frames this late (each agent's estimator knows it and predicts
  forward), and every state, bundle and command this late too (0-100 ms);
* ``noise`` [m]: motion-capture position noise, one standard deviation per coordinate (0-10 mm;
  frames at 100 Hz, on time);
* ``gusts`` [m/s]: Dryden gusts' standard deviation (MIL-F-8785C lengths at 1 m; 0-3 m/s), with
  the rotor drag through which wind reaches a drone (on at every level, 0 included);
* ``mass`` [fraction]: every drone heavier than the filter's model by this much (0-30 %).

The scenes: ``circle_8`` (8 drones swapping across a 2 m circle, exact symmetry), ``sphere_8``
(8 drones swapping across a sphere of radius 1.5 m: they pass above one another) and
``circle_8p`` (the circle, starts and goals perturbed by up to 5 cm, seed 0). ORCA is left out: its
agents take velocities, not commands, so only the ideal world flies it (``tools.bench_liveness``).

    python -m tools.bench_imperfections                  # every axis (about 20 min on 2 cores)
    python -m tools.bench_imperfections --axis latency --jobs 2
    python -m tools.bench_imperfections --plot docs/experiments/imperfections.jsonl  # the PNG

Keys (stable): axis, level, unit, method, scene, n, success, collisions, margin_violations,
min_separation_m (closest centres of any pair, m), min_h, downwash_pairs, downwash_pair_ticks,
min_downwash_distance (pairs inside their keep-out ellipsoid, ``swarm.offline.metrics``), deadlocks, mean_time_ratio,
estimate_error_p95_m (null without sensing), commands_lost, states_lost.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarm.config import resolve
from swarm.geometry import min_pair_distance
from swarm.model import QuadModel
from swarm.offline.closed_loop import outcome, scenario_swarm, simulate_swarm
from swarm.offline.scenario import SwapSettings, circle_swap, sphere_swap

AXES: dict[str, tuple[str, tuple[float, ...]]] = {
    "latency": ("s", (0.0, 0.01, 0.025, 0.05, 0.075, 0.1)),
    "noise": ("m", (0.0, 0.001, 0.0025, 0.005, 0.0075, 0.01)),
    "gusts": ("m/s", (0.0, 0.5, 1.0, 2.0, 3.0)),
    "mass": ("fraction", (0.0, 0.1, 0.2, 0.3)),
}
METHODS = ("c3bf", "hocbf")
SCENES = ("circle_8", "sphere_8", "circle_8p")


def realism(axis: str, level: float) -> dict[str, Any]:
    """``world.realism`` with only ``axis`` at ``level`` (its unit in :data:`AXES`)."""
    if axis == "latency":
        link = {"delay_s": level}
        return {
            "sensing": {"enabled": True, "rate_hz": 100.0, "latency_s": level},
            "comms": {"state": link, "bundle": link, "command": link},
        }
    if axis == "noise":
        return {"sensing": {"enabled": True, "rate_hz": 100.0, "position_noise_m": level}}
    if axis == "gusts":  # (wind reaches a drone through its rotor drag, so drag acts at every level)
        return {"wind": {"gust_std_mps": level}, "aero": {"drag": True}}
    if axis == "mass":
        return {"motors": {"mass_offset_fraction": level}}
    raise ValueError(f"unknown axis {axis!r}")


def scene(name: str, method: str, axis: str, level: float) -> dict:
    """The raw config of ``name`` flown by ``method`` with one imperfection."""
    s = SwapSettings(realism="ideal", perturb_m=0.05 if name == "circle_8p" else 0.0, seed=0)
    raw = sphere_swap(8, 1.5, s) if name == "sphere_8" else circle_swap(8, 2.0, s)
    raw["world"] = {"realism": realism(axis, level)}
    raw["defaults"].setdefault("filter", {})["kind"] = method
    return raw


@dataclass(frozen=True)
class Point:
    axis: str
    level: float
    method: str
    scene: str


def points(axes: list[str]) -> Iterator[Point]:
    for axis in axes:
        for level in AXES[axis][1]:
            for method in METHODS:
                for name in SCENES:
                    yield Point(axis, level, method, name)


def fly(p: Point) -> dict[str, Any]:
    """One run of point ``p``: its JSON line."""
    cfg = resolve(scene(p.scene, p.method, p.axis, p.level))
    agents, obs = scenario_swarm(cfg)
    log = simulate_swarm(
        QuadModel(),
        agents,
        obs,
        cfg.duration_s,
        control_hz=cfg.time.control_hz,
        physics_hz=cfg.time.physics_hz,
        goal_tolerance_m=cfg.goal_tolerance_m,
        realism=cfg.world.realism,
        seed=cfg.seed,
    )
    o = outcome(cfg, log)
    sep = min(min_pair_distance(x) for x in log.x_b_w)
    err = log.estimate_error_m
    return {
        "axis": p.axis,
        "level": p.level,
        "unit": AXES[p.axis][0],
        "method": p.method,
        "scene": p.scene,
        "n": len(agents),
        "success": o.success,
        "collisions": o.collisions,
        "margin_violations": o.margin_violations,
        "min_separation_m": round(sep, 4),
        "min_h": o.min_h,
        "downwash_pairs": o.downwash_pairs,
        "downwash_pair_ticks": o.downwash_pair_ticks,
        "min_downwash_distance": o.min_downwash_distance,
        "deadlocks": o.deadlocked,
        "mean_time_ratio": round(float(np.mean(o.time_ratios)), 3) if o.time_ratios else None,
        "estimate_error_p95_m": None if err is None else round(float(np.percentile(err, 95)), 5),
        "commands_lost": log.commands_lost,
        "states_lost": log.states_lost,
    }


def plot(lines: list[dict[str, Any]], out: Path) -> None:
    """One panel per axis: the closest centres of any pair [m] against the level, a line per
    method and scene; contacts marked with a cross, the airframes' contact distance dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes_seen = [a for a in AXES if any(r["axis"] == a for r in lines)]
    fig, panels = plt.subplots(1, len(axes_seen), figsize=(4.2 * len(axes_seen), 3.8), squeeze=False)
    contact_m = 2 * QuadModel().params.body_radius_m
    colours = {"c3bf": "tab:blue", "hocbf": "tab:orange"}
    styles = {"circle_8": "-", "sphere_8": "--", "circle_8p": ":"}
    scale = {"s": 1000.0, "m": 1000.0, "m/s": 1.0, "fraction": 100.0}
    label = {"s": "ms", "m": "mm", "m/s": "m/s", "fraction": "%"}
    for ax, axis in zip(panels[0], axes_seen, strict=True):
        unit = AXES[axis][0]
        for method in METHODS:
            for name in SCENES:
                rows = sorted((r for r in lines if (r["axis"], r["method"], r["scene"]) == (axis, method, name)),
                              key=lambda r: r["level"])  # fmt: skip
                if not rows:
                    continue
                x = [r["level"] * scale[unit] for r in rows]
                y = [r["min_separation_m"] for r in rows]
                ax.plot(x, y, styles[name], color=colours[method], marker="o", ms=3, label=f"{method} {name}")
                hit = [(xi, yi) for xi, yi, r in zip(x, y, rows, strict=True) if r["collisions"]]
                if hit:
                    ax.plot(*zip(*hit, strict=True), "x", color="red", ms=9, mew=2)
        ax.axhline(contact_m, color="k", lw=0.8, ls="--")
        ax.set_xlabel(f"{axis} [{label[unit]}]")
        ax.set_ylabel("closest centres [m]")
        ax.set_title(axis)
        ax.grid(alpha=0.3)
    panels[0][0].legend(fontsize=7)
    fig.suptitle("One imperfection at a time (red x: contact; dashed: airframes touch)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)


def main(axes: list[str], jobs: int) -> None:
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for line in pool.map(fly, list(points(axes))):
            print(json.dumps(line), flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--axis", choices=sorted(AXES), action="append", help="default: every axis")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--plot", type=Path, help="draw this JSON-lines file's points to a PNG beside it, and stop")
    args = ap.parse_args()
    if args.plot:
        plot([json.loads(s) for s in args.plot.read_text().splitlines() if s.strip()], args.plot.with_suffix(".png"))
    else:
        main(args.axis or list(AXES), args.jobs)
