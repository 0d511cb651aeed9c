"""One point of a sweep (or of ``swarm compare``): fly it as a whole swarm, or as the ORCA
baseline, and sum its ``metrics.json`` up in one results row."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarm.config import ConfigError, ScenarioConfig
from swarm.offline.orca import run_orca
from swarm.runs.launch import RunHandle


def summarise(metrics: dict[str, Any]) -> dict[str, Any]:
    """One results row from a run's ``metrics.json``."""
    agents = list(metrics.get("agents", {}).values())
    times = [a["time_to_goal_s"] for a in agents]
    ratios = [a["path_length_m"] / a["straight_line_m"] for a in agents if a["straight_line_m"] > 1e-9]
    hs = [a["min_h"] for a in agents if a["min_h"] is not None]
    solve = [a["solve_us_mean"] for a in agents if a.get("solve_us_mean")]
    reached = bool(metrics.get("all_reached_goal"))
    return {
        "success": int(reached and metrics.get("collisions", 1) == 0),
        "all_reached_goal": reached,
        "collisions": metrics.get("collisions"),
        "margin_violations": metrics.get("margin_violations"),
        "max_margin_depth_m": metrics.get("max_margin_depth_m"),
        "min_clearance_m": metrics.get("min_obstacle_clearance_m"),
        "min_separation_m": metrics.get("min_separation_m"),
        "min_h": min(hs) if hs else None,
        "negative_h_ticks": metrics.get("negative_h_ticks"),
        "mean_time_to_goal_s": None if (not times or None in times) else float(np.mean(times)),
        "max_time_to_goal_s": None if (not times or None in times) else max(times),
        "path_length_ratio": float(np.mean(ratios)) if ratios else None,
        "max_path_deviation_m": max((a["max_path_deviation_m"] for a in agents), default=None),
        "infeasible_ticks": None
        if any(a["infeasible_ticks"] is None for a in agents)
        else sum(a["infeasible_ticks"] for a in agents),  # None: not a measure of the method (ORCA)
        "plugin_fallbacks": metrics.get("plugin_fallbacks"),  # a plugin filter's ticks on the built-in fallback
        "deadlock": int(bool(metrics.get("deadlocked_agents"))),
        "deadlocked_agents": len(metrics.get("deadlocked_agents", [])),
        "solve_us_mean": float(np.mean(solve)) if solve else None,
        "agents": len(agents),
        "stop_reason": metrics.get("stop_reason"),
    }


def run_point(cfg: ScenarioConfig, method: str, out: Path) -> dict[str, Any]:
    """Fly one point: the whole swarm as real processes, or the ORCA baseline."""
    if method == "orca":
        try:
            return summarise(run_orca(cfg, out))
        except ValueError as exc:
            raise ConfigError(f"{cfg.name}: {exc}") from None
    h = RunHandle.start(cfg, out)
    h.wait()
    return summarise(json.loads((out / "metrics.json").read_text()))


ROW_FILE = "row.json"
"""Each finished point's results row, in its run folder (what ``--resume`` keeps)."""


@dataclass(frozen=True)
class Job:
    """One grid point to fly: its row's first columns, its config and where it runs."""

    index: int
    head: dict[str, Any]  # the row's first columns: run (the folder's name) and the point's knobs
    cfg: ScenarioConfig
    method: str  # "swarm" or "orca"
    folder: Path


def fly(job: Job) -> dict[str, Any]:
    """The results row of one point; a run that raised is a row that says why (``error``),
    never a lost sweep."""
    try:
        return {**job.head, **run_point(job.cfg, job.method, job.folder), "error": ""}
    except Exception as exc:  # a crash of this run: its row, the others go on
        return {**job.head, "success": 0, "error": f"{type(exc).__name__}: {exc}"}


def fly_reporting(job: Job, on_start: Callable[[dict[str, Any]], None] | None) -> dict[str, Any]:
    """:func:`fly`, first telling ``on_start`` the point's first columns."""
    if on_start:
        on_start(job.head)
    return fly(job)
