"""Every process a run's messages go through, stopped in turn (SIGSTOP, as a busy laptop or a
slow disk stops one), in a star and in a mesh (issue 55; through a router:
``test_faults.test_a_stopped_world_or_recorder_delays_the_run_and_changes_nothing``): the
recording holds every message each process says it sent, and the swarm flies on safely.

The recorder is stopped last, while the world finishes the run: the end of the run then
waits in the links behind it (a star once lost it there)."""

from __future__ import annotations

import json
import signal
import time
from collections import Counter
from pathlib import Path

import pytest

from swarm.runs.runfiles import read_recording

from .conftest import scenario
from .test_faults import THREE


def _stopped_for(h, name: str, wall_s: float) -> None:
    """SIGSTOP ``name`` for ``wall_s`` of wall time, then SIGCONT (the fault is the pause)."""
    h.kill(name, signal.SIGSTOP)
    try:
        time.sleep(wall_s)
    finally:
        h.kill(name, signal.SIGCONT)


def _summaries(run_dir: Path) -> dict[str, dict]:
    """Each process's own summary line (``WORLD_SUMMARY`` / ``AGENT_SUMMARY``) from its log."""
    out = {}
    for path in (run_dir / "logs").glob("*.log"):
        for line in path.read_text(errors="replace").splitlines():
            tag, _, body = line.partition(" ")
            if tag in ("WORLD_SUMMARY", "AGENT_SUMMARY"):
                out[path.stem] = json.loads(body)
    return out


# the processes each topology's messages pass through, in the order they are stopped:
# an agent, the relay or router (which carries bundles, or everything), the world, the recorder
STOPPED = {
    "star": ("agent-cf3", "router", "world", "recorder"),
    "mesh": ("agent-cf3", "world", "recorder"),
}


# the star (the loopback default, where the end of a run was lost behind a stopped recorder) for a
# second and for three; the mesh (every put to the recorder blocks rather than drops) for three
@pytest.mark.parametrize(("topology", "stop_s"), [("star", 1.0), ("star", 3.0), ("mesh", 3.0)])
def test_every_hub_stopped_in_turn_loses_no_message(start_run, topology, stop_s):
    cfg = scenario("swap_2.yaml", name="stalls", duration_s=8.0, agents=THREE, network={"topology": topology})
    assert cfg.topology == topology
    h = start_run(cfg)
    for i, name in enumerate(STOPPED[topology]):
        h.wait_sim_time(1.0 + 1.2 * i)
        _stopped_for(h, name, stop_s)
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["complete"] is True, (m["recording"], m["recording_gaps"])
    assert m["recording_gaps"] == [] and m["lost_messages"] == 0
    assert json.loads((h.out / "recorder.json").read_text())["gaps"] == []
    # what each process says it sent, counted in the file by hand (not by the ledger)
    said = _summaries(h.out)
    records = [r for r in read_recording(h.out / "run.mcap").records if "topic" in r]
    held = Counter((r["src"], r["kind"]) for r in records)
    assert held["world", "clock"] == said["world"]["ticks"] + 1  # one clock per tick, 0 to the last
    assert sorted(r["k"] for r in records if r["kind"] == "clock") == list(range(said["world"]["ticks"] + 1))
    for a in ("cf1", "cf2", "cf3"):
        assert held[a, "command"] == said[f"agent-{a}"]["ticks"], a
    # and the swarm flew on: no contact, nobody lost, everyone home
    assert m["collisions"] == 0 and m["margin_violations"] == 0 and m["lost_agents"] == []
    assert m["all_reached_goal"], {a: v["reached_goal"] for a, v in m["agents"].items()}
