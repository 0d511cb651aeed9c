"""Scenes among walls flown as a user flies them: ``swarm scenario`` writes the scene, real
agent processes plan their paths round the walls and give way at the passage by what they hear
of each other over Zenoh, the world flies them in PyBullet."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

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


def test_swarm_run_notes_agents_round_walls_at_a_gain_that_keeps_the_pillars_whole_cones(tmp_path):
    """A hand-written corridor at the config's default gain 1 and 0.8 m/s: ``swarm run`` says on
    stderr, once, which agents keep every pillar's whole cone and how to turn the obstacle horizon
    on, then flies the run (which agents get the note: test_planning)."""
    raw = corridor(1)
    raw["duration_s"] = 0.3
    del raw["defaults"]["filter"]["gamma"]  # the config's default, the paper's 1 (swarm scenario writes 2)
    path = tmp_path / "corridor.yaml"
    path.write_text(yaml.safe_dump(raw))
    p = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "run", str(path), "--out", str(tmp_path / "run"), "--no-progress"],
        capture_output=True, text=True, timeout=120, cwd=Path(__file__).resolve().parents[2],
    )  # fmt: skip
    assert p.returncode in (0, 1), p.stderr[-2000:]  # flown (0.3 s: nobody home yet)
    assert (tmp_path / "run" / "metrics.json").exists()
    notes = [ln for ln in p.stderr.splitlines() if ln.startswith("note: ")]
    assert len(notes) == 1 and notes[0].startswith("note: cf1, cf2 plan paths round walls"), p.stderr[-2000:]
    assert "filter.gamma to at least speed_mps / 0.4" in notes[0]
