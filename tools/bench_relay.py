"""What the bundle relay's own work costs per tick, without the links, printed as JSON lines:
the part of the relay's CPU that compiling its per-state work could lower (docs/benchmarks.md,
"Where the time goes").

    python -m tools.bench_relay [--agents 8,16,32] [--ticks 2000] [--modes lockstep,realtime]

The router's relay (:class:`swarm.runs.router.BundleRelay`, on a Zenoh session linked to no
one: each put goes nowhere, about 2.6 us) takes every agent's state of each tick of a
``circle_<n>`` swap, as the agents would send them, and sends the bundles that are then due.
The line gives the relay thread's CPU per tick (``cpu_us_per_tick``), per state taken
(``cpu_us_per_state``: the checks, the intake, the bundler), per bundle sent
(``cpu_us_per_bundle``: choosing who hears whom, encoding, the put), and the bundles sent.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np

from swarm.config import resolve
from swarm.net import statewire
from swarm.net import transport as tp
from swarm.offline.scenario import SwapSettings, circle_swap
from swarm.runs.router import BundleRelay

RUN = "bench"


def _states(n: int, ticks: int, mode: str) -> tuple[Any, list[list[tuple[str, bytes]]]]:
    """The scenario and, per tick, each agent's (key, state message) on its start circle."""
    settings = SwapSettings(control_hz=100.0, physics_hz=300.0, duration_s=ticks / 100.0, mode=mode)
    cfg = resolve(circle_swap(n, max(2.0, 0.35 * n), settings, name=f"bench_relay_{n}"))
    keys = tp.Keys(RUN)
    starts = np.array([a.start for a in cfg.agents], float)
    v = np.zeros(3)
    ticks_out = []
    for k in range(ticks):
        x = starts * (1.0 - 0.5 * k / ticks)  # (n, 3) m: towards the centre
        ticks_out.append([
            (keys.state(a.id), statewire.encode_state(RUN, a.id, k + 1, k * 0.01, k, x[i], v, 0.07, False))
            for i, a in enumerate(cfg.agents)
        ])  # fmt: skip
    return cfg, ticks_out


def bench(conf: Any, n: int, ticks: int, mode: str) -> dict[str, Any]:
    cfg, states = _states(n, ticks, mode)
    with tp.open_session(conf) as session:
        relay = BundleRelay(cfg, RUN, session)
        for a in cfg.agents:
            relay.bundler.set_live(a.id, True)
        take_s = send_s = 0.0
        for tick in states:
            t0 = time.thread_time()
            for key, data in tick:
                relay.take(key, data)
            t1 = time.thread_time()
            relay.send()
            take_s += t1 - t0
            send_s += time.thread_time() - t1
        sent, dropped = relay.sent, relay.counter.dropped
    return {
        "agents": n,
        "mode": mode,
        "ticks": ticks,
        "cpu_us_per_tick": round((take_s + send_s) / ticks * 1e6, 1),
        "cpu_us_per_state": round(take_s / (ticks * n) * 1e6, 2),
        "cpu_us_per_bundle": round(send_s / max(sent, 1) * 1e6, 2),
        "bundles": sent,
        "dropped": dropped,
    }


def main(conf: Any, agents: list[int], ticks: int, modes: list[str]) -> None:
    for mode in modes:
        for n in agents:
            print(json.dumps(bench(conf, n, ticks, mode)), flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", default="8,16,32")
    ap.add_argument("--ticks", type=int, default=2000)
    ap.add_argument("--modes", default="lockstep,realtime")
    args = ap.parse_args()
    main(
        tp.session_config(gossip=False, lowlatency=True),
        [int(a) for a in args.agents.split(",")],
        args.ticks,
        args.modes.split(","),
    )
