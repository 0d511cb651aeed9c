"""``swarm sweep``: a grid of variants of one scenario, run in parallel, in one table.

Each grid point is the base scenario with some *knobs* turned (``--axis NAME=v1,v2``).
Every point is validated before anything starts, then run as a whole multi-process
swarm (lockstep, so the numbers do not depend on the machine's load), ``--jobs`` runs
at a time. The output folder gets one run folder per point, ``results.csv`` (one row
per run: the point's knobs and its metrics) and one PNG per metric, plotted against the
first numeric axis with one line per combination of the other axes (seeds averaged).

Knobs (the config's names; units in brackets):

* ``filter``: every agent's safety filter: ``c3bf``, ``hocbf``, an installed plugin's name
  (``swarm.plugins``, docs/plugins.md) or ``none`` (unfiltered), or ``orca``: the ORCA baseline
  (``swarm/offline/orca.py``) instead of the swarm.
* ``gamma`` [1/s], ``gamma_ho`` [m/s] (the HO-CBF gain), ``rho`` (responsibility share),
  ``sensing_radius_m`` [m] (neighbours farther away get no row), ``horizon_s`` [s] (the live
  rows' horizon allowance, ``swarm.safety.barriers``; ``none``: the cone alone), ``buffer_mps``
  [m/s] (the live rows' velocity buffer, ``swarm.safety.constraints``) and ``contact_s`` [s] (the live
  neighbour rows' contact horizon, ``swarm.safety.barriers``; 0: the cone alone).
* ``tiebreak``: ``none`` or ``right_hand`` (``swarm.control.right_hand_bias``).
* ``obstacle_speed`` [m/s] and ``approach_angle_deg`` [deg]: the first obstacle is
  re-aimed so that it passes its configured centre when the first agent, flying its
  first path leg at its target speed, gets there. Angle 0 is head-on, 90 crosses from
  the agent's left, 180 comes from behind. Speed 0 makes it static.
* ``seed``: the scenario seed.
* For generated swaps (base ``circle``, ``sphere`` or ``random`` instead of a file):
  ``agents``, ``radius`` [m], ``perturb_m`` [m] and ``density`` [1/m^2] (``swarm.offline.scenario``).
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from collections import defaultdict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from swarm.config import ConfigError, ScenarioConfig, resolve
from swarm.model import QuadParams
from swarm.offline.scenario import SwapSettings, circle_swap, default_radius, random_swap, sphere_swap
from swarm.runs import ray_engine
from swarm.runs.launch import unpinned
from swarm.runs.point import ROW_FILE, Job, fly_reporting

Raw = dict[str, Any]
Knob = Callable[[Raw, str], Raw]


def _float(name: str, value: str) -> float:
    try:
        x = float(value)
    except ValueError:
        raise ConfigError(f"--axis {name}: {value!r} is not a number") from None
    if not math.isfinite(x):
        raise ConfigError(f"--axis {name}: {value!r} is not finite")
    return x


def _float_or_none(name: str, value: str) -> float | None:
    return None if value == "none" else _float(name, value)


def _each_filter(field: str, convert: Callable[[str, str], Any]) -> Knob:
    def knob(raw: Raw, value: str) -> Raw:
        v = convert(field, value)
        for a in raw["agents"]:
            a.setdefault("filter", {})[field] = v
        return raw

    return knob


def _filter_kind(raw: Raw, value: str) -> Raw:
    from swarm.plugins import UNFILTERED, names

    known = [*names(), UNFILTERED, "orca"]
    if value not in known:
        raise ConfigError(f"--axis filter: {value!r} is not one of {', '.join(known)}")
    if value == "orca":
        raw["_method"] = "orca"
        return raw
    layers = [raw.get("defaults") or {}, *(raw.get("agent_types") or {}).values(), *raw["agents"]]
    kinds = {(layer.get("filter") or {}).get("kind") for layer in layers} - {None}
    if value != UNFILTERED and kinds - {value}:  # another filter's options are not this one's
        for layer in layers:
            (layer.get("filter") or {}).pop("options", None)
    for a in raw["agents"]:
        f = a.setdefault("filter", {})
        f["enabled"] = value != UNFILTERED
        if value != UNFILTERED:
            f["kind"] = value
    return raw


def _aim(key: str) -> Knob:
    def knob(raw: Raw, value: str) -> Raw:
        raw.setdefault("_aim", {})[key] = _float(key, value)
        return raw

    return knob


def aim_first_obstacle(raw: Raw, speed_mps: float | None = None, angle_deg: float = 0.0) -> Raw:
    """Re-aim obstacle 0 at its configured centre (the meeting point), see the module doc.
    ``speed_mps`` None keeps the configured speed."""
    if not raw.get("obstacles"):
        raise ConfigError("--axis obstacle_speed/approach_angle_deg: the scenario has no obstacle")
    obs, agent = raw["obstacles"][0], raw["agents"][0]
    meet = np.asarray(obs["center"], dtype=float)
    start = np.asarray(agent["start"], dtype=float)
    first = np.asarray((agent.get("waypoints") or [agent.get("goal") or agent["start"]])[0], dtype=float)
    heading = first - start
    heading[2] = 0.0
    if np.linalg.norm(heading) < 1e-9:
        raise ConfigError("--axis obstacle_speed/approach_angle_deg: the first agent has no horizontal first leg")
    heading /= np.linalg.norm(heading)
    t_meet = float(np.linalg.norm(meet - start)) / float(agent.get("speed_mps", 1.0))
    if speed_mps is None:
        speed_mps = float(np.linalg.norm(obs.get("velocity", [0.0, 0.0, 0.0])))
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    towards = -np.array([c * heading[0] - s * heading[1], s * heading[0] + c * heading[1], 0.0])
    v = speed_mps * towards
    c0 = meet - t_meet * v
    if np.linalg.norm(c0 - start) < float(obs.get("radius_m", 0.0)) + 0.3:
        raise ConfigError(
            f"--axis obstacle_speed/approach_angle_deg: at {speed_mps} m/s from {angle_deg} deg the obstacle "
            "would start on the agent (it keeps pace from behind); drop this point"
        )
    obs["velocity"] = v.round(9).tolist()
    obs["center"] = c0.round(9).tolist()
    return raw


def _tiebreak(raw: Raw, value: str) -> Raw:
    if value not in ("none", "right_hand"):
        raise ConfigError(f"--axis tiebreak: {value!r} is not one of none, right_hand")
    for a in raw["agents"]:
        a.setdefault("tiebreak", {})["kind"] = value
    return raw


KNOBS: dict[str, Knob] = {
    "filter": _filter_kind,
    "gamma": _each_filter("gamma", _float),
    "gamma_ho": _each_filter("gamma_ho", _float),
    "rho": _each_filter("rho", _float),
    "sensing_radius_m": _each_filter("sensing_radius_m", _float),
    "horizon_s": _each_filter("horizon_s", _float_or_none),
    "buffer_mps": _each_filter("buffer_mps", _float),
    "contact_s": _each_filter("contact_s", _float),
    "obstacle_speed": _aim("speed_mps"),
    "approach_angle_deg": _aim("angle_deg"),
    "seed": lambda raw, v: {**raw, "seed": int(_float("seed", v))},
    "tiebreak": _tiebreak,
    # generated scenarios only (base circle, sphere or random): see GENERATORS
    "agents": lambda raw, v: raw,
    "radius": lambda raw, v: raw,
    "perturb_m": lambda raw, v: raw,
    "density": lambda raw, v: raw,
}
GENERATED_ONLY = ("agents", "radius", "perturb_m", "density")
GENERATORS = ("circle", "sphere", "random")


def generator_base(kind: str, **options: Any) -> Raw:
    """The base of a sweep over generated scenarios: ``kind`` circle, sphere or random,
    with ``agents``, ``radius`` [m] (default grows with N), ``perturb_m``, ``density``
    [1/m^2] and ``seed`` as defaults for the knobs of the same names."""
    if kind not in GENERATORS:
        raise ConfigError(f"scenario kind {kind!r}: choose one of {', '.join(GENERATORS)}")
    return {
        "_generate": {
            "kind": kind,
            "agents": 4,
            "radius": None,
            "perturb_m": 0.0,
            "density": 0.5,
            "seed": 0,
            **{k: v for k, v in options.items() if v is not None},
        }
    }


def generate(gen: dict[str, Any]) -> Raw:
    """A generated scenario (raw) from a ``_generate`` spec."""
    n = int(_float("agents", str(gen["agents"])))
    if n < 1:
        raise ConfigError(f"--axis agents: {n} agents")
    settings = SwapSettings(perturb_m=_float("perturb_m", str(gen["perturb_m"])), seed=int(gen["seed"]))
    radius = _float("radius", str(gen["radius"])) if gen["radius"] is not None else default_radius(gen["kind"], n)
    if gen["kind"] == "circle":
        return circle_swap(n, radius, settings)
    if gen["kind"] == "sphere":
        return sphere_swap(n, radius, settings)
    try:
        return random_swap(n, _float("density", str(gen["density"])), settings)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def parse_axes(specs: list[str], known: dict[str, Knob] | None = None) -> dict[str, list[str]]:
    """``["gamma=0.5,1", ...]`` to ``{"gamma": ["0.5", "1"]}``, checked against the knobs."""
    known = KNOBS if known is None else known
    axes: dict[str, list[str]] = {}
    for spec in specs:
        name, sep, values = spec.partition("=")
        name = name.strip()
        if not sep or not values.strip():
            raise ConfigError(f"--axis {spec!r}: expected NAME=v1,v2,...")
        if name not in known:
            raise ConfigError(f"--axis {name}: unknown knob (have {', '.join(sorted(known))})")
        if name in axes:
            raise ConfigError(f"--axis {name}: given twice")
        axes[name] = [v.strip() for v in values.split(",") if v.strip()]
    return axes


def grid(axes: dict[str, list[str]]) -> list[dict[str, str]]:
    names = list(axes)
    return [dict(zip(names, combo, strict=True)) for combo in itertools.product(*(axes[n] for n in names))]


def point_name(i: int, point: dict[str, str]) -> str:
    return f"p{i:03d}_" + "_".join(f"{k}-{v}" for k, v in point.items()) if point else f"p{i:03d}"


def build(base: Raw, point: dict[str, str], knobs: dict[str, Knob] | None = None) -> tuple[ScenarioConfig, str]:
    """The base scenario (raw) with the point's knobs turned, validated, and the method
    that flies it: ``swarm`` (the multi-process runtime) or ``orca``."""
    knobs = KNOBS if knobs is None else knobs
    raw = json.loads(json.dumps(base))  # a deep copy
    gen = raw.pop("_generate", None)
    if gen is not None:
        gen.update({k: v for k, v in point.items() if k in (*GENERATED_ONLY, "seed")})
        raw = generate(gen)
    else:
        given = [k for k in point if k in GENERATED_ONLY]
        if given:
            raise ConfigError(f"--axis {given[0]}: only for generated scenarios (circle, sphere, random)")
    for name, value in point.items():  # each knob edits its own fields: order does not matter
        raw = knobs[name](raw, value)
    aim = raw.pop("_aim", None)
    if aim:
        aim_first_obstacle(raw, **aim)
    method = raw.pop("_method", "swarm")
    return resolve(raw, f"sweep point {point}"), method


def sweep(
    base: Raw,
    axes: dict[str, list[str]],
    out: Path,
    *,
    jobs: int = 1,
    knobs: dict[str, Knob] | None = None,
    on_done: Callable[[dict[str, Any]], None] | None = None,
    on_start: Callable[[dict[str, Any]], None] | None = None,
    engine: str = "local",
    address: str | None = None,
    resume: bool = False,
) -> list[dict[str, Any]]:
    """Run every grid point; write ``results.csv`` and the plots; return the rows.

    ``engine``: ``local`` (``jobs`` runs at a time on this machine) or ``ray`` (each run a
    Ray task, on the cluster at ``address`` or a local one: :mod:`swarm.runs.ray_engine`).
    Each point's row is written to its folder (``row.json``) and ``results.csv`` is
    rewritten as each run finishes, so an interrupted sweep keeps what it finished; with
    ``resume`` the points that have a row are not run again. ``on_start`` hears each point's
    first columns as its run starts, ``on_done`` its row as it ends (progress)."""
    if engine not in ("local", "ray"):
        raise ConfigError(f"--engine: {engine!r} is not local or ray")
    points = grid(axes)
    out = out.resolve()  # (a Ray worker runs in a folder of its own)
    built = [build(base, p, knobs) for p in points]  # every point validated before any run
    if jobs > 1 or engine == "ray":  # runs side by side: no two worlds pinned to one CPU
        built = [(unpinned(cfg), method) for cfg, method in built]
    out.mkdir(parents=True, exist_ok=True)
    rows: dict[int, dict[str, Any]] = {}
    todo: list[Job] = []
    for i, (point, (cfg, method)) in enumerate(zip(points, built, strict=True)):
        folder = out / point_name(i, point)
        if resume and (folder / ROW_FILE).exists():
            rows[i] = json.loads((folder / ROW_FILE).read_text())
            continue
        todo.append(Job(i, {"run": folder.name, **point}, cfg, method, folder))

    def finished(job: Job, row: dict[str, Any]) -> None:
        job.folder.mkdir(parents=True, exist_ok=True)
        (job.folder / ROW_FILE).write_text(json.dumps(row, indent=2))
        rows[job.index] = row
        write_csv([rows[i] for i in sorted(rows)], out / "results.csv")
        if on_done:
            on_done(row)

    if engine == "ray":
        ray_engine.run(todo, finished, address=address, started=on_start)
    else:
        with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
            futures = {pool.submit(fly_reporting, job, on_start): job for job in todo}
            for f in as_completed(futures):
                finished(futures[f], f.result())
    ordered = [rows[i] for i in sorted(rows)]
    write_csv(ordered, out / "results.csv")
    plot([r for r in ordered if not r.get("error")], list(axes), out)
    return ordered


def finished_rows(out: Path) -> int:
    """How many points of the sweep in ``out`` have a row already (what ``--resume`` keeps)."""
    return sum(1 for _ in out.glob(f"*/{ROW_FILE}")) if out.is_dir() else 0


def write_csv(rows: list[dict[str, Any]], path: Path) -> None:
    fields: list[str] = []
    for r in rows:
        fields += [k for k in r if k not in fields]
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)


PLOTTED = {
    "success": "success rate",
    "mean_time_to_goal_s": "mean time to goal [s] (successful runs)",
    "max_path_deviation_m": "largest path deviation [m]",
    "path_length_ratio": "path length / straight line",
    "min_clearance_m": "closest approach to an obstacle surface [m]",
    "min_separation_m": "closest approach between agents [m]",
    "infeasible_ticks": "infeasible ticks",
    "deadlock": "deadlock rate",
    "solve_us_mean": "filter (or ORCA step) time per agent per tick [us]",
}


UNITS = {
    "obstacle_speed": "m/s",
    "approach_angle_deg": "deg",
    "gamma": "1/s",
    "gamma_ho": "m/s",
    "radius": "m",
    "horizon_s": "s",
    "buffer_mps": "m/s",
    "contact_s": "s",
}


def _numeric(values: list[str]) -> bool:
    try:
        [float(v) for v in values]
    except ValueError:
        return False
    return True


def aggregate(rows: list[dict[str, Any]], axes: list[str]) -> tuple[str | None, dict[tuple, dict[float, dict]]]:
    """Group rows by the non-x, non-seed axes; average each metric over seeds per x."""
    xs = [a for a in axes if a != "seed" and _numeric([str(r[a]) for r in rows])]
    varied = [a for a in xs if len({str(r[a]) for r in rows}) > 1]
    x_axis = next(iter(varied or xs), None)  # the first numeric axis that varies
    group_axes = [a for a in axes if a not in (x_axis, "seed")]
    groups: dict[tuple, dict[float, list[dict[str, Any]]]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        key = tuple((a, r[a]) for a in group_axes)
        groups[key][float(r[x_axis]) if x_axis else 0.0].append(r)
    table: dict[tuple, dict[float, dict]] = {}
    for key, by_x in groups.items():
        table[key] = {}
        for x, rs in sorted(by_x.items()):
            agg: dict[str, Any] = {"n": len(rs)}
            for m in PLOTTED:
                if m == "mean_time_to_goal_s":
                    vals = [r[m] for r in rs if r.get("success") and r.get(m) is not None]
                else:
                    vals = [r[m] for r in rs if r.get(m) is not None]
                agg[m] = float(np.mean(vals)) if vals else None
            table[key][x] = agg
    return x_axis, table


def plot(rows: list[dict[str, Any]], axes: list[str], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x_axis, table = aggregate(rows, axes)
    paths = []
    for m, title in PLOTTED.items():
        if not any(r.get(m) is not None for r in rows):
            continue
        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        for key, by_x in table.items():
            pts = [(x, a[m]) for x, a in by_x.items() if a[m] is not None]
            if not pts:
                continue
            label = ", ".join(f"{k}={v}" for k, v in key) or "all"
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=label)
        if m == "min_clearance_m":
            ax.axhline(QuadParams().body_radius_m, color="red", ls="--", lw=1, label="airframe radius: contact below")
        unit = UNITS.get(x_axis or "")
        ax.set_xlabel(f"{x_axis} [{unit}]" if unit else (x_axis or "(single point)"))
        ax.set_ylabel(title)
        ax.set_title(f"{title} against {x_axis}" if x_axis else title)
        if m == "success" or m == "deadlock":
            ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        p = out / f"{m}.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths
