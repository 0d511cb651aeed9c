"""Faults injected into real runs (issue 20): the recorder, the world or an agent killed or
stopped mid-run. A run's results survive any single process's death, stalls are loud, and
a dead agent's drone is counted apart from collisions among the live ones."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from swarm.offline.metrics import compute
from swarm.runs.runfiles import read_config, read_recording

from .conftest import scenario

BODY, MARGIN = 0.07, 0.02  # m: the Crazyflie's bounding radius and the filter's default margin

THREE = [
    {"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [4.0, 0.0, 1.0]},
    {"id": "cf2", "start": [4.0, 0.05, 1.0], "goal": [0.0, 0.05, 1.0]},
    {"id": "cf3", "start": [2.0, 1.5, 1.0], "goal": [2.0, -1.5, 1.0], "speed_mps": 0.5},
]


def _metrics(run_dir: Path) -> dict:
    return json.loads((run_dir / "metrics.json").read_text())


def _until(run_dir: Path, t_s: float) -> dict:
    """Metrics of what ``run_dir``'s recording holds up to sim time ``t_s``."""
    records = [r for r in read_recording(run_dir / "run.mcap").records if r["t"] <= t_s]
    return compute(read_config(run_dir), records)


def test_killed_recorder_leaves_incomplete_metrics_that_match_the_whole_run_so_far(start_run):
    cfg = scenario("swap_2.yaml", name="rec_kill", duration_s=8.0, agents=THREE)
    whole = start_run(cfg, "whole")
    assert whole.wait() == "completed"
    assert _metrics(whole.out)["complete"] is True

    h = start_run(cfg, "killed")
    h.wait_sim_time(3.0)
    h.kill("recorder", signal.SIGKILL)
    reason = h.wait()
    assert reason.startswith("recorder killed by SIGKILL at t = "), reason
    m = _metrics(h.out)
    assert m["complete"] is False and m["recording"]["complete"] is False, m["recording"]
    assert m["stop_reason"] == reason and "cut short" in m["recording"]["summary"]
    assert m["lost_agents"] == [], "the recorder's death is not an agent's"
    until = m["recording"]["recorded_until_s"]
    assert until is not None and until > 1.0, m["recording"]  # the recorder flushes every 0.5 s
    # lockstep: the same run, so what the cut file holds is the whole run's first part (the last
    # 0.1 s of the cut file may hold part of a tick: commands arrive after their clock)
    cut, ref = _until(h.out, until - 0.1), _until(whole.out, until - 0.1)
    for key in ("min_separation_m", "min_obstacle_clearance_m", "collisions", "duration_s"):
        assert cut[key] == ref[key], key
    for a in ("cf1", "cf2", "cf3"):
        for key in ("path_length_m", "min_h", "max_path_deviation_m"):
            assert cut["agents"][a][key] == ref["agents"][a][key], (a, key)

    # a file cut in the middle of a record: swarm metrics recovers what is whole and says so
    data = (whole.out / "run.mcap").read_bytes()
    (whole.out / "run.mcap").write_bytes(data[: len(data) // 2 + 7])
    p = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "metrics", str(whole.out)], capture_output=True, text=True, timeout=60
    )
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["complete"] is False and out["recording"]["bytes_unread"] > 0, out["recording"]
    assert out["stop_reason"] == "completed"  # kept from the metrics.json the run wrote
    assert 0 < out["recording"]["recorded_until_s"] < ref["duration_s"] + 8.0


def test_killed_world_ends_the_run_with_one_clear_line_and_metrics(start_run):
    cfg = scenario("swap_2.yaml", name="world_kill", duration_s=8.0, agents=THREE)
    h = start_run(cfg)
    h.wait_sim_time(2.0)
    h.kill("world", signal.SIGKILL)
    reason = h.wait()
    assert re.fullmatch(r"world killed by SIGKILL at t = [0-9.]+ s(: world: .*)?", reason), reason
    m = _metrics(h.out)
    assert m["complete"] is False and m["stop_reason"] == reason and m["exit_codes"]["world"] == -signal.SIGKILL
    assert m["duration_s"] >= 1.5 and m["collisions"] == 0
    assert all(p.poll() is not None for p in h.procs.values())


def test_a_stopped_agent_in_lockstep_is_a_loud_stall_and_the_run_goes_on(start_run):
    cfg = scenario(
        "swap_2.yaml",
        name="stall",
        duration_s=6.0,
        agents=THREE,
        time={"lockstep_timeout_s": 5.0, "stall_warn_fraction": 0.1},
    )
    h = start_run(cfg)
    h.wait_sim_time(1.0)
    h.kill("agent-cf3", signal.SIGSTOP)
    # the world says so while it waits: a stall line naming the agent it waits for
    log = h.out / "logs" / "world.log"
    seen = None
    for _ in range(200):
        seen = re.search(r"has waited [0-9.]+ s for \['cf3'\]", log.read_text())
        if seen or h.poll(wait_s=0.05):
            break
    assert seen, log.read_text()[-2000:]
    h.kill("agent-cf3", signal.SIGCONT)
    assert h.wait() == "completed"
    m = _metrics(h.out)
    assert m["stalls"] >= 1 and m["stall_events"][0]["agents"] == ["cf3"], m["stall_events"]
    assert m["stall_events"][0]["wait_s"] >= 0.5
    assert m["collisions"] == 0 and m["lost_agents"] == []
    assert re.search(r"tick \d+ stalled [0-9.]+ s on \['cf3'\]", log.read_text())


def test_a_dead_agents_falling_drone_is_counted_apart_from_collisions(start_run):
    cfg = scenario("swap_2.yaml", name="fall", duration_s=6.0, agents=THREE, failure={"on_agent_death": "motors_off"})
    h = start_run(cfg)
    h.wait_sim_time(1.0)
    h.kill("agent-cf3", signal.SIGKILL)
    assert h.wait() == "completed"
    m = _metrics(h.out)
    assert m["lost_agents"] == ["cf3"]
    assert m["collisions"] == 0, m["collision_pairs"]
    assert m["dead_agent_contacts"] >= 1 and m["dead_agent_contact_pairs"] == ["cf3|ground"], m
    assert m["agents"]["cf1"]["reached_goal"] and m["agents"]["cf2"]["reached_goal"]


def _streams(run_dir: Path) -> dict[str, int]:
    """Messages the recorder wrote per stream (the world's clocks, each agent's commands)."""
    return json.loads((run_dir / "recorder.json").read_text())["streams"]


def _stopped_for(h, name: str, wall_s: float) -> None:
    """SIGSTOP ``name`` for ``wall_s`` of wall time, then SIGCONT (the fault is the pause)."""
    h.kill(name, signal.SIGSTOP)
    try:
        time.sleep(wall_s)
    finally:
        h.kill(name, signal.SIGCONT)


@pytest.mark.parametrize("topology", ["router", "star"])
def test_a_stopped_world_or_recorder_delays_the_run_and_changes_nothing(start_run, topology):
    cfg = scenario("swap_2.yaml", name="pause", duration_s=8.0, agents=THREE, network={"topology": topology})
    clean = start_run(cfg, "clean")
    assert clean.wait() == "completed"
    ref = _metrics(clean.out)
    for name in ("world", "recorder"):
        h = start_run(cfg, f"{name}-stopped")
        h.wait_sim_time(2.0)
        _stopped_for(h, name, 1.0)
        assert h.wait() == "completed", name
        m = _metrics(h.out)
        assert m["complete"] is True and m["lost_agents"] == [] and m["collisions"] == 0, (name, m)
        # and the whole of it recorded: every clock and command of the clean run (a stopped world may
        # add a stall: it waited for the commands while it was stopped itself)
        assert m["lost_messages"] == 0 and _streams(h.out) == _streams(clean.out), name
        for a in ("cf1", "cf2", "cf3"):  # lockstep: the same flight, to the bit, and the whole of it recorded
            for key in ("path_length_m", "min_h", "time_to_goal_s"):
                assert m["agents"][a][key] == ref["agents"][a][key], (name, a, key)


def _kill_the_hoverer(start_run, name: str, on_lost: str) -> dict:
    """cf1 crosses through where ``hover`` holds station; ``hover`` dies at t = 1 s and the
    firmware keeps its drone there until 2.5 s after (its watchdog: the last setpoint,
    then levelled out, motors off at 2 s)."""
    cfg = scenario(
        "swap_2.yaml",
        name=name,
        duration_s=8.0,
        agents=[
            {"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [4.0, 0.0, 1.0]},
            {"id": "hover", "start": [2.0, 0.0, 1.0], "goal": [2.0, 0.0, 1.0]},
        ],
        failure={"on_agent_death": "firmware", "on_lost": on_lost},
        world={"realism": "ideal"},  # the held drone stays exactly on cf1's line (in the lab it drifts off it)
    )
    h = start_run(cfg, name)
    h.wait_sim_time(1.0)
    h.kill("agent-hover", signal.SIGKILL)
    assert h.wait() == "completed"
    return _metrics(h.out)


def test_a_dead_neighbour_on_the_path_is_kept_as_an_obstacle_and_avoided(start_run):
    m = _kill_the_hoverer(start_run, "kept", "keep_stopped")
    assert m["lost_agents"] == ["hover"]
    assert m["collisions"] == 0 and "cf1|hover" not in m["dead_agent_contact_pairs"], m  # (it falls: ground|hover)
    assert m["agents"]["cf1"]["reached_goal"]
    assert m["agents"]["cf1"]["max_path_deviation_m"] >= 2 * BODY + MARGIN - 0.02  # it went around the dead drone
    # the same with the dead neighbour dropped from the rows: cf1 flies into the drone the firmware holds there
    m = _kill_the_hoverer(start_run, "dropped", "drop")
    assert m["dead_agent_contacts"] >= 1 and "cf1|hover" in m["dead_agent_contact_pairs"], m


def test_an_agent_whose_world_never_comes_stops_by_itself(tmp_path):
    """An agent started alone (its launcher died before it started the world) gives up after
    ``time.start_timeout_s`` instead of waiting for ever."""
    from swarm.config import dump
    from swarm.runs.launch import ensure_secrets, free_port

    cfg = scenario("swap_2.yaml", time={"start_timeout_s": 2.0}, network={"port": free_port()})
    path = tmp_path / "config.yaml"
    path.write_text(dump(cfg))
    secrets = ensure_secrets(cfg, tmp_path / "secrets")
    args = ["agent", str(path), "--id", "cf1", "--run", "alone", "--port", str(cfg.network.port), "--secrets"]
    res = subprocess.run(
        [sys.executable, "-m", "swarm.cli", *args, str(secrets)], capture_output=True, text=True, timeout=120
    )
    assert "no world within time.start_timeout_s" in res.stderr, res.stderr
