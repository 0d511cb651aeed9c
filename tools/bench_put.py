"""What one Zenoh put costs its caller, printed as JSON lines: the floor under an agent's and the
relay's publishing (docs/benchmarks.md, "Where the time goes").

    python -m tools.bench_put [--puts 3000] [--payload 200] [--links 0,1,2,3] [--gap-us 1000]

A publisher session in this process links to ``links`` listener sessions, each a process of its
own with a subscriber on the key, as an agent links to a star's hubs (peer mode, gossip off, the
low-latency transport: ``swarm.net.transport.session_config``). It puts ``--puts`` messages of
``--payload`` bytes, one every ``--gap-us`` microseconds as an agent puts once per tick (the
listeners asleep between them), and the line gives the CPU the calling thread spends in a put
(``thread_cpu_us_median``, ``thread_cpu_us_mean``) and how long the put call takes
(``call_us_median``, ``call_us_p99``). Each listener reports how many it took; a line is printed only once every
listener has taken every put. With ``--no-lowlatency`` the links use Zenoh's default transport.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import time
from typing import Any

import numpy as np

from swarm.net import transport as tp

KEY = "bench/put"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def serve(port: int, puts: int, lowlatency: bool) -> None:
    """A listener: a subscriber on :data:`KEY` that says ``ready`` on stdout once it listens,
    and how many puts it took once it has ``puts`` of them or 120 s have passed (it sleeps
    between them, as a hub does)."""
    import threading

    import zenoh

    conf = tp.session_config(listen=[f"tcp/127.0.0.1:{port}"], gossip=False, lowlatency=lowlatency)
    got = [0]
    done = threading.Event()

    def take(_sample: Any) -> None:
        got[0] += 1
        if got[0] == puts:
            done.set()

    with zenoh.open(conf) as session:
        session.declare_subscriber(KEY, take)
        print("ready", flush=True)
        done.wait(120.0)
        print(f"took {got[0]}", flush=True)


def measure(links: int, puts: int, payload: int, gap_us: float, lowlatency: bool) -> dict:
    import zenoh

    ports = [_free_port() for _ in range(links)]
    me = [sys.executable, "-m", "tools.bench_put", "--puts", str(puts)]
    me += [] if lowlatency else ["--no-lowlatency"]
    procs = [
        subprocess.Popen([*me, "--serve", str(p)], stdout=subprocess.PIPE, text=True, start_new_session=True)
        for p in ports
    ]
    try:
        for p in procs:
            assert p.stdout is not None and p.stdout.readline().strip() == "ready", "a listener did not start"
        conf = tp.session_config(
            connect=[f"tcp/127.0.0.1:{p}" for p in ports], gossip=False, lowlatency=lowlatency, listen=[]
        )
        with zenoh.open(conf) as session:
            pub: Any = session.declare_publisher(KEY)  # (zenoh's stub types matching_status as a bool)
            deadline = time.monotonic() + 20.0
            while links and pub.matching_status.matching is False and time.monotonic() < deadline:
                time.sleep(0.01)  # (linked and the subscriptions known)
            data = os.urandom(payload)
            calls, cpu = np.empty(puts), np.empty(puts)
            for i in range(puts):
                c0, t0 = time.thread_time(), time.perf_counter()
                pub.put(data)
                calls[i], cpu[i] = time.perf_counter() - t0, time.thread_time() - c0
                end = t0 + gap_us * 1e-6
                while time.perf_counter() < end:
                    time.sleep(max(0.0, end - time.perf_counter()) * 0.8)
            took = []
            for p in procs:
                assert p.stdout is not None
                line = p.stdout.readline().strip()
                took.append(int(line.split()[1]) if line.startswith("took") else -1)
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    if any(t != puts for t in took):
        raise RuntimeError(f"listeners took {took} of {puts} puts")
    return {
        "links": links,
        "lowlatency": lowlatency,
        "payload_bytes": payload,
        "gap_us": gap_us,
        "puts": puts,
        "thread_cpu_us_median": round(float(np.median(cpu)) * 1e6, 1),
        "thread_cpu_us_mean": round(float(np.mean(cpu)) * 1e6, 1),
        "call_us_median": round(float(np.median(calls)) * 1e6, 1),
        "call_us_p99": round(float(np.percentile(calls, 99)) * 1e6, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--puts", type=int, default=3000)
    ap.add_argument("--payload", type=int, default=200, help="bytes per put (an agent's state is about 200)")
    ap.add_argument("--links", default="0,1,2,3", help="comma-separated numbers of listeners")
    ap.add_argument("--gap-us", type=float, default=1000.0, help="time from one put to the next")
    ap.add_argument("--no-lowlatency", dest="lowlatency", action="store_false")
    ap.add_argument("--serve", type=int, help=argparse.SUPPRESS)  # (a listener process)
    args = ap.parse_args()
    if args.serve is not None:
        serve(args.serve, args.puts, args.lowlatency)
        return
    for links in (int(x) for x in args.links.split(",")):
        print(json.dumps(measure(links, args.puts, args.payload, args.gap_us, args.lowlatency)), flush=True)


if __name__ == "__main__":
    main()
