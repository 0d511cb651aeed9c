"""Scenes among walls flown as a user flies them: ``swarm scenario`` writes the scene, real
agent processes plan their paths round the walls and give way at the passage by what they hear
of each other over Zenoh, the world flies them in PyBullet."""

from __future__ import annotations

import json

import pytest

from swarm.config import resolve
from swarm.offline.scenario import corridor

pytestmark = pytest.mark.integration


@pytest.mark.parametrize("lanes", [True, False], ids=["lanes", "in_turn"])
def test_two_drones_of_opposite_flows_pass_in_the_corridor_s_lanes_or_take_it_in_turn(start_run, lanes):
    """One drone each way through a corridor two lanes wide: with lanes (the default) each flies
    its right-hand lane and they pass each other inside; with ``planner.lanes: false`` they take
    it in turn. Both arrive either way, without contact or a slip into the safety radius."""
    raw = corridor(1)
    raw["defaults"]["planner"] = {"lanes": lanes}
    h = start_run(resolve(raw), "corridor")
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["margin_violations"] == 0, m
    arrivals = sorted(a["time_to_goal_s"] for a in m["agents"].values())
    assert all(a["reached_goal"] for a in m["agents"].values()), m["agents"]
    if lanes:
        assert arrivals[1] - arrivals[0] < 0.5  # passed each other: neither waited
    else:
        assert arrivals[1] - arrivals[0] > 1.0  # in turn: the corridor (2 m) is not passed side by side
