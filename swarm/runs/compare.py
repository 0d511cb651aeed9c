"""``swarm compare CONFIG --filters c3bf,hocbf [--realism ideal,crazyflie_lab]``: one scenario
under several safety filters, in one world or side by side in several.

Each filter runs the whole scenario as real processes (every agent switched to that
filter: a built-in barrier or an installed plugin, ``swarm.plugins``; ``none`` flies the
reference controller unfiltered), in each world asked
(``world.realism``'s presets; none asked: the config's own). The table, printed and saved
as ``compare.md`` and ``compare.json`` in the output folder, has per filter (and world): collisions,
closest approach of a body centre to an obstacle surface, closest approach between
agents, minimum h, the latest time to goal, the largest deviation from the reference
path, and infeasible ticks. Every run folder is kept under the output folder.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from swarm.config import ScenarioConfig, resolve
from swarm.plugins import BUILTIN, FILTERS, UNFILTERED
from swarm.runs.launch import RunHandle
from swarm.runs.point import summarise
from swarm.runs.readable import fig, markdown_table, notes
from swarm.strict import merge

COLUMNS = (
    ("world", "world"),
    ("filter", "filter"),
    ("collisions", "contacts"),
    ("margin_violations", "inside the safety radius"),
    ("min_clearance_m", "closest to an obstacle surface [m]"),
    ("min_separation_m", "closest between agents [m]"),
    ("min_h", "min exact C3BF h [m^2/s]"),
    ("negative_h_ticks", "ticks with h < 0"),
    ("max_time_to_goal_s", "latest time to goal [s]"),
    ("max_path_deviation_m", "largest path deviation [m]"),
    ("infeasible_ticks", "infeasible ticks"),
    ("plugin_fallbacks", "plugin fallbacks"),
    ("all_reached_goal", "all reached goal"),
)


def with_filter(cfg: ScenarioConfig, name: str) -> ScenarioConfig:
    """The scenario with every agent on filter ``name`` (a name registered in
    ``c3swarm.filters``; ``none``: unfiltered), validated again: an unknown name, a plugin that
    cannot be imported or one that does not filter an agent's command level raise
    :class:`ConfigError`. An agent keeps its ``filter.options`` where it already flies ``name``."""
    if name == "none":
        agents = [a.model_copy(update={"filter": a.filter.model_copy(update={"enabled": False})}) for a in cfg.agents]
        return cfg.model_copy(update={"agents": agents})
    raw = cfg.model_dump(mode="json")
    for a in raw["agents"]:
        f = a["filter"]
        if f["kind"] != name:
            f["options"] = {}
        f.update(kind=name, enabled=True)
    return resolve(raw, f"{cfg.name} with filter {name}")


def in_world(cfg: ScenarioConfig, realism: str) -> ScenarioConfig:
    """The scenario in the world of ``world.realism``'s preset ``realism`` (its margins follow:
    they are derived from the world, ``swarm.tuning``). Raises :class:`ConfigError` for an
    unknown preset or a world the config cannot fly (motion capture with the world's roster)."""
    raw = merge(cfg.model_dump(mode="json"), {"world": {"realism": realism}})
    return resolve(raw, f"{cfg.name} in world.realism {realism}")


def row(name: str, metrics: dict[str, Any], world: str | None = None) -> dict[str, Any]:
    """One table row: the sweep's summary of the run (``swarm.runs.point.summarise``)."""
    return {"world": world, "filter": name, **summarise(metrics)}


def spread(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """One row of several seeds' rows of one filter (and world): each number as its
    ``{"mean", "min", "max", "n"}`` over the seeds that have it, a yes/no as how many of the
    seeds said yes (``{"yes", "n"}``), anything else the first seed's; ``seeds`` their count."""
    out: dict[str, Any] = {"seeds": len(rows)}
    for key in rows[0]:
        vals = [r.get(key) for r in rows]
        if all(isinstance(v, bool) for v in vals):
            out[key] = {"yes": sum(vals), "n": len(vals)}
        elif all(isinstance(v, int | float) and not isinstance(v, bool) for v in vals if v is not None) and any(
            v is not None for v in vals
        ):
            nums = [v for v in vals if v is not None]
            out[key] = {"mean": sum(nums) / len(nums), "min": min(nums), "max": max(nums), "n": len(nums)}
        else:
            out[key] = vals[0]
    return out


def compare(
    cfg: ScenarioConfig, filters: list[str], out: Path, worlds: list[str] | None = None, seeds: int = 1
) -> list[dict[str, Any]]:
    """Run ``cfg`` under each filter, in each of ``worlds`` (None: the config's own world), each
    run in ``out/<filter>`` (with worlds: ``out/<world>/<filter>``); the rows, also saved. With
    ``seeds`` above 1 each is flown with seeds ``cfg.seed`` to ``cfg.seed + seeds - 1`` (in
    ``.../seed<k>``) and its row holds the spread (:func:`spread`)."""
    runs = [(None, cfg)] if worlds is None else [(w, in_world(cfg, w)) for w in worlds]
    rows = []
    for world, c in runs:
        for name in filters:
            folder = out / name if world is None else out / world / name
            per_seed = []
            for k in range(seeds):
                run_cfg = with_filter(c, name)
                if seeds > 1:
                    run_cfg = run_cfg.model_copy(update={"seed": c.seed + k})
                h = RunHandle.start(run_cfg, folder if seeds == 1 else folder / f"seed{c.seed + k}")
                h.wait()
                per_seed.append(row(name, json.loads((h.out / "metrics.json").read_text()), world))
            rows.append(per_seed[0] if seeds == 1 else spread(per_seed))
    (out / "compare.json").write_text(json.dumps(rows, indent=2))
    (out / "compare.md").write_text(markdown(cfg.name, rows))
    return rows


def _fmt(v: Any, key: str = "") -> str:
    """A cell: ``swarm.runs.readable.fig``."""
    return fig(v, key)


def columns(rows: list[dict[str, Any]]) -> tuple[tuple[str, str], ...]:
    """The table's columns: the world's only where a row names one, the plugin fallbacks' only
    where a row flies a plugin (not c3swarm's own filters) or counts one, the seeds' where rows
    hold several."""
    own = {*BUILTIN[FILTERS], UNFILTERED, "orca"}
    show = {
        "world": any(r.get("world") for r in rows),
        "plugin_fallbacks": any(r.get("filter") not in own or r.get("plugin_fallbacks") for r in rows),
    }
    cols = tuple(c for c in COLUMNS if show.get(c[0], True))
    if any(r.get("seeds") for r in rows):
        at = 2 if cols[0][0] == "world" else 1  # after the world and the filter
        cols = (*cols[:at], ("seeds", "seeds"), *cols[at:])
    return cols


def cells(rows: list[dict[str, Any]]) -> tuple[list[str], list[list[str]], list[str]]:
    """The table's header, its cells, and the meaning of each column (its legend)."""
    cols = columns(rows)
    body = [[_fmt(r.get(key), key) for key, _ in cols] for r in rows]
    legend = notes([k for k, _ in cols], dict(cols))
    if any(r.get("seeds") for r in rows):
        legend.append("over several seeds: each number is mean [min, max] over the seeds; a yes/no, how many said yes")
    return [t for _, t in cols], body, legend


def markdown(name: str, rows: list[dict[str, Any]]) -> str:
    header, body, legend = cells(rows)
    return "\n".join(
        [f"# {name}: filters compared", "", markdown_table(header, body), "", *(f"* {line}" for line in legend), ""]
    )
