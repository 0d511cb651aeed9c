"""One simulator: the offline loop (``swarm.offline.closed_loop.fly_scenario``) flies a scenario
as a lockstep run of its real processes (world, agents, bundle relay, recorder over Zenoh)
does, bit for bit. Every tick's centre of mass, attitude and velocity of every drone, as the
run's recorder stored the world's measurements, equals the offline loop's, and both runs end
on the same tick.

Why bit for bit holds: both build each agent with ``swarm.build`` (airframe, yaw, estimator,
neighbour table with its limits), fly the same plant (``swarm.sim.stepper.Stepper``: PyBullet,
``world.realism``'s plant, motion capture and command link, seeded alike), tick at ``t = k dt``
and hear the neighbours' states of tick k-1 of the agents the world names near; the wire carries
float64 values as they are. Scenes: the lab world's (``crazyflie_lab``) ``swap_2`` and
``circle_8``, a doorway for 4 in the lab world, and the 8-drone circle of the imperfections
sweep with motion capture and every message 75 ms late (its exact symmetry is where a
difference of one bit shows first)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from swarm.config import ScenarioConfig, load, resolve
from swarm.net.messages import measurement_agent
from swarm.offline.closed_loop import fly_scenario
from swarm.offline.scenario import SwapSettings, doorway
from swarm.runs.runfiles import read_records
from tools.bench_imperfections import scene

pytestmark = pytest.mark.integration

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _swap_2() -> ScenarioConfig:
    return load(CONFIGS / "swap_2.yaml")


def _circle_8() -> ScenarioConfig:
    return load(CONFIGS / "circle_8.yaml", {"duration_s": 8.0})


def _doorway_4() -> ScenarioConfig:
    raw = doorway(4, settings=SwapSettings(realism="crazyflie_lab"))
    raw["duration_s"] = 8.0
    return resolve(raw)


def _delayed_circle() -> ScenarioConfig:
    raw = scene("circle_8", "c3bf", "latency", 0.075, duration_s=6.0)
    return resolve(raw)


def _measured(run_dir: Path) -> dict[str, dict[int, np.ndarray]]:
    """Every recorded measurement (position, attitude, velocity) by agent and tick."""
    out: dict[str, dict[int, np.ndarray]] = {}
    for r in read_records(run_dir / "run.mcap"):
        if r["kind"] == "measurement":
            out.setdefault(measurement_agent(r), {})[r["k"]] = np.array([*r["x"], *r["q"], *r["v"]])
    return out


@pytest.mark.parametrize("make", [_swap_2, _circle_8, _doorway_4, _delayed_circle], ids=lambda f: f.__name__[1:])
def test_the_offline_loop_flies_what_the_processes_fly_bit_for_bit(make, start_run):
    cfg = make()
    log = fly_scenario(cfg)
    h = start_run(cfg)
    assert h.wait() == "completed"
    measured = _measured(h.out)
    names = [a.id for a in cfg.agents]
    assert set(measured) == set(names)
    ticks = len(log.t_s)
    assert ticks > 100
    for i, a in enumerate(names):
        got = measured[a]
        assert max(got) == ticks  # the run's last measurement: the tick the offline loop ended on
        for k in range(ticks):
            assert np.array_equal(got[k][:3], log.x_w[k, i]), (a, k)  # centre of mass [m], bit for bit
            assert np.array_equal(got[k][7:], log.v_w[k, i]), (a, k)  # velocity [m/s]
