"""The real-drone path closed through cflib against software-in-the-loop Crazyflies that
apply the firmware's rules (world/sitl_cf.py): a sign or scale error of the client shows
as a drone that drifts, turns away, falls or never spins up. Realtime, as real drones fly."""

from __future__ import annotations

import json
import re
import signal
import time

import numpy as np

from swarm.net.messages import measurement_agent
from swarm.rotation import R_to_euler, quat_to_R
from swarm.runs.runfiles import read_records

from .conftest import scenario

REAL = ("real1", "real2")


def _track(run_dir, agent: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t [s], x (T, 3) [m], yaw (T,) [rad]) of an agent's measurements, in time order."""
    recs = sorted(
        (r for r in read_records(run_dir / "run.mcap") if r["kind"] == "measurement" and measurement_agent(r) == agent),
        key=lambda r: r["t"],
    )
    yaw = [R_to_euler(quat_to_R(np.asarray(r["q"])))[2] for r in recs]
    return np.array([r["t"] for r in recs]), np.array([r["x"] for r in recs]), np.array(yaw)


def _sitl_events(run_dir) -> dict[str, tuple[str, list]]:
    """What the stand-ins said at the end: per drone its last supervisor state and events."""
    out = {}
    for line in (run_dir / "logs" / "sitl.log").read_text().splitlines():
        m = re.match(r"sitl: (\w+) ended (\w+); supervisor events (.*)$", line)
        if m:
            out[m[1]] = (m[2], eval(m[3]))  # a list of (monotonic s, state) tuples it printed
    return out


def _world_summary(run_dir) -> dict:
    line = next(x for x in (run_dir / "logs" / "world.log").read_text().splitlines() if x.startswith("WORLD_SUMMARY "))
    return json.loads(line.split(" ", 1)[1])


def test_sitl_drones_take_off_hold_height_and_yaw_let_the_others_pass_and_land(start_run):
    # (the simulated drones brake on a late command: a stalled CI machine is not what this tests)
    cfg = scenario("mixed_sitl.yaml", duration_s=12.0, stop_when_all_reached=False, time={"late_command": "brake"})
    h = start_run(cfg, "sitl")
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["min_separation_m"] >= 2 * 0.07 + 0.02 - 3e-3
    assert m["agents"]["sim1"]["reached_goal"] and m["agents"]["sim2"]["reached_goal"]
    crossed = max(m["agents"][s]["time_to_goal_s"] for s in ("sim1", "sim2"))  # the simulated drones are through
    for name in REAL:
        t, x, yaw = _track(h.out, name)
        assert x[0, 2] < 0.05  # it started on the ground
        up = np.flatnonzero(np.abs(x[:, 2] - 1.0) < 0.03)
        assert up.size, f"{name} never reached its height: highest {x[:, 2].max():.3f} m"
        # hovering: from 1.5 s after the simulated drones are through (while one passes close both yield,
        # as rho = 1 asks, and it takes a second to come back) to the landing
        held = (t > max(t[up[0]] + 2.5, crossed + 1.5)) & (t < cfg.duration_s)
        assert held.sum() > 200 and np.abs(x[held, 2] - 1.0).max() < 0.03  # within 3 cm of its height target
        # it climbs while the simulated drones close in, and rises to let one pass (both yield at rho = 1):
        # by less than 15 cm above its height (a wrong thrust map overshoots by far more, or never gets there)
        assert x[t < cfg.duration_s, 2].max() < 1.15
        assert abs(np.degrees(yaw[0])) > 15.0  # it started 20 degrees off
        assert np.abs(np.degrees(yaw[held])).max() < 3.0  # and turned to its yaw, not away from it
        assert x[-1, 2] < 0.1  # landed
    ends = _sitl_events(h.out)
    assert {n: ends[n][0] for n in REAL} == {"real1": "landed", "real2": "landed"}  # not locked: reusable
    # the real drones' commands answer motion-capture frames stamped on the wall clock, which runs ahead
    # of a late world's ticks: the world records them all (their status makes a drone solo) and drops none
    world = _world_summary(h.out)
    assert not any(r.startswith("command for a tick") for r in world["dropped_reasons"]), world["dropped_reasons"]


def test_a_drone_that_does_not_answer_fails_the_run_in_seconds_naming_it(start_run):
    cfg = scenario("mixed_mock.yaml")
    silent = next(a for a in cfg.agents if a.crazyflie is not None)
    t0 = time.monotonic()
    h = start_run(cfg, "silent")  # nothing listens at the stand-ins' ports
    reason = h.wait()
    assert time.monotonic() - t0 < 20.0
    assert reason.startswith("agent-") and "not reached" in reason and silent.crazyflie.uri in reason, reason


def test_a_simulated_drone_whose_agent_dies_meets_the_firmware_watchdog(start_run):
    """on_agent_death: firmware: the world flies the dead agent's Crazyflie as its firmware
    would with no setpoints: the last setpoint, level from 500 ms with its thrust, motors off
    from 2 s (supervisor.c); then it falls."""
    cfg = scenario(
        "swap_2.yaml",
        name="fw_death",
        duration_s=8.0,
        stop_when_all_reached=False,
        failure={"on_agent_death": "firmware"},
        agents=[
            {"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [4.0, 0.0, 1.0]},
            {"id": "cf3", "start": [2.0, 3.0, 1.5], "goal": [2.0, 2.0, 1.5], "speed_mps": 0.3},
        ],
    )
    h = start_run(cfg, "fw")
    h.wait_sim_time(1.0)
    h.kill("agent-cf3", signal.SIGKILL)
    assert h.wait() == "completed"
    records = read_records(h.out / "run.mcap")
    last_cmd = max(r["t"] for r in records if r["kind"] == "command" and r["src"] == "cf3")
    clocks = sorted((r for r in records if r["kind"] == "clock"), key=lambda r: r["t"])
    t = np.array([r["t"] for r in clocks])  # the roster holds every drone, a dead agent's too
    zs = np.array([np.asarray(r["xvr"]).reshape(-1, 7)[r["ids"].index("cf3"), 2] for r in clocks])
    z = lambda at: float(np.interp(at, t, zs))
    assert abs(z(last_cmd + 1.9) - z(last_cmd)) < 0.15  # held up by its last thrust, levelled out
    assert z(last_cmd + 2.0) - z(last_cmd + 2.6) > 0.8  # motors off at 2 s: it falls (g t^2 / 2 = 1.8 m)
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["lost_agents"] == ["cf3"] and m["agents"]["cf1"]["reached_goal"]
