"""Scaling at constant density: does an agent's cost stay flat as the swarm grows?

    python -m tools.bench_scaling [--agents 4,8,16,32,64] [--density 0.1] [--seconds 10]
        [--interest bundle|cells|all] [--mode lockstep] [--plot docs/scaling.png] [--rows FILE]

One JSON line per swarm size (the keys of ``tools.bench_swarm``, with ``density_per_m2``):
``n`` agents with random starts in a square whose side keeps ``n / side^2`` at
``--density`` (``swarm.offline.scenario.random_swap``), each flying 4 m in a random direction
(:func:`local_hops`), so the neighbours within an agent's interest radius stay about the
same whatever ``n``; neighbours from the agents'
own states (``neighbours.source: agents``: the bundle relay's bundles by default, or by cells
through the router, or every agent's), 100 Hz control,
lockstep by default. ``--plot`` draws ``cpu_us_per_agent_tick`` and
``rx_bytes_per_agent_tick`` against ``n`` from the lines of ``--rows`` (a JSON-lines file,
e.g. this tool's own output) or of this run.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from swarm.offline.scenario import SwapSettings, random_swap
from tools.bench_swarm import run_row

HOP_M = 4.0  # each agent flies this far [m], in a random direction, from a random start


def local_hops(n: int, density: float, settings: SwapSettings, spacing_m: float = 1.0) -> dict:
    """``n`` agents at random starts at ``density`` per m^2 (``random_swap``'s), each flying
    ``HOP_M`` in a random direction (goals ``spacing_m`` apart): the density stays about the
    same everywhere and all the time, unlike random goals across the square, whose paths
    crowd its centre more as ``n`` grows."""
    raw = random_swap(n, density, settings, name=f"scaling_{n}", min_spacing_m=spacing_m)
    rng = np.random.default_rng(settings.seed + 1)
    goals: list[np.ndarray] = []
    for a in raw["agents"]:
        start = np.asarray(a["start"], float)
        for _ in range(1000):
            th = rng.uniform(0.0, 2.0 * math.pi)
            g = start + HOP_M * np.array([math.cos(th), math.sin(th), 0.0])
            if all(np.linalg.norm(g - other) >= spacing_m for other in goals):
                break
        else:
            raise ValueError(f"local_hops: no goal {spacing_m} m from the others for {a['id']}")
        goals.append(g)
        a["goal"] = [round(float(c), 6) for c in g]
    return raw


def bench_size(n: int, density: float, seconds: float, mode: str, interest: str, out: Path) -> dict:
    settings = SwapSettings(
        control_hz=100.0, physics_hz=300.0, duration_s=seconds, mode=mode, neighbours="agents", seed=n
    )
    raw = local_hops(n, density, settings)
    raw["time"]["start_timeout_s"] = 60.0 + 3.0 * n  # every agent's warm-up, on two cores
    raw["limits"] = {"max_agents": max(n, 1)}
    row = run_row(raw, n, mode, 100.0, out / f"scaling_{n}_{mode}_{interest}", interest=interest)
    return {**row, "density_per_m2": density}


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for interest in sorted({r.get("interest") or "cells" for r in rows}):
        sel = sorted((r for r in rows if (r.get("interest") or "cells") == interest), key=lambda r: r["agents"])
        n = [r["agents"] for r in sel]
        axes[0].plot(n, [r["cpu_us_per_agent_tick"] for r in sel], "o-", label=f"interest: {interest}")
        axes[1].plot(n, [r["rx_bytes_per_agent_tick"] for r in sel], "o-", label=f"interest: {interest}")
    for ax, what in zip(axes, ("agent CPU per control tick [us]", "bytes received per agent and tick"), strict=True):
        ax.set_xscale("log", base=2)
        ax.set_xlabel("agents (constant density)")
        ax.set_ylabel(what)
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
        ax.legend()
    density = rows[0].get("density_per_m2") if rows else None
    fig.suptitle(f"neighbours.source: agents, {density} agents/m^2, lockstep, 100 Hz")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", default="4,8,16,32,64")
    ap.add_argument("--density", type=float, default=0.1, help="agents per m^2")
    ap.add_argument("--seconds", type=float, default=10.0, help="sim time of each run")
    ap.add_argument("--mode", default="lockstep", choices=["lockstep", "realtime"])
    ap.add_argument("--interest", default="bundle", help="bundle, cells, all, or several: bundle,cells")
    ap.add_argument("--out", type=Path, default=Path("runs/bench_scaling"))
    ap.add_argument("--plot", type=Path, help="write the figure here (PNG)")
    ap.add_argument("--rows", type=Path, help="plot these JSON lines instead of running")
    args = ap.parse_args()
    if args.rows:
        rows = [json.loads(line) for line in args.rows.read_text().splitlines() if line.strip()]
    else:
        rows = []
        for n in (int(x) for x in args.agents.split(",")):
            for interest in args.interest.split(","):
                row = bench_size(n, args.density, args.seconds, args.mode, interest, args.out)
                print(json.dumps(row), flush=True)
                rows.append(row)
    if args.plot:
        plot(rows, args.plot)


if __name__ == "__main__":
    main()
