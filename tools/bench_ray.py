"""The cost of ``swarm sweep --engine ray`` per run against the local pool, printed as JSON lines.

    python -m tools.bench_ray [--points 4] [--seconds 3] [--repeats 2]

Starts a one-node Ray cluster (``ray start --head``) with as many CPUs as one run of
``configs/sweeps/head_on.yaml`` needs (so both engines fly one run at a time), then flies the
same ``obstacle_speed`` sweep of ``--points`` points, cut to ``--seconds`` of sim time, with
``--engine local --jobs 1`` and ``--engine ray`` in turn, ``--repeats`` times. One line per
sweep: ``engine``, ``repeat``, ``runs``, ``wall_s``, ``wall_s_per_run``.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from swarm.config import load, resolve
from swarm.runs.ray_engine import cpus_needed
from swarm.runs.sweep import parse_axes, sweep

CONFIG = Path(__file__).resolve().parent.parent / "configs" / "sweeps" / "head_on.yaml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    raw = load(CONFIG).model_dump(mode="json")
    raw["duration_s"] = args.seconds
    axes = parse_axes([f"obstacle_speed={','.join(str(0.5 + 0.5 * i) for i in range(args.points))}"])
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    ray_bin = str(Path(sys.executable).with_name("ray"))
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")
    cpus = str(cpus_needed(resolve(raw)))
    subprocess.run(
        [ray_bin, "start", "--head", "--num-cpus", cpus, "--port", str(port), "--temp-dir", temp,
         "--include-dashboard", "false", "--disable-usage-stats"],
        check=True, capture_output=True,
    )  # fmt: skip
    try:
        for repeat in range(args.repeats):
            for engine in ("local", "ray"):
                out = Path(tempfile.mkdtemp()) / "sweep"
                t0 = time.monotonic()
                sweep(raw, axes, out, jobs=1, engine=engine, address=f"127.0.0.1:{port}")
                wall = time.monotonic() - t0
                line = {"engine": engine, "repeat": repeat, "runs": args.points, "wall_s": round(wall, 2)}
                print(json.dumps({**line, "wall_s_per_run": round(wall / args.points, 2)}), flush=True)
    finally:
        subprocess.run([ray_bin, "stop", "--force"], capture_output=True)


if __name__ == "__main__":
    main()
