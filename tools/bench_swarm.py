"""Benchmark of whole swarms as real processes, printed as JSON lines.

    python -m tools.bench_swarm [--agents 2,4,8,16] [--modes lockstep,realtime] [--rate 100] [--seconds 10]
        [--sources agents,world] [--topology auto|mesh|star|router] [--access-control on|off]
        [--interest auto|bundle|cells|all] [--busy N]

One line per (agents, mode) on a ``circle_<n>`` antipodal swap at ``--rate`` Hz control
(physics at 3x), in the world ``swarm scenario`` writes (``crazyflie_lab``; with ``--sources
world``, the roster of true states, its motion capture off), with: ``real_time_factor`` (sim
time / wall time), ``on_time_fraction`` (commands for tick k that reached the world before it published tick k+1),
``cpu_percent_per_agent`` (steady-state CPU of one agent process, start-up excluded,
averaged over agents, as a percentage of one core; ``world_cpu_percent`` likewise), ``p99_tick_latency_ms`` (world
sends a measurement -> receives that tick's command), ``cpu_us_per_agent_tick`` (an
agent's CPU per control tick [us], start-up excluded, averaged over agents),
``rx_bytes_per_agent_tick`` and ``rx_messages_per_agent_tick`` (payload bytes and messages an
agent received per tick), ``missed_neighbours``
(near neighbours whose state was not there when used, summed over agents),
``recorder_cpu_us_per_tick`` (the recorder's CPU per world tick [us], start-up excluded: the
message channels, the Foxglove scene and the log), ``relay_cpu_us_per_tick`` (the bundle relay's,
likewise; nan without one), ``swarm_cpu_us_per_agent_tick`` (every process's steady CPU, agents,
world, relay and recorder, per agent and world tick [us]) against ``budget_us_per_agent_tick`` (the
CPUs this process may use, per agent tick at ``--rate``: what a realtime swarm can spend), plus
collisions, late ticks and the minimum separation, and ``busy_processes`` (``--busy N``: N
processes spin on the CPUs meanwhile, one pinned to each, an overloaded machine). Each run's
folder is kept under ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from swarm import ledger
from swarm.config import resolve
from swarm.offline.scenario import SwapSettings, circle_swap
from swarm.runs.launch import RunHandle


def summaries(run_dir: Path) -> tuple[dict, list[dict]]:
    world, agents = {}, []
    for log in (run_dir / "logs").glob("*.log"):
        for line in log.read_text().splitlines():
            m = re.match(r"(WORLD|AGENT)_SUMMARY (.*)", line)
            if m and m.group(1) == "WORLD":
                world = json.loads(m.group(2))
            elif m:
                agents.append(json.loads(m.group(2)))
    return world, agents


def bench_one(
    n: int,
    mode: str,
    rate_hz: float,
    seconds: float,
    out: Path,
    source: str = "agents",
    topology: str = "auto",
    access_control: bool = True,
    interest: str = "auto",
) -> dict:
    settings = SwapSettings(
        rotation_rad=0.05, control_hz=rate_hz, physics_hz=3 * rate_hz, duration_s=seconds, mode=mode, neighbours=source
    )
    raw = circle_swap(n, max(2.0, 0.35 * n), settings, name=f"bench_{n}_{mode}")
    if source == "world":  # the roster is every drone's true state: the world's motion capture off, the rest as it is
        raw["world"]["realism"] = {"preset": raw["world"]["realism"], "sensing": {"enabled": False}}
    return run_row(raw, n, mode, rate_hz, out / f"circle_{n}_{mode}_{source}", topology, access_control, interest)


def run_row(
    raw: dict,
    n: int,
    mode: str,
    rate_hz: float,
    out: Path,
    topology: str = "auto",
    access_control: bool = True,
    interest: str = "auto",
) -> dict:
    """Run the scenario ``raw`` to its end and return the benchmark's line."""
    raw["stop_when_all_reached"] = False
    raw["network"] = {"topology": topology, "access_control": access_control}
    raw.setdefault("neighbours", {})["interest"] = interest
    cfg = resolve(raw, raw["name"])
    source = cfg.neighbours.source
    h = RunHandle.start(cfg, out.with_name(f"{out.name}_{cfg.topology}"))
    reason = h.wait()
    world, agents = summaries(h.out)
    metrics = json.loads((h.out / "metrics.json").read_text()) if (h.out / "metrics.json").exists() else {}
    wall = world["t_s"] / world["real_time_factor"] if world.get("real_time_factor") else float("nan")
    cpu = [(a["cpu_s"] - a["startup_cpu_s"]) / wall * 100 for a in agents] if agents else [float("nan")]
    per_tick = [
        (
            (a["cpu_s"] - a["startup_cpu_s"]) * 1e6 / a["ticks"],
            a.get("rx_bytes", 0) / a["ticks"],
            a.get("rx_messages", 0) / a["ticks"],
        )
        for a in agents
        if a.get("ticks")
    ]
    nan = float("nan")
    us, rx, msgs = np.mean(per_tick, axis=0).tolist() if per_tick else (nan, nan, nan)
    rec_path = h.out / "recorder.json"
    rec = json.loads(rec_path.read_text()) if rec_path.exists() else {}
    rec_us = ((rec["cpu_s"] - rec["startup_cpu_s"]) * 1e6 / rec["clocks"]) if rec.get("clocks") else float("nan")
    relay = ledger.summaries(h.out / "logs").get("router", {})
    ticks = world.get("ticks") or nan
    relay_s = relay["cpu_s"] - relay["startup_cpu_s"] if "cpu_s" in relay else 0.0  # (no relay: no CPU)
    relay_us = relay_s * 1e6 / ticks if "cpu_s" in relay else nan
    steady_s = [a["cpu_s"] - a["startup_cpu_s"] for a in agents]
    steady_s += [world.get("cpu_s", nan) - world.get("startup_cpu_s", 0.0), relay_s]
    steady_s += [rec["cpu_s"] - rec["startup_cpu_s"] if rec.get("clocks") else nan]
    return {
        "agents": n,
        "mode": mode,
        "rate_hz": rate_hz,
        "neighbour_source": source,
        "topology": cfg.topology,
        "access_control": access_control,
        "interest": cfg.interest if source == "agents" else None,
        "cpu_us_per_agent_tick": round(us, 1),
        "rx_bytes_per_agent_tick": round(rx, 1),
        "rx_messages_per_agent_tick": round(msgs, 2),
        "missed_neighbours": sum(a.get("missed_neighbours", 0) for a in agents),
        "real_time_factor": round(world.get("real_time_factor", float("nan")), 3),
        "on_time_fraction": round(world["on_time_fraction"], 4) if world.get("on_time_fraction") is not None else None,
        "cpu_percent_per_agent": round(float(np.mean(cpu)), 1),
        "p99_tick_latency_ms": round(world["p99_tick_latency_ms"], 2) if world.get("p99_tick_latency_ms") else None,
        "late_ticks": world.get("late"),
        "collisions": metrics.get("collisions"),
        "margin_violations": metrics.get("margin_violations"),
        "min_h": metrics.get("min_h"),
        "min_separation_m": metrics.get("min_separation_m"),
        "world_cpu_percent": round((world.get("cpu_s", 0) - world.get("startup_cpu_s", 0)) / wall * 100, 1),
        "recorder_cpu_us_per_tick": round(rec_us, 1),
        "relay_cpu_us_per_tick": round(relay_us, 1),
        "swarm_cpu_us_per_agent_tick": round(sum(steady_s) * 1e6 / (n * ticks), 1),
        "budget_us_per_agent_tick": round(len(os.sched_getaffinity(0)) * 1e6 / (n * rate_hz), 1),
        "stop_reason": reason,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", default="2,4,8,16")
    ap.add_argument("--modes", default="lockstep,realtime")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--seconds", type=float, default=10.0, help="sim time: 10 s covers the crossing at the centre")
    ap.add_argument("--sources", default="agents,world", help="neighbour sources (see NeighbourSettings)")
    ap.add_argument(
        "--interest",
        default="auto",
        choices=["auto", "bundle", "cells", "all"],
        help="agents source: the router's bundles, by cells, or every agent (NeighbourSettings.interest)",
    )
    ap.add_argument(
        "--topology",
        default="auto",
        choices=["auto", "mesh", "star", "router"],
        help="which processes link to which (see NetworkSettings.topology)",
    )
    ap.add_argument(
        "--access-control",
        choices=["on", "off"],
        default="on",
        help="Zenoh authentication and access control (network.access_control)",
    )
    ap.add_argument("--out", type=Path, default=Path("runs/bench_swarm"))
    ap.add_argument(
        "--busy", type=int, default=0, help="overload: this many busy-looping processes, one pinned to each CPU"
    )
    args = ap.parse_args()
    with Busy(args.busy):
        run_all(args)


class Busy:
    """``n`` processes that spin on the CPU, process i pinned to the i-th CPU this one may
    use, for as long as the ``with`` block runs (an overloaded machine)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.procs: list[subprocess.Popen[bytes]] = []

    def __enter__(self) -> Busy:
        cpus = sorted(os.sched_getaffinity(0))
        for i in range(self.n):
            spin = f"import os; os.sched_setaffinity(0, {{{cpus[i % len(cpus)]}}})\nwhile True: pass"
            self.procs.append(subprocess.Popen([sys.executable, "-c", spin], start_new_session=True))
        return self

    def __exit__(self, *exc: object) -> None:
        for p in self.procs:
            p.kill()
            p.wait()


def run_all(args: argparse.Namespace) -> None:
    for n in (int(x) for x in args.agents.split(",")):
        for mode in args.modes.split(","):
            for source in args.sources.split(","):
                row = bench_one(
                    n,
                    mode,
                    args.rate,
                    args.seconds,
                    args.out,
                    source,
                    args.topology,
                    args.access_control == "on",
                    args.interest,
                )
                row["busy_processes"] = args.busy
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
