"""Delay-aware C3BF in real processes (docs/design.md, "Delay"): the imperfection sweep's 8-drone
circle with the motion capture and every state, bundle and command 150 ms late, flown by the world,
the relay and eight agent processes in lockstep: no contact, every drone home."""

from __future__ import annotations

import json

import pytest

from swarm.config import resolve
from tools.bench_imperfections import scene

pytestmark = pytest.mark.integration


def test_the_sweeps_circle_at_150_ms_on_every_link_flown_by_processes_touches_nothing_and_gets_home(start_run):
    cfg = resolve(scene("circle_8", "c3bf", "latency", 0.15))
    h = start_run(cfg, "late")
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["margin_violations"] == 0, m
    assert m["all_reached_goal"], {a: v["time_to_goal_s"] for a, v in m["agents"].items()}
    assert m["min_separation_m"] > 0.14  # the airframes' contact distance (2 x 0.07 m)
