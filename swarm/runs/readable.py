"""What a user reads: figures rounded to what they mean, tables that read anywhere, and a
one-line meaning of each metric printed under them.

Pure but for :func:`print_table`, which picks how to print: a rich table on a terminal, plain
markdown (full width, never cut) in a log, CI or a pipe.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from typing import Any, TextIO

MEANINGS: dict[str, str] = {
    "collisions": "bodies that touched (PyBullet contacts among live drones and with obstacles); 0 is safe",
    "margin_violations": "pairs that came closer than their radii plus the filter's margin (the distance it keeps)",
    "downwash_pairs": "pairs that flew inside each other's downwash ellipsoid",
    "min_clearance_m": "closest approach of a drone's body centre to an obstacle's surface [m]",
    "min_obstacle_clearance_m": "closest approach of a drone's body centre to an obstacle's surface [m]",
    "min_separation_m": "closest approach between two drones' body centres [m]",
    "min_h": (
        "smallest exact C3BF collision-cone barrier h over every pair and obstacle [m^2/s], computed from the "
        "recorded states whatever the filter (HO-CBF and none are scored on C3BF's cone); below 0 means on a "
        "course into the other's cone, not a contact"
    ),
    "negative_h_ticks": (
        "agent ticks with some exact h below 0 (see min h); the filter turns the course back out of the cone, "
        "sampled control lets a few ticks through, and they are no contact"
    ),
    "reached_goal": "the agent came within goal_tolerance_m of its goal",
    "path_length_m": "distance the agent flew [m]",
    "min_row_h": "smallest h the agent's own filter rows reported as it flew [m^2/s] (escape rows left out)",
    "monitor": "ticks the agent's safety monitor warned, slowed, held or landed its drone",
    "time_to_goal_s": "per agent: sim time of its first arrival within goal_tolerance_m of its goal [s]",
    "max_time_to_goal_s": "latest arrival among the agents: sim time the last one reached its goal [s]",
    "mean_time_to_goal_s": "mean arrival over the agents [s]",
    "max_path_deviation_m": "largest distance of any drone from its reference path [m]",
    "infeasible_ticks": "agent ticks whose filter QP had no clean solution (the fallback command flew)",
    "all_reached_goal": "every agent came within goal_tolerance_m of its goal",
    "plugin_fallbacks": "agent ticks a plugin's command (filter's or controller's) was replaced by the built-in's "
    "(it raised, was not finite, left the limits or overran its budget: docs/plugins.md)",
    "duration_s": "sim time the run lasted [s]",
    "real_time_factor": "sim time over wall time (above 1: faster than real time)",
    "late_ticks": "agent ticks whose command came after the world's deadline (it kept the last one)",
    "dropped_messages": "messages the processes dropped as malformed, late or from the wrong sender",
    "lost_agents": "agents whose process died during the run",
    "stop_reason": "what ended the run",
    "seeds": "how many seeds each row flew (world.realism's randomness; the ideal world repeats itself exactly)",
    "success": "every agent reached its goal with no contact",
    "deadlock": "some agent stopped short of its goal for good (1) or none did (0)",
}
"""One line per metric: what it means, with its unit. Printed under every table that shows it
(``swarm run``, ``swarm compare``, ``swarm report``'s summary) and listed in docs/design.md."""

SECONDS_SUFFIXES = ("_s",)
METRES_SUFFIXES = ("_m",)


def fig(value: Any, key: str = "") -> str:
    """``value`` as a user reads it: ``-`` for none, integers and words as they are, metres to
    the millimetre and seconds to the millisecond (by ``key``'s unit suffix), anything else
    to 3 significant digits; a non-finite number as itself."""
    if value is None:
        return "-"
    if isinstance(value, bool) or isinstance(value, int) or isinstance(value, str):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return str(value)
        if key.endswith(METRES_SUFFIXES) or key.endswith(SECONDS_SUFFIXES):
            text = f"{value:.3f}"
            return "0.000" if text == "-0.000" else text
        return f"{value:#.3g}".rstrip(".")
    if isinstance(value, dict) and {"mean", "min", "max"} <= set(value):  # a spread over seeds
        lo, hi = fig(value["min"], key), fig(value["max"], key)
        mean = fig(float(value["mean"]), key if key.endswith(METRES_SUFFIXES + SECONDS_SUFFIXES) else "")
        return lo if lo == hi else f"{mean} [{lo}, {hi}]"
    if isinstance(value, dict) and {"yes", "n"} <= set(value):  # how many seeds said yes
        return f"{value['yes']}/{value['n']}"
    if isinstance(value, list | tuple):
        return ", ".join(fig(v, key) for v in value) if value else "-"
    return str(value)


def notes(keys: Sequence[str], titles: dict[str, str] | None = None) -> list[str]:
    """The meaning of each of ``keys`` that has one, as ``title: meaning`` lines."""
    titles = titles or {}
    return [f"{titles.get(k, k)}: {MEANINGS[k]}" for k in keys if k in MEANINGS]


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A markdown (GitHub) table; ``|`` in a cell escaped."""

    def line(cells: Sequence[str]) -> str:
        return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"

    return "\n".join([line(header), "|" + "---|" * len(header), *(line(r) for r in rows)])


def print_table(
    title: str,
    header: Sequence[str],
    rows: Sequence[Sequence[str]],
    legend: Sequence[str] = (),
    stream: TextIO | None = None,
) -> None:
    """Print a table and its ``legend`` lines under it: rich's box table on a terminal, plain
    markdown otherwise (nothing cut, whatever the width)."""
    stream = stream or sys.stdout
    if stream.isatty():
        from rich.console import Console
        from rich.table import Table

        table = Table(title=title)
        for h in header:
            table.add_column(h)
        for r in rows:
            table.add_row(*r)
        console = Console(file=stream)
        console.print(table)
        for line in legend:
            console.print(line, markup=False, highlight=False, style="dim")
        return
    text = ["", f"{title}", "", markdown_table(header, rows)]
    if legend:
        text += ["", *(f"* {line}" for line in legend)]
    stream.write("\n".join(text) + "\n")
