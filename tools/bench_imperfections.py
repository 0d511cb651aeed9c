"""Imperfections one at a time: how far can each go before the swarm touches?

Each point flies a scene in one process (``swarm.offline.closed_loop.fly_scenario``, the same
control step, plant, motion capture, links and safety monitor as the world and agent processes)
with ONE imperfection of ``world.realism`` raised from zero and everything else ideal, under
C3BF and HO-CBF, and prints one JSON line. The imperfections and their levels:

* ``latency`` [s]: motion-capture frames this late (each agent's estimator knows it and predicts
  forward), and every state, bundle and command this late too (0-200 ms); on this axis C3BF also
  flies without its delay contract (method ``c3bf_fixed``: ``filter.delay_growth_m`` null, the
  airframe's whole acceleration in its neighbours' rows, docs/design.md "Delay");
* ``noise`` [m]: motion-capture position noise, one standard deviation per coordinate (0-10 mm;
  frames at 100 Hz, on time);
* ``gusts`` [m/s]: Dryden gusts' standard deviation (MIL-F-8785C lengths at 1 m; 0-3 m/s), with
  the rotor drag through which wind reaches a drone (on at every level, 0 included);
* ``mass`` [fraction]: every drone heavier than the filter's model by this much (0-30 %).

The failures of a lab's bad day (``crazyflie_lab_bad_day``), one at a time, each flown with the
lab's motion capture on (``crazyflie_lab``'s sensing block: 100 Hz, 1 mm, 10 ms, 10 % of frames
dropped, its estimator, and the innovation gate at 5 sigmas) and everything else ideal:

* ``occlusion`` [s]: the mean length of a burst in which a drone is lost to the motion capture,
  bursts beginning at 0.5 per second a drone is seen (each drone is hit several times in a run;
  0-2 s; the monitor lands a drone unseen for 1 s);
* ``swap`` [s]: how long two drones' identities stay swapped, swaps at 0.5 per second of the run
  (0-1 s);
* ``radio`` [drones]: drones sharing one Crazyradio (Crazyswarm2's C++ backend; 1-16), on the bad
  day's command link at every level (10 ms, 10 % of commands lost, in bursts: a burst begins on
  2 % of commands, ends on 20 %, loses half);
* ``battery`` [fraction/min]: the thrust lost per MINUTE of flight (0-0.1), each drone's battery
  having flown a seeded 0-3 min at takeoff: a run lasts 15-20 s, so most of the sag is the
  starting spread (up to 3 x the level), not the run's;
* ``turbulence`` [m/s]: each drone's own gust (``relative_gust_std_mps``, correlation length
  0.3 m; 0-2 m/s), with the rotor drag and the body's drag (C_d A 1.3e-3 m^2) at every level.

The first level of each of these is the lab's motion capture alone (``radio``: with the command
link, ``turbulence``: with the drag), so each line's difference from it is the one failure.

* ``jitter`` [s]: on top of 50 ms on the motion capture and every link, each state, bundle and
  command up to this much later again (uniform: a late message is used at its true age, and may
  arrive after a newer one), and losses in bursts on every link (a burst begins on 2 % of
  messages, ends on 20 %, loses half; 0-100 ms).

The scenes: ``circle_8`` (8 drones swapping across a 2 m circle, exact symmetry), ``sphere_8``
(8 drones swapping across a sphere of radius 1.5 m: they pass above one another) and
``circle_8p`` (the circle, starts and goals perturbed by up to 5 cm, seed 0); on the delay axes
(``latency``, ``jitter``) also ``circle_16`` (16 drones across a 3 m circle, exact symmetry).

ORCA (``swarm.offline.orca``, method ``orca``) flies each axis's first level only, in the ideal
world (``ideal_world: true``): the reference row; on the delay axes every level, with the same
delays on what it sees and on the velocities it chooses (``run_orca``'s ``seen_delay_ticks``:
the state's and the bundle's links, ``command_delay_ticks``: the command link; no jitter or
loss). Its agents are RVO2's holonomic discs that take velocities from perfect positions, so no
other axis applies to it as it does to the filters: no motion capture or estimator to occlude,
swap or make noisy (``noise``, ``occlusion``, ``swap``), no thrust, mass, battery or drag for a
gust or a sag to act through (``mass``, ``battery``, ``gusts``, ``turbulence``). ``--no-orca``
leaves it out.

    python -m tools.bench_imperfections                  # every axis (about an hour on 2 cores)
    python -m tools.bench_imperfections --axis latency --jobs 2
    python -m tools.bench_imperfections --plot docs/experiments/imperfections.jsonl  # the PNG

Keys (stable): axis, level, unit, method, scene, n, ideal_world (the point's world.realism is
the ideal world), success, collisions, margin_violations, min_separation_m (closest centres of
any pair, m), min_h, downwash_pairs, downwash_pair_ticks, min_downwash_distance (pairs inside
their keep-out ellipsoid, ``swarm.offline.metrics``), deadlocks, mean_time_ratio,
estimate_error_p95_m and estimate_error_max_m (|estimate - true centre of mass| over agent
ticks; null without sensing), commands_lost, states_lost, monitor_ticks ({slow, hold, land}:
agent ticks the safety monitor took each action), landed_by_monitor (agents it landed),
unguarded_ticks (agent ticks an estimate's error exceeded its live bound with the monitor not
acting); the monitor's keys are null for ORCA.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import tempfile
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarm.config import resolve
from swarm.geometry import min_pair_distance
from swarm.model import QuadModel
from swarm.offline.closed_loop import fly_scenario, outcome
from swarm.offline.scenario import SwapSettings, circle_swap, sphere_swap
from swarm.realism.settings import PRESETS, RealismSettings
from swarm.safety.monitor import Action
from swarm.strict import merge

AXES: dict[str, tuple[str, tuple[float, ...]]] = {
    "latency": ("s", (0.0, 0.01, 0.025, 0.05, 0.075, 0.1, 0.15, 0.2)),
    "noise": ("m", (0.0, 0.001, 0.0025, 0.005, 0.0075, 0.01)),
    "gusts": ("m/s", (0.0, 0.5, 1.0, 2.0, 3.0)),
    "mass": ("fraction", (0.0, 0.1, 0.2, 0.3)),
    # the bad day's failures, one at a time, each with the lab's motion capture (the module docstring)
    "occlusion": ("s", (0.0, 0.1, 0.25, 0.5, 1.0, 2.0)),
    "swap": ("s", (0.0, 0.1, 0.25, 0.5, 1.0)),
    "radio": ("drones", (1, 2, 4, 8, 16)),
    # per MINUTE of flight, and a run lasts 15-20 s: the batteries' 0-3 min at takeoff make it bite
    "battery": ("fraction/min", (0.0, 0.01, 0.02, 0.05, 0.1)),
    "turbulence": ("m/s", (0.0, 0.25, 0.5, 1.0, 2.0)),
    # on top of 50 ms on every link and the motion capture, with losses in bursts (the module docstring)
    "jitter": ("s", (0.0, 0.025, 0.05, 0.1)),
}
DELAY_AXES = ("latency", "jitter")  # C3BF without its contract, circle_16 and ORCA at every level on these
JITTER_BASE_S = 0.05
BURSTS = {"burst_enter_probability": 0.02, "burst_exit_probability": 0.2, "burst_loss_fraction": 0.5}
METHODS = ("c3bf", "hocbf")
FIXED = "c3bf_fixed"  # C3BF without the delay contract (filter.delay_growth_m null): the latency axis only
ORCA = "orca"  # flies each axis's first level only, in the ideal world (the module docstring)
SCENES = ("circle_8", "sphere_8", "circle_8p")
DELAY_SCENES = (*SCENES, "circle_16")


def realism(axis: str, level: float) -> dict[str, Any]:
    """``world.realism`` with only ``axis`` at ``level`` (its unit in :data:`AXES`)."""
    if axis == "latency":
        link = {"delay_s": level}
        return {
            "sensing": {"enabled": True, "rate_hz": 100.0, "latency_s": level},
            "comms": {"state": link, "bundle": link, "command": link},
        }
    if axis == "jitter":
        link = {"delay_s": JITTER_BASE_S, "jitter_s": level, **BURSTS}
        return {
            "sensing": {"enabled": True, "rate_hz": 100.0, "latency_s": JITTER_BASE_S},
            "comms": {"state": link, "bundle": link, "command": link},
        }
    if axis == "noise":
        return {"sensing": {"enabled": True, "rate_hz": 100.0, "position_noise_m": level}}
    if axis == "gusts":  # (wind reaches a drone through its rotor drag, so drag acts at every level)
        return {"wind": {"gust_std_mps": level}, "aero": {"drag": True}}
    if axis == "mass":
        return {"motors": {"mass_offset_fraction": level}}
    if axis == "occlusion":  # bursts at 0.5 per second a drone is seen, of this mean length
        return {
            "sensing": lab_sensing({"occlusion_rate_hz": OCCLUSION_RATE_HZ, "occlusion_mean_s": level} if level else {})
        }
    if axis == "swap":  # swaps at 0.5 per second of the run, each this long
        return {"sensing": lab_sensing({"swap_rate_hz": SWAP_RATE_HZ, "swap_duration_s": level} if level else {})}
    if axis == "radio":  # the bad day's command link at every level; the radio's drones raised
        return {
            "sensing": lab_sensing(),
            "comms": {
                "command": dict(BAD_DAY_COMMAND),
                "shared_radio": {"drones_per_radio": int(level), "backend": "cpp"},
            },
        }
    if axis == "battery":  # the level is per minute; a run lasts 15-20 s, batteries 0-3 min flown at takeoff
        motors = {"battery_sag_fraction_per_min": level, "battery_start_spread_min": BATTERY_START_SPREAD_MIN}
        return {"sensing": lab_sensing(), **({"motors": motors} if level else {})}
    if axis == "turbulence":  # each drone's own gust, through the rotors' and the body's drag (at every level)
        wind = {"relative_gust_std_mps": level, "body_drag_area_m2": BODY_DRAG_AREA_M2}
        return {"sensing": lab_sensing(), "wind": wind, "aero": {"drag": True}}
    raise ValueError(f"unknown axis {axis!r}")


OCCLUSION_RATE_HZ = 0.5  # bursts per second a drone is seen: several per drone in a run
SWAP_RATE_HZ = 0.5  # swaps per second of the run (not per drone)
BATTERY_START_SPREAD_MIN = 3.0  # as crazyflie_lab_bad_day
BODY_DRAG_AREA_M2 = 1.3e-3  # as crazyflie_lab_bad_day
# crazyflie_lab_bad_day's command link (the lab's 10 ms and 10 %, in bursts), one drone on the radio
BAD_DAY_COMMAND: dict[str, float] = dict(PRESETS["crazyflie_lab_bad_day"]["comms"]["command"])


def lab_sensing(over: dict[str, Any] | None = None) -> dict[str, Any]:
    """``crazyflie_lab``'s sensing block (motion capture on, its estimator) with the innovation
    gate at 5 sigmas, as ``crazyflie_lab_bad_day`` has it, and ``over`` on top."""
    base = merge(copy.deepcopy(PRESETS["crazyflie_lab"]["sensing"]), {"estimator": {"gate_sigmas": 5.0}})
    return merge(base, over or {})


def _base(name: str, duration_s: float | None = None) -> dict:
    """The raw config of scene ``name`` in the ideal world (``duration_s``: shorter, for tests)."""
    s = SwapSettings(realism="ideal", perturb_m=0.05 if name == "circle_8p" else 0.0, seed=0, duration_s=duration_s)
    if name == "circle_16":
        return circle_swap(16, 3.0, s)
    return sphere_swap(8, 1.5, s) if name == "sphere_8" else circle_swap(8, 2.0, s)


def scene(name: str, method: str, axis: str, level: float, duration_s: float | None = None) -> dict:
    """The raw config of ``name`` flown by ``method`` with one imperfection."""
    raw = _base(name, duration_s)
    raw["world"] = {"realism": realism(axis, level)}
    f = raw["defaults"].setdefault("filter", {})
    f["kind"] = "c3bf" if method == FIXED else method
    if method == FIXED:
        f["delay_growth_m"] = None
    return raw


@dataclass(frozen=True)
class Point:
    axis: str
    level: float
    method: str
    scene: str
    duration_s: float | None = None  # None: the scene's


def points(axes: list[str], orca: bool = True) -> Iterator[Point]:
    for axis in axes:
        levels = AXES[axis][1]
        delays = axis in DELAY_AXES
        scenes = DELAY_SCENES if delays else SCENES
        for level in levels:
            for method in (*METHODS, FIXED) if delays else METHODS:
                for name in scenes:
                    yield Point(axis, level, method, name)
            if orca and (delays or level == levels[0]):
                for name in scenes:
                    yield Point(axis, level, ORCA, name)


def fly(p: Point) -> dict[str, Any]:
    """One run of point ``p``: its JSON line."""
    if p.method == ORCA:
        return _fly_orca(p)
    raw = scene(p.scene, p.method, p.axis, p.level, p.duration_s)
    cfg = resolve(raw)
    log = fly_scenario(cfg)
    o = outcome(cfg, log)
    sep = min(min_pair_distance(x) for x in log.x_b_w)
    err = log.estimate_error_m
    return {
        **_key(p, len(cfg.agents), RealismSettings.model_validate(raw["world"]["realism"]).ideal),
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
        "estimate_error_max_m": None if err is None else round(float(err.max()), 5),
        "monitor_ticks": {a.name.lower(): log.action_ticks(a) for a in (Action.SLOW, Action.HOLD, Action.LAND)},
        "landed_by_monitor": sum(log.landed_by_monitor),
        "unguarded_ticks": log.unguarded_ticks,
    }


def _key(p: Point, n: int, ideal: bool) -> dict[str, Any]:
    return {
        "axis": p.axis,
        "level": p.level,
        "unit": AXES[p.axis][0],
        "method": p.method,
        "scene": p.scene,
        "n": n,
        "ideal_world": ideal,
    }


def _fly_orca(p: Point) -> dict[str, Any]:
    """ORCA on point ``p``'s scene: in the ideal world (a level that is its axis's first), or on a
    delay axis with the point's delays on what it sees and on its velocities: the line."""
    from swarm.offline.orca import run_orca

    cfg = resolve(_base(p.scene, p.duration_s))
    seen = command = 0
    if p.axis in DELAY_AXES:
        comms = RealismSettings.model_validate(realism(p.axis, p.level)).comms.params()
        tick = 1.0 / cfg.time.control_hz
        seen = round((comms.state.delay_s + comms.bundle.delay_s) / tick)
        command = round(comms.command.delay_s / tick)
    with tempfile.TemporaryDirectory() as tmp:
        m = run_orca(cfg, Path(tmp), seen_delay_ticks=seen, command_delay_ticks=command)
    agents = list(m["agents"].values())
    ratios = [
        a["time_to_goal_s"] / (a["straight_line_m"] / cfg.agents[i].speed_mps)
        for i, a in enumerate(agents)
        if a["time_to_goal_s"] is not None
    ]
    sep = m["min_separation_m"]
    return {
        **_key(p, len(agents), seen == command == 0),
        "success": bool(m["all_reached_goal"]) and m["collisions"] == 0,
        "collisions": m["collisions"],
        "margin_violations": m["margin_violations"],
        "min_separation_m": None if sep is None else round(sep, 4),
        "min_h": m["min_h"],
        "downwash_pairs": m["downwash_pairs"],
        "downwash_pair_ticks": m["downwash_pair_ticks"],
        "min_downwash_distance": m["min_downwash_distance"],
        "deadlocks": len(m["deadlocked_agents"]),
        "mean_time_ratio": round(float(np.mean(ratios)), 3) if ratios else None,
        "estimate_error_p95_m": None,
        "commands_lost": 0,
        "states_lost": 0,
        "estimate_error_max_m": None,
        "monitor_ticks": None,
        "landed_by_monitor": None,
        "unguarded_ticks": None,
    }


def plot(lines: list[dict[str, Any]], out: Path) -> None:
    """One panel per axis: the closest centres of any pair [m] against the level, a line per
    method and scene; contacts marked with a cross, the airframes' contact distance dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes_seen = [a for a in AXES if any(r["axis"] == a for r in lines)]
    cols = min(len(axes_seen), 5)
    rows_n = -(-len(axes_seen) // cols)
    fig, grid = plt.subplots(rows_n, cols, figsize=(4.2 * cols, 3.8 * rows_n), squeeze=False)
    panels = grid.ravel()
    for spare in panels[len(axes_seen) :]:
        spare.set_visible(False)
    contact_m = 2 * QuadModel().params.body_radius_m
    colours = {"c3bf": "tab:blue", "hocbf": "tab:orange", ORCA: "tab:green", FIXED: "tab:purple"}
    styles = {"circle_8": "-", "sphere_8": "--", "circle_8p": ":", "circle_16": "-."}
    scale = {"s": 1000.0, "m": 1000.0, "m/s": 1.0, "fraction": 100.0, "drones": 1.0, "fraction/min": 100.0}
    label = {"s": "ms", "m": "mm", "m/s": "m/s", "fraction": "%", "drones": "drones", "fraction/min": "%/min"}
    for ax, axis in zip(panels, axes_seen, strict=False):
        unit = AXES[axis][0]
        for method in (*METHODS, FIXED, ORCA):
            for name in DELAY_SCENES:
                rows = sorted((r for r in lines if (r["axis"], r["method"], r["scene"]) == (axis, method, name)),
                              key=lambda r: r["level"])  # fmt: skip
                if not rows:
                    continue
                x = [r["level"] * scale[unit] for r in rows]
                y = [math.nan if r["min_separation_m"] is None else r["min_separation_m"] for r in rows]
                ax.plot(x, y, styles[name], color=colours[method], marker="o", ms=3, label=f"{method} {name}")
                hit = [(xi, yi) for xi, yi, r in zip(x, y, rows, strict=True) if r["collisions"]]
                if hit:
                    ax.plot(*zip(*hit, strict=True), "x", color="red", ms=9, mew=2)
        ax.axhline(contact_m, color="k", lw=0.8, ls="--")
        ax.set_xlabel(f"{axis} [{label[unit]}]")
        ax.set_ylabel("closest centres [m]")
        ax.set_title(axis)
        ax.grid(alpha=0.3)
    handles, names = panels[0].get_legend_handles_labels()
    fig.legend(handles, names, fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.suptitle(
        "One imperfection at a time\n(red x: contact; dashed black: airframes touch;"
        " ORCA: the ideal world, but as late on latency and jitter)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out, dpi=110, bbox_inches="tight")


def main(axes: list[str], jobs: int, orca: bool = True) -> None:
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for line in pool.map(fly, list(points(axes, orca))):
            print(json.dumps(line), flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--axis", choices=sorted(AXES), action="append", help="default: every axis")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--no-orca", action="store_true", help="leave out ORCA's ideal-world reference rows")
    ap.add_argument("--plot", type=Path, help="draw this JSON-lines file's points to a PNG beside it, and stop")
    args = ap.parse_args()
    if args.plot:
        plot([json.loads(s) for s in args.plot.read_text().splitlines() if s.strip()], args.plot.with_suffix(".png"))
    else:
        main(args.axis or list(AXES), args.jobs, not args.no_orca)
