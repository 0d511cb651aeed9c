"""``swarm compare CONFIG --filters c3bf,hocbf``: one scenario under several safety filters.

Each filter runs the whole scenario as real processes (every agent switched to that
barrier; ``none`` flies the reference controller unfiltered). The table, printed and saved
as ``compare.md`` and ``compare.json`` in the output folder, has per filter: collisions,
closest approach of a body centre to an obstacle surface, closest approach between
agents, minimum h, the latest time to goal, the largest deviation from the reference
path, and infeasible ticks. Every run folder is kept under the output folder.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from swarm.config import ScenarioConfig
from swarm.runs.launch import RunHandle
from swarm.runs.point import summarise
from swarm.safety.barriers import BarrierKind

COLUMNS = (
    ("filter", "filter"),
    ("collisions", "contacts"),
    ("margin_violations", "inside the safety radius"),
    ("min_clearance_m", "closest to an obstacle surface [m]"),
    ("min_separation_m", "closest between agents [m]"),
    ("min_h", "min exact h [m^2/s]"),
    ("negative_h_ticks", "ticks with h < 0"),
    ("max_time_to_goal_s", "time to goal [s] (latest)"),
    ("max_path_deviation_m", "largest path deviation [m]"),
    ("infeasible_ticks", "infeasible ticks"),
    ("all_reached_goal", "all reached goal"),
)


def with_filter(cfg: ScenarioConfig, name: str) -> ScenarioConfig:
    """The scenario with every agent on barrier ``name`` (``none``: unfiltered)."""
    agents = []
    for a in cfg.agents:
        update: dict[str, Any] = {"enabled": name != "none"}
        if name != "none":
            update["kind"] = BarrierKind(name)
        f = a.filter.model_copy(update=update)
        agents.append(a.model_copy(update={"filter": f}))
    return cfg.model_copy(update={"agents": agents})


def row(name: str, metrics: dict[str, Any]) -> dict[str, Any]:
    """One table row: the sweep's summary of the run (``swarm.runs.point.summarise``)."""
    return {"filter": name, **summarise(metrics)}


def compare(cfg: ScenarioConfig, filters: list[str], out: Path) -> list[dict[str, Any]]:
    rows = []
    for name in filters:
        h = RunHandle.start(with_filter(cfg, name), out / name)
        h.wait()
        rows.append(row(name, json.loads((h.out / "metrics.json").read_text())))
    (out / "compare.json").write_text(json.dumps(rows, indent=2))
    (out / "compare.md").write_text(markdown(cfg.name, rows))
    return rows


def _fmt(v: Any) -> str:
    return f"{v:.3f}" if isinstance(v, float) else ("-" if v is None else str(v))


def markdown(name: str, rows: list[dict[str, Any]]) -> str:
    head = "| " + " | ".join(title for _, title in COLUMNS) + " |"
    rule = "|" + "---|" * len(COLUMNS)
    body = ["| " + " | ".join(_fmt(r[key]) for key, _ in COLUMNS) + " |" for r in rows]
    return "\n".join([f"# {name}: filters compared", "", head, rule, *body, ""])
