"""Soak benchmark (not a test): a long realtime flight, to see whether anything drifts.

Eight drones (by default) on a 2 m circle fly a back-and-forth swap for ``--minutes`` of
realtime flight: each flies to its antipode and back again, leg after leg, until the end
(``configs/circle_8.yaml``: the lab world, each agent's own state bundled by the relay, control
at 100 Hz; ``--source world``: the world's roster, in the ideal world it needs). Every
``--report-s`` of wall time it prints one JSON line of what each process and the run did
in that interval; at the end one more line, whether the recording is whole and readable
to its last message.

    python -m tools.bench_soak                       # 60 min (the lead schedules it: it holds the machine)
    python -m tools.bench_soak --minutes 3 --out /tmp/soak

Keys of a report line (stable): ``report`` (1, 2, ...), ``wall_s`` (since the first
status), ``sim_t_s``, ``rss_mb`` (each process's resident memory now [MiB]: world,
recorder, agents, and the router where there is one), ``cpu_s`` (each process's CPU since
it started [s]), ``cpu_frac`` (its CPU in this interval over the interval's wall time),
``late_ticks`` (agent ticks answered late, or never, in this interval: the world's count),
``on_time_fraction`` (1 - late / the agent ticks of the interval), ``recording_mb``
(``run.mcap`` now).

Keys of the last line: ``end`` (true), ``stop_reason``, ``minutes``, ``complete`` (the
file ends with its footer, the world said done, no stream has a hole: metrics.json),
``readable_to_s`` (sim time of the last message the file gives back, read to its end),
``duration_s``, ``messages``, ``lost_messages``, ``recording_mb``, ``metrics_s`` (wall time
[s] the launcher took to compute metrics.json), ``launcher_peak_rss_mb`` (this process's
largest resident memory, reached computing them: the file is streamed, the per-tick arrays kept),
``compared_reports`` (the first report and the last one taken while every process ran),
``rss_growth_pct`` (per process, its resident memory at the second of those against the
first's) and ``on_time_drift_pct`` (that report's on-time fraction less the first's, in
percent).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import time
from pathlib import Path
from typing import Any

from mcap.records import Footer, Message
from mcap.stream_reader import StreamReader

from swarm.config import ScenarioConfig, load
from swarm.runs.launch import RunHandle
from swarm.shutdown import StopSignals

ROOT = Path(__file__).resolve().parents[1]
PAGE = os.sysconf("SC_PAGE_SIZE")
TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def soak_config(minutes: float, agents: int, source: str) -> ScenarioConfig:
    """``configs/circle_8.yaml`` in realtime for ``minutes``, with ``agents`` drones on its
    circle each flying its antipode and back, leg after leg, past the end."""
    base = load(ROOT / "configs" / "circle_8.yaml")
    r, z, speed = 2.0, 1.0, base.agents[0].speed_mps
    legs = math.ceil(minutes * 60.0 * speed / (2 * r)) + 2  # more legs than the flight has time for
    out = []
    for i in range(agents):
        a = 2 * math.pi * i / agents + 0.05  # (off exact symmetry, as a lab's drones are)
        start = [round(r * math.cos(a), 4), round(r * math.sin(a), 4), z]
        goal = [-start[0], -start[1], z]
        there_and_back = [goal if j % 2 == 0 else start for j in range(legs)]
        out.append({"id": f"cf{i + 1}", "start": start, "waypoints": there_and_back})
    over = {
        "name": "soak",
        "duration_s": minutes * 60.0,
        "stop_when_all_reached": False,
        "time": {"mode": "realtime"},
        "neighbours": {"source": source},
        "agents": out,
        **({"world": {"realism": "ideal"}} if source == "world" else {}),  # the roster's exact states
    }
    return load(ROOT / "configs" / "circle_8.yaml", over)


def proc_sample(pid: int) -> tuple[float, float]:
    """(resident memory [MiB], CPU since start [s]) of process ``pid`` (its threads included)."""
    try:
        with open(f"/proc/{pid}/statm") as f:
            rss = int(f.read().split()[1]) * PAGE / 2**20
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return rss, (int(fields[11]) + int(fields[12])) * TICK_S  # utime, stime
    except (OSError, IndexError, ValueError):
        return math.nan, math.nan


def read_through(path: Path) -> tuple[int, float | None, bool]:
    """(messages, sim time [s] of the last one, whether the footer is there): ``path``
    read record by record to its end, holding none of them."""
    n, last_ns, footer = 0, None, False
    with open(path, "rb") as f:
        for record in StreamReader(f, record_size_limit=path.stat().st_size).records:
            if isinstance(record, Message):
                n += 1
                last_ns = record.log_time
            elif isinstance(record, Footer):
                footer = True
    return n, None if last_ns is None else last_ns / 1e9, footer


class Reporter:
    """One JSON line per interval from the processes' /proc and the world's status."""

    def __init__(self, h: RunHandle) -> None:
        self.h = h
        self.t0 = time.monotonic()
        self.last_wall, self.last_cpu = self.t0, {n: proc_sample(p.pid)[1] for n, p in h.procs.items()}
        self.last_k, self.last_late = 0.0, 0
        self.lines: list[dict[str, Any]] = []

    def report(self) -> dict[str, Any]:
        h, now = self.h, time.monotonic()
        st = h.progress.status
        rss, cpu = {}, {}
        for name, p in sorted(h.procs.items()):
            rss[name], cpu[name] = proc_sample(p.pid)
        dt = now - self.last_wall
        ticks = (h.progress.t_s - self.last_k) * h.cfg.time.control_hz * max(1, len(st.get("live", [])))
        late = int(st.get("late", 0)) - self.last_late
        line = {
            "report": len(self.lines) + 1,
            "wall_s": round(now - self.t0, 1),
            "sim_t_s": round(h.progress.t_s, 2),
            "rss_mb": {n: round(v, 1) for n, v in rss.items()},
            "cpu_s": {n: round(v, 2) for n, v in cpu.items()},
            "cpu_frac": {n: round((cpu[n] - self.last_cpu.get(n, 0.0)) / dt, 3) for n in cpu},
            "late_ticks": late,
            "on_time_fraction": round(1.0 - late / ticks, 5) if ticks > 0 else None,
            "recording_mb": round((h.out / "run.mcap").stat().st_size / 2**20, 1),
        }
        self.last_wall, self.last_cpu, self.last_k, self.last_late = now, cpu, h.progress.t_s, self.last_late + late
        self.lines.append(line)
        print(json.dumps(line), flush=True)
        return line


def run(args: argparse.Namespace) -> dict[str, Any]:
    cfg = soak_config(args.minutes, args.agents, args.source)
    with StopSignals() as interrupted:  # (Ctrl-C or kill: the run is stopped, not left flying)
        h = RunHandle.start(cfg, args.out)
        h.wait_sim_time(0.0, timeout_s=cfg.time.start_timeout_s + 60.0)
        rep = Reporter(h)
        reason = None
        next_at = rep.t0 + args.report_s
        while reason is None:
            reason = h.poll(wait_s=0.2) or ("interrupted" if interrupted.now else None)
            if time.monotonic() >= next_at:
                rep.report()
                next_at += args.report_s
        if not rep.lines or rep.lines[-1]["wall_s"] < (time.monotonic() - rep.t0) - 1.0:
            rep.report()  # the last part interval
        t_metrics = time.monotonic()
        h.finish(reason)  # as `swarm run` does: the processes end, metrics.json is written
    metrics_s = time.monotonic() - t_metrics
    m = json.loads((h.out / "metrics.json").read_text())
    n, until, footer = read_through(h.out / "run.mcap")
    first = rep.lines[0]
    # the last report whose processes were all still running (the run's end stops them)
    last = next((ln for ln in reversed(rep.lines) if all(math.isfinite(v) for v in ln["rss_mb"].values())), first)
    end = {
        "end": True,
        "stop_reason": reason,
        "minutes": args.minutes,
        "complete": bool(m.get("complete")) and footer,
        "readable_to_s": until,
        "duration_s": m.get("duration_s"),
        "messages": n,
        "lost_messages": m.get("lost_messages"),
        "recording_mb": round((h.out / "run.mcap").stat().st_size / 2**20, 1),
        "metrics_s": round(metrics_s, 1),
        "launcher_peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "compared_reports": [first["report"], last["report"]],
        "rss_growth_pct": {
            p: round(100.0 * (last["rss_mb"][p] / first["rss_mb"][p] - 1.0), 2)
            for p in first["rss_mb"]
            if first["rss_mb"][p] > 0 and p in last["rss_mb"]
        },
        "on_time_drift_pct": (
            round(100.0 * (last["on_time_fraction"] - first["on_time_fraction"]), 3)
            if last["on_time_fraction"] is not None and first["on_time_fraction"] is not None
            else None
        ),
    }
    print(json.dumps(end), flush=True)
    return end


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=60.0, help="realtime flight [min]")
    ap.add_argument("--report-s", type=float, default=60.0, help="wall time between report lines [s]")
    ap.add_argument("--agents", type=int, default=8)
    ap.add_argument("--source", choices=("world", "agents"), default="agents", help="neighbours.source")
    ap.add_argument("--out", type=Path, default=Path("runs/bench_soak"))
    run(ap.parse_args())


if __name__ == "__main__":
    main()
