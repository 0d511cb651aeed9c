"""Benchmark of the ROS 2 bridge (swarm.ros2), printed as JSON lines.

    python -m tools.bench_ros2 [--agents 16] [--mode realtime] [--rate 100] [--seconds 10] [--pairs 2]
        [--ros2-rate 30] [--out runs/bench_ros2]

A ``circle_<n>`` antipodal swap (as ``tools.bench_swarm``) through the run's router, flown
with the bridge (``ros2.enabled``) and without it, in ABBA order (on, off, off, on, ...) in
one session. With the bridge, a ROS 2 participant (a Zenoh session with the run's ``ros2``
credentials, as ``ros2.env`` sets it up) subscribes to every drone's pose and velocity,
``/tf``, ``/clock``, the filter status and the obstacles, so every message is encoded and
sent. One line per run, with:

* ``swarm_cpu_us_per_tick``: CPU [us] of every process of the run (world, agents, recorder,
  router and, when on, the bridge; each read from ``/proc/<pid>/stat``, all threads) per
  world tick, between sim times 2 s and 1 s before the end (start-up and wind-down left out);
* ``bridge_cpu_us_per_tick`` and ``router_cpu_us_per_tick`` over the same span;
* ``subscribed``: ``--topics all`` (every topic: the bridge then also takes every agent's
  command for the filter status) or ``poses`` (poses, velocities, /tf, /clock);
* ``delay_ms_median``/``delay_ms_p99``: wall time from the clock message of tick k reaching
  the participant's process to that tick's pose of a drone reaching it (the bridge waits
  for the next clock when a publication is due, decodes it and publishes);
* ``bridge_share``: with the bridge, its CPU per tick over the swarm's; ``pair_extra``
  (on lines after their pair): the pair's extra swarm CPU per tick with the bridge over the
  swarm's without it.
"""

from __future__ import annotations

import argparse
import json
import os
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from swarm.config import resolve
from swarm.net import access
from swarm.net import transport as tp
from swarm.net.messages import decode
from swarm.net.ros2.topics import Kind, run_topics
from swarm.offline.scenario import SwapSettings, circle_swap
from swarm.runs.launch import RunHandle

CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU [s] of process ``pid`` (all its threads) so far; 0 once it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


class Participant:
    """The ROS 2 side: every topic of the run subscribed with the ``ros2`` credentials,
    arrival times of each tick's clock (seen by the launcher) and of cf poses."""

    def __init__(self, h: RunHandle, kinds: tuple[Kind, ...]) -> None:
        self.clock_at: dict[float, float] = {}
        self.pose_at: list[tuple[float, float]] = []  # (stamp [s], arrival [s])
        self.lock = threading.Lock()
        run = h.run
        net = h.cfg.network
        conf = tp.session_config(mode="client", connect=[f"tcp/{net.host}:{net.port}"])
        pw = access.password(h.secrets, access.ROS2) if h.secrets else ""
        conf.insert_json5("transport/auth/usrpwd", json.dumps({"user": access.ROS2, "password": pw}))
        self.session = tp.open_session(conf)
        ids = [a.id for a in h.cfg.agents]
        self.subs = []
        for t in run_topics(h.cfg.ros2.namespace, ids):
            if t.inbound or t.kind not in kinds:
                continue
            cb = self._pose if (t.kind is Kind.POSE and t.agent == ids[0]) else self._any
            self.subs.append(self.session.declare_subscriber(t.key(h.cfg.ros2.domain_id), cb))
        self.messages = 0

        def on_clock(sample: Any) -> None:
            now = time.monotonic()
            m = decode(tp.payload(sample), run, ("clock",), ("done",))
            with self.lock:
                self.clock_at[round(m.t, 6)] = now

        self.clock_sub = h.session.declare_subscriber(tp.Keys(run).clock, on_clock)

    def _any(self, sample: Any) -> None:
        self.messages += 1

    def _pose(self, sample: Any) -> None:
        now = time.monotonic()
        data = tp.payload(sample)
        sec, nsec = np.frombuffer(data[4:12], dtype="<i4")[0], np.frombuffer(data[8:12], dtype="<u4")[0]
        with self.lock:
            self.pose_at.append((round(float(sec) + 1e-9 * float(nsec), 6), now))
        self.messages += 1

    def delays_ms(self) -> np.ndarray:
        with self.lock:
            return np.array([(a - self.clock_at[t]) * 1e3 for t, a in self.pose_at if t in self.clock_at])

    def close(self) -> None:
        self.clock_sub.undeclare()
        self.session.close()


VIEWS = {
    "all": tuple(Kind),
    "poses": (Kind.POSE, Kind.VELOCITY, Kind.TF, Kind.CLOCK),  # what rviz or a controller takes
}


def one(
    n: int, mode: str, rate_hz: float, seconds: float, ros2_rate: float, bridge: bool, out: Path, view: str
) -> dict:
    settings = SwapSettings(
        rotation_rad=0.05, control_hz=rate_hz, physics_hz=3 * rate_hz, duration_s=seconds, mode=mode
    )
    raw = circle_swap(n, max(2.0, 0.35 * n), settings, name=f"ros2_{n}_{mode}")
    raw["stop_when_all_reached"] = False
    raw["network"] = {"topology": "router"}
    raw["ros2"] = {"enabled": bridge, "rate_hz": ros2_rate}
    cfg = resolve(raw, raw["name"])
    h = RunHandle.start(cfg, out)
    participant = Participant(h, VIEWS[view]) if bridge else None
    try:
        h.wait_sim_time(2.0, timeout_s=300.0)
        t0, c0 = h.progress.t_s, {name: cpu_s(p.pid) for name, p in h.procs.items()}
        h.wait_sim_time(seconds - 1.0, timeout_s=300.0)
        t1, c1 = h.progress.t_s, {name: cpu_s(p.pid) for name, p in h.procs.items()}
        reason = h.wait()
    finally:
        if participant is not None:
            participant.close()
        if h.reason is None:
            h.finish("benchmark stopped")
    ticks = (t1 - t0) * rate_hz
    per_tick = {name: (c1[name] - c0[name]) * 1e6 / ticks for name in c1}
    swarm = sum(per_tick.values())
    delays = participant.delays_ms() if participant is not None else np.zeros(0)
    return {
        "agents": n,
        "mode": mode,
        "rate_hz": rate_hz,
        "bridge": bridge,
        "ros2_rate_hz": ros2_rate if bridge else None,
        "subscribed": view if bridge else None,
        "swarm_cpu_us_per_tick": round(swarm, 1),
        "bridge_cpu_us_per_tick": round(per_tick.get("ros2", 0.0), 1),
        "router_cpu_us_per_tick": round(per_tick.get("router", 0.0), 1),
        "world_cpu_us_per_tick": round(per_tick.get("world", 0.0), 1),
        "bridge_share": round(per_tick.get("ros2", 0.0) / swarm, 4) if bridge else None,
        "delay_ms_median": round(float(np.median(delays)), 2) if delays.size else None,
        "delay_ms_p99": round(float(np.percentile(delays, 99)), 2) if delays.size else None,
        "poses_matched": int(delays.size),
        "ros2_messages": participant.messages if participant is not None else 0,
        "span_s": round(t1 - t0, 2),
        "stop_reason": reason,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", type=int, default=16)
    ap.add_argument("--mode", default="realtime", choices=["realtime", "lockstep"])
    ap.add_argument("--rate", type=float, default=100.0, help="control rate [Hz]")
    ap.add_argument("--seconds", type=float, default=10.0, help="sim time of each run [s]")
    ap.add_argument("--pairs", type=int, default=2, help="ABBA: on, off, off, on, ... (2 pairs: 4 runs)")
    ap.add_argument("--ros2-rate", type=float, default=30.0, help="ros2.rate_hz of the bridge")
    ap.add_argument("--topics", default="all", choices=sorted(VIEWS), help="what the participant subscribes to")
    ap.add_argument("--out", type=Path, default=Path("runs/bench_ros2"))
    args = ap.parse_args()
    order = [True, False, False, True] * ((args.pairs + 1) // 2)
    rows: list[dict] = []
    for i, on in enumerate(order[: 2 * args.pairs]):
        row = one(
            args.agents,
            args.mode,
            args.rate,
            args.seconds,
            args.ros2_rate,
            on,
            args.out / f"{args.topics}_run{i}_{'on' if on else 'off'}",
            args.topics,
        )
        rows.append(row)
        if i % 2 == 1:  # a pair: one on, one off
            a, b = (rows[-2], rows[-1]) if rows[-2]["bridge"] else (rows[-1], rows[-2])
            row["pair_extra"] = round(a["swarm_cpu_us_per_tick"] / b["swarm_cpu_us_per_tick"] - 1.0, 4)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
