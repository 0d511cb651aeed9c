"""The imperfect world in real processes (``world.realism``, ``crazyflie_lab``): the world
flies the plant and publishes motion-capture frames, each agent acts on its own estimate, the
radio loses and delays commands; seeded, so a lockstep run still repeats bit for bit, and
``metrics.json`` reports what was applied and how far the estimates were from the truth."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from swarm.config import ScenarioConfig

from .conftest import scenario
from .test_determinism import positions

pytestmark = pytest.mark.integration


def _lab() -> ScenarioConfig:
    agents = [
        {"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [3.0, 0.0, 1.0]},
        {"id": "cf2", "start": [3.0, 0.05, 1.0], "goal": [0.0, 0.05, 1.0]},
        {"id": "cf3", "start": [1.5, 1.2, 1.0], "goal": [1.5, -1.2, 1.0], "speed_mps": 0.5},
    ]
    return scenario("swap_2.yaml", name="lab", duration_s=8.0, agents=agents, world={"realism": "crazyflie_lab"})


def test_a_lab_run_repeats_bit_for_bit_and_reports_what_the_world_did(start_run):
    runs = []
    for name in ("a", "b"):
        h = start_run(_lab(), name)
        assert h.wait() == "completed"
        runs.append(h.out)
    first, second = (positions(r) for r in runs)
    assert first.keys() == {"cf1", "cf2", "cf3"} and first == second  # every tick's true state, bit for bit
    m = json.loads((runs[0] / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["all_reached_goal"], m
    assert 0.0 < m["estimate_error_max_m"] < 0.02  # the agents acted on estimates, within 2 cm of the truth
    assert all(a["estimate_error_p95_m"] < 0.006 for a in m["agents"].values())
    applied = m["realism"]
    assert applied["preset"] == "crazyflie_lab" and applied["sensing"]
    world = _summary(runs[0] / "logs" / "world.log")
    assert applied["commands"]["lost"] == world["commands_lost"] > 0  # the metrics' fates are the world's
    assert world["mocap_frames_dropped"] > 0 and applied["states"]["lost"] == 0


def _summary(log: Path) -> dict:
    line = next(ln for ln in log.read_text().splitlines() if ln.startswith("WORLD_SUMMARY "))
    return json.loads(re.sub(r"^WORLD_SUMMARY ", "", line))
