"""How long a run takes to start, with its processes forked from the fork server
(swarm.runs.forkserver) or each started from scratch (``SWARM_FORKSERVER=0``), printed as
JSON lines (docs/benchmarks.md, "Starting a run").

    python -m tools.bench_start [--agents 2,8,16] [--repeat 2] [--how cli,reuse]

Each sample is a lockstep circle swap of ``--agents`` drones flown for 0.2 s of sim time (so
the run is almost all start and finish), once forked and once from scratch, in the order
A B B A per repeat (this machine's speed drifts by the hour). ``cli`` times ``swarm run``
as a user starts it, one process per run, its fork server started with it; ``reuse`` times
:meth:`swarm.runs.launch.RunHandle.start` to the world's first status message, then the whole
run, in this one process, whose server serves every run after its first (a sweep's worker, the
tests). Keys: ``how``, ``agents``, ``forked``, ``wall_s`` (the whole run), ``first_status_s``
(``reuse`` only: from start to the world's first status), ``startup_cpu_s`` (the CPU the
run's agents, world and recorder spent before their first tick, summed; the server's own
imports not included).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from swarm.config import dump, resolve
from swarm.offline.scenario import circle_swap
from swarm.runs import forkserver
from tools.bench_swarm import summaries


def _config(n: int) -> Any:
    raw = circle_swap(n, max(2.0, 0.35 * n))
    raw["duration_s"] = 0.2
    return resolve(raw)


def _startup_cpu(out: Path) -> float:
    world, agents = summaries(out)
    return float(world.get("startup_cpu_s", 0.0)) + sum(float(a.get("startup_cpu_s", 0.0)) for a in agents)


def cli(n: int, forked: bool, out: Path) -> dict[str, Any]:
    cfg = out.with_suffix(".yaml")
    cfg.write_text(dump(_config(n)))
    env = dict(os.environ, **({} if forked else {forkserver.DISABLE_ENV: "0"}))
    t0 = time.monotonic()
    subprocess.run(
        [sys.executable, "-m", "swarm.cli", "run", str(cfg), "--out", str(out), "--no-progress"],
        env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    return {"wall_s": time.monotonic() - t0, "startup_cpu_s": _startup_cpu(out)}


def reuse(n: int, forked: bool, out: Path) -> dict[str, Any]:
    from swarm.runs.launch import RunHandle

    if forked:
        os.environ.pop(forkserver.DISABLE_ENV, None)
    else:
        os.environ[forkserver.DISABLE_ENV] = "0"
    t0 = time.monotonic()
    h = RunHandle.start(_config(n), out)
    first = None
    while (reason := h.poll(wait_s=0.05)) is None:
        if first is None and h.progress.status:
            first = time.monotonic() - t0
    if h.finish(reason) != "completed":
        raise RuntimeError(f"{n} agents: {h.reason}")
    return {"wall_s": time.monotonic() - t0, "first_status_s": first, "startup_cpu_s": _startup_cpu(out)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", default="2,8,16")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--how", default="cli,reuse")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench_start_"))
    try:
        for how in args.how.split(","):
            bench = {"cli": cli, "reuse": reuse}[how]
            if how == "reuse":
                bench(2, True, tmp / "warm-up")  # (the server's imports: its first run, not counted)
            for n in (int(x) for x in args.agents.split(",")):
                for r in range(args.repeat):
                    for forked in (True, False, False, True):
                        out = tmp / f"{how}_{n}_{r}_{int(forked)}_{time.monotonic_ns()}"
                        row = {"how": how, "agents": n, "forked": forked, **bench(n, forked, out)}
                        print(json.dumps(row), flush=True)
                        shutil.rmtree(out, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
