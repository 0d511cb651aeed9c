"""Benchmark of the world model's per-step costs (swarm.realism), printed as JSON lines.

    python -m tools.bench_realism [--agents 16,64] [--repeats 2000] [--preset crazyflie_lab]

One line per (part, agents) with ``median_us``, ``p99_us`` and ``per_second_ms`` (the cost of
one simulated second). ``part``: ``plant`` (one ``Plant.step``: motors, gusts, downwash, drag,
ground effect for every drone; ``--physics-hz`` calls a second), ``mocap`` (one
``MocapSensor.step``, captures at 100 Hz; ``--physics-hz``), ``estimator`` (one agent's
frame, estimate and command; ``--control-hz`` calls a second for every agent) or ``comms``
(the fates of every pair's state message of one tick, ``CommsModel.fate_matrix``;
``--control-hz``). Drones hover at random places, level; the gusts are per drone (the
costlier field).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

import numpy as np

from swarm.model import QuadParams
from swarm.realism.comms import MessageKind
from swarm.realism.settings import RealismSettings


def timed(fn: Callable[[], object], repeats: int) -> np.ndarray:
    fn()  # compile
    out = np.empty(repeats)
    for k in range(repeats):
        t0 = time.perf_counter()
        fn()
        out[k] = time.perf_counter() - t0
    return out * 1e6


def line(part: str, agents: int, us: np.ndarray, calls_per_s: float) -> dict[str, object]:
    return {
        "part": part,
        "agents": agents,
        "median_us": round(float(np.median(us)), 1),
        "p99_us": round(float(np.percentile(us, 99)), 1),
        "per_second_ms": round(float(np.mean(us)) * calls_per_s / 1e3, 2),
    }


def run(agents: list[int], repeats: int, preset: str, physics_hz: float, control_hz: float) -> None:
    r = RealismSettings.model_validate({"preset": preset, "wind": {"gust_field": "per_drone"}})
    for n in agents:
        for out in run_one(r, n, repeats, physics_hz, control_hz):
            print(json.dumps(out), flush=True)


def run_one(r: RealismSettings, n: int, repeats: int, physics_hz: float, control_hz: float) -> list[dict[str, object]]:
    p = QuadParams()
    rng = np.random.default_rng(n)
    x = rng.uniform(-1, 1, (n, 3)) * np.sqrt(n) * 0.3 + [0, 0, 1.5]
    v = rng.normal(0, 0.3, (n, 3))
    R = np.tile(np.eye(3), (n, 1, 1))
    q = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    f = np.full((n, 4), p.weight_N / 4) + rng.normal(0, 0.005, (n, 4))
    plant = r.plant([p] * n, 1 / physics_hz, seed=1)
    lines = [line("plant", n, timed(lambda: plant.step(x, v, R, f), repeats), physics_hz)]
    mocap = r.mocap(n, seed=1)
    clock = iter(range(10**9))
    lines.append(line("mocap", n, timed(lambda: mocap.step(next(clock) / physics_hz, x, q), repeats), physics_hz))
    est = r.estimator(x[0], q[0])
    one = r.mocap(1, 2)
    frames = [fr for k in range(round(physics_hz)) for fr in one.step(k / physics_hz, x[:1], q[:1])]
    ticks = iter(range(10**9))

    def tick() -> None:  # a frame, the estimate and the command, as at a control tick
        k = next(ticks)
        fr = frames[k % len(frames)]
        est.frame(fr._replace(seq=k, t_arrival_s=frames[0].t_arrival_s + k / control_hz))
        est.estimate((k + 0.5) / control_hz)
        est.command((k + 0.5) / control_hz, np.zeros(3))

    lines.append(line("estimator", n, timed(tick, repeats), control_hz * n))
    comms = r.comms_model(1, 1 / control_hz)
    ids = [f"cf{i}" for i in range(n)]
    k_tick = iter(range(10**9))
    us = timed(lambda: comms.fate_matrix(ids, MessageKind.STATE, next(k_tick)), repeats)
    lines.append(line("comms", n, us, control_hz))
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", default="16,64")
    ap.add_argument("--repeats", type=int, default=2000)
    ap.add_argument("--preset", default="crazyflie_lab")
    ap.add_argument("--physics-hz", type=float, default=240.0)
    ap.add_argument("--control-hz", type=float, default=120.0)
    args = ap.parse_args()
    run([int(a) for a in args.agents.split(",")], args.repeats, args.preset, args.physics_hz, args.control_hz)


if __name__ == "__main__":
    main()
