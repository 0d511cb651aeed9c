"""Benchmark of one whole safety-filter call (row building plus QP), printed as JSON lines.

    python -m tools.bench_filter [--repeats 2000]

One line per (rows, backend, level) with ``median_us``, ``p99_us`` and ``max_violation``
(the largest row or bound violation of any returned OK command). Scenes are random but
seeded: a moving, tilted drone among moving spheres and cylinders within 3 m, with a
reference command from the path tracker, so that some rows are active in most calls.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from swarm.control import AttitudeController, PathTracker
from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.rotation import euler_to_quat
from swarm.safety.filter import FilterConfig, FilterStatus, SafetyFilter
from swarm.safety.obstacles import ObstacleArrays


def scenes(model: QuadModel, level: CommandLevel, rows: int, count: int, seed: int = 0) -> list:
    rng = np.random.default_rng(seed)
    att = AttitudeController(model)
    out = []
    for _ in range(count):
        s = QuadState(
            np.array([0.0, 0.0, 1.0]),
            np.array([1.0, 0.0, 0.0]) + rng.normal(0, 0.2, 3),
            euler_to_quat(float(rng.normal(0, 0.1)), float(rng.normal(0, 0.1)), 0.0),
            rng.normal(0, 0.5, 3),
        )
        d = rng.uniform(0.6, 3.0, rows)
        direction = rng.normal(size=(rows, 3)) + np.array([1.5, 0, 0])
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        obs = ObstacleArrays.build(
            s.x_w + d[:, None] * direction,
            rng.uniform(0.05, 0.3, rows),
            rng.normal(0, 0.5, (rows, 3)),
            axis_w=np.where(rng.random((rows, 1)) < 0.2, [0.0, 1.0, 0.0], 0.0),
        )
        F = PathTracker([[0, 0, 1.0], [6, 0, 1.0]], 1.0).thrust_vector(model, s.x_w, s.v_w)
        u_ref = att.from_thrust_vector(s, F) if level is CommandLevel.ROTORS else F
        out.append((s, u_ref, obs))
    return out


def run(repeats: int, out) -> None:
    model = QuadModel()
    for rows in (1, 5, 20, 100):
        for level in CommandLevel:
            cases = scenes(model, level, rows, 200)
            for backend in ("daqp", "osqp"):
                filt = SafetyFilter(model, FilterConfig(level=level, backend=backend, max_rows=128))
                times, worst, qp_calls = [], 0.0, 0
                for k in range(repeats):
                    s, u_ref, obs = cases[k % len(cases)]
                    t0 = time.perf_counter()
                    res = filt.filter(s, u_ref, obs)
                    times.append(time.perf_counter() - t0)
                    if res.status is FilterStatus.OK:
                        worst = max(worst, res.max_violation)
                    qp_calls += bool(res.active.any())
                us = np.array(times) * 1e6
                line = {
                    "rows": rows,
                    "backend": backend,
                    "level": level.value,
                    "median_us": round(float(np.median(us)), 1),
                    "p99_us": round(float(np.percentile(us, 99)), 1),
                    "max_violation": worst,
                    "active_fraction": round(qp_calls / repeats, 3),
                }
                print(json.dumps(line), file=out, flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=2000)
    args = ap.parse_args()
    # OSQP's C code prints "Polishing not needed ..." on stdout regardless of verbose:
    # keep stdout for the JSON lines only.
    out = os.fdopen(os.dup(sys.stdout.fileno()), "w")
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    run(args.repeats, out)


if __name__ == "__main__":
    main()
