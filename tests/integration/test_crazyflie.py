"""A real-Crazyflie agent against a stand-in drone, with no hardware.

The agent process is the real one (``swarm agent``): it starts its cflib link guard,
which talks CRTP over cflib's UDP driver to a stand-in (world/sitl_cf.py, not stepped: it
decodes, answers and records, and its firmware model judges). The
test plays the world: it declares the world's liveliness and publishes the clock and
the motion-capture measurements over Zenoh at 100 Hz. Every wait is on a condition
(packets at the stand-in, messages on the bus) with a deadline.
"""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from swarm.agents.crazyflie import thrust_command
from swarm.config import ScenarioConfig, dump, resolve
from swarm.net import transport as tp
from swarm.net.messages import decode, encode
from swarm.runs.launch import ensure_secrets, free_port
from swarm.world.sitl_cf import SitlDrone as StandIn

ROOT = Path(__file__).resolve().parents[2]


def real_config(uri: str, port: int, **cf: object) -> ScenarioConfig:
    # timeouts generous enough that a busy 2-core CI machine never trips them by accident
    raw = {
        "version": 1,
        "name": "cf_standin",
        "duration_s": 60.0,
        "time": {"mode": "realtime", "physics_hz": 200, "control_hz": 100},
        "network": {"port": port, "topology": "mesh"},
        "mocap": {"type": "mock"},  # the test plays the world
        "agents": [
            {
                "id": "cf1",
                "backend": "crazyflie",
                "start": [0.0, 0.0, 1.0],
                "goal": [1.0, 0.0, 1.0],
                "crazyflie": {"uri": uri, "mocap_timeout_s": 0.5, "link_timeout_s": 1.0, **cf},
            }
        ],
    }
    return resolve(raw)


class FakeWorld:
    """The world's side of one agent: liveliness, clock and measurements at 100 Hz."""

    def __init__(self, cfg: ScenarioConfig, run: str, secrets: Path) -> None:
        self.cfg, self.run, self.keys = cfg, run, tp.Keys(run)
        acc = tp.Access.of(cfg, run, tp.Role.WORLD, secrets)
        self.session = tp.open_session(tp.process_config(cfg, tp.Role.WORLD, acc))
        self.token = tp.declare_liveliness(self.session, self.keys.alive("world"))
        self.pub_meas = self.session.declare_publisher(self.keys.measurement("cf1"))
        self.pub_clock = self.session.declare_publisher(self.keys.clock)
        self.commands = tp.open_channel(self.session, self.keys.command("cf1"), 1 << 14)
        self.measuring = threading.Event()
        self.measuring.set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        k, seq, t0 = 0, 0, time.monotonic()
        while not self._stop.is_set():
            t = k * 0.01
            seq += 2
            self.pub_clock.put(
                encode(
                    "clock",
                    self.run,
                    "world",
                    seq,
                    t,
                    k,
                    live=["cf1"],
                    done=False,
                    ids=["cf1"],
                    xvr=[0, 0, 1.014, 0, 0, 0, 0.07],
                    meas_ids=[],
                    meas=[],
                    items=[],
                    solo=[],
                    frames=[],
                    skipped=0,
                )
            )
            if self.measuring.is_set():
                self.pub_meas.put(
                    encode(
                        "measurement",
                        self.run,
                        "world",
                        seq + 1,
                        t,
                        k,
                        x=[0.0, 0.0, 1.0],
                        v=[0.0, 0.0, 0.0],
                        q=[0.0, 0.0, 0.0, 1.0],
                        w=[0.0, 0.0, 0.0],
                    )
                )
            k += 1
            time.sleep(max(0.0, t0 + k * 0.01 - time.monotonic()))  # the 100 Hz capture clock

    def received_commands(self) -> list[np.ndarray]:
        out = []
        for s in tp.drain(self.commands):
            m = decode(tp.payload(s), self.run)
            out.append(np.asarray(m["u"]))
        return out

    def vanish(self) -> None:
        self.token.undeclare()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self.session.close()


@pytest.fixture
def rig(tmp_path):
    made: list = []

    def start(**cf: object) -> tuple[StandIn, FakeWorld, subprocess.Popen, ScenarioConfig]:
        standin = StandIn.start()
        cfg = real_config(standin.uri, free_port(), **cf)
        run = f"cf-{os.getpid()}-{len(made)}"
        path = tmp_path / f"cfg{len(made)}.yaml"
        path.write_text(dump(cfg))
        secrets = ensure_secrets(cfg, tmp_path / f"secrets{len(made)}")  # as `swarm secrets` writes them
        world = FakeWorld(cfg, run, secrets)
        log = open(tmp_path / f"agent{len(made)}.log", "wb")
        agent = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "swarm.cli",
                "agent",
                str(path),
                "--id",
                "cf1",
                "--run",
                run,
                "--port",
                str(cfg.network.port),
                "--secrets",
                str(secrets),
            ],
            cwd=ROOT,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        made.append((standin, world, agent, log))
        assert standin.wait_for("setpoints", 20, timeout_s=60.0), (tmp_path / f"agent{len(made) - 1}.log").read_text()
        return standin, world, agent, cfg

    yield start
    for standin, world, agent, log in made:
        if agent.poll() is None:
            os.killpg(agent.pid, signal.SIGKILL)
            agent.wait()
        world.close()
        standin.close()
        log.close()


def test_setpoints_at_the_drone_are_the_filtered_commands_and_a_lost_body_stops_it(rig):
    standin, world, agent, cfg = rig()
    assert standin.wait_for("poses", 5)
    commands = world.received_commands()
    assert len(commands) >= 5
    cal = cfg.agents[0].crazyflie.thrust
    sent = [(math.degrees(u[0]), math.degrees(u[1]), -math.degrees(u[2]), thrust_command(u[3], cal)) for u in commands]
    got = [(s.roll_deg, s.pitch_deg, s.yawrate_dps, s.thrust) for s in standin.setpoints]
    matched = [g for g in got[-10:] if any(np.allclose(g[:3], c[:3], atol=1e-4) and g[3] == c[3] for c in sent)]
    assert len(matched) == len(got[-10:]), (got[-3:], sent[-3:])
    assert any(abs(s.pitch_deg) > 0.5 for s in standin.setpoints)  # flying towards its goal, not just hovering
    assert all(10_000 < s.thrust < 60_000 for s in standin.setpoints[-10:])
    x, y, z = standin.poses[-1][:3]
    assert (x, y, z) == pytest.approx((0.0, 0.0, 1.0))  # the motion-capture pose went to the drone
    assert not standin.estops
    world.measuring.clear()  # the body disappears from motion capture
    assert standin.wait_for("estops", 1, timeout_s=10.0)


def test_link_loss_sends_an_emergency_stop(rig):
    standin, _world, agent, _cfg = rig()
    standin.deaf()  # the drone stops answering: to cflib the link is gone
    assert standin.wait_for("estops", 1, timeout_s=10.0)
    agent.wait(10)  # and the agent ends


def test_agent_death_sends_an_emergency_stop(rig):
    standin, _world, agent, _cfg = rig()
    os.kill(agent.pid, signal.SIGKILL)  # not even a chance to clean up: the guard does it
    assert standin.wait_for("estops", 1, timeout_s=10.0)


def test_world_gone_and_ctrl_c_send_an_emergency_stop(rig):
    standin, world, _agent, _cfg = rig()
    world.vanish()
    assert standin.wait_for("estops", 1, timeout_s=10.0)
    standin2, _world2, agent2, _cfg2 = rig()
    os.kill(agent2.pid, signal.SIGINT)
    assert standin2.wait_for("estops", 1, timeout_s=5.0)


def test_a_probe_is_not_a_client_the_stand_in_waits_for_one():
    """``swarm run`` probes each stand-in with a lone null packet (as cflib's UDP scan does)
    before the agents start, and an agent with a cold numba cache connects seconds later:
    the probe must not count as a client that has since gone silent (the stand-in then
    ended, and the agent found no drone). A packet of a client does count."""
    drone = StandIn.start()
    port = int(drone.uri.rsplit(":", 1)[1])
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.settimeout(2.0)
    try:
        probe.sendto(b"\xff", ("127.0.0.1", port))
        probe.recv(64)  # answered
        assert not drone.handed_back(time.monotonic() + 10.0)
        probe.sendto(bytes([0x90, 0x0C]), ("127.0.0.1", port))  # CMD_GET_STATE_BITFIELD (port 9, ch 0)
        assert probe.recv(64)[:2] == bytes([0x9C, 0x8C])
        assert drone.handed_back(time.monotonic() + 10.0)  # a client that has been silent 3 s is done
    finally:
        probe.close()
        drone.close()


def test_mixed_swarm_with_mock_motion_capture(tmp_path):
    """configs/mixed_mock.yaml: two real agents held by the mock capture system, flown
    through stand-ins; two simulated agents fly through their space and go around them."""
    from swarm.config import load
    from swarm.runs.launch import RunHandle
    from swarm.runs.runfiles import read_records

    stand = {"real1": StandIn.start(), "real2": StandIn.start()}
    try:
        # (this test is of the mock capture path and the real agents' rows: its simulated drones brake
        # when a command is late, as a stalled CI machine makes them, rather than meet the firmware's watchdog)
        cfg = load(ROOT / "configs" / "mixed_mock.yaml", {"time": {"late_command": "brake"}})
        agents = [
            a.model_copy(update={"crazyflie": a.crazyflie.model_copy(update={"uri": stand[a.id].uri})})
            if a.id in stand
            else a
            for a in cfg.agents
        ]
        h = RunHandle.start(cfg.model_copy(update={"agents": agents}), tmp_path / "mixed")
        reason = h.wait()
        m = __import__("json").loads((h.out / "metrics.json").read_text())
        assert reason == "completed", (reason, m.get("exit_codes"))
        assert m["collisions"] == 0, m["collision_pairs"]
        assert m["min_separation_m"] >= 2 * 0.07  # airframes never touched
        assert m["agents"]["sim1"]["reached_goal"] and m["agents"]["sim2"]["reached_goal"]
        assert m["min_obstacle_clearance_m"] > 0.07
        assert m["agents"]["sim1"]["max_path_deviation_m"] > 0.1  # it went around real1
        records = read_records(h.out / "run.mcap")
        # the simulated agents had the real ones as rows, through the same agent-state topics
        rows = {r["src"]: set() for r in records if r["kind"] == "command"}
        for r in records:
            if r["kind"] == "command":
                rows[r["src"]].update(r["row_ids"])
        assert "real1" in rows["sim1"] and "real2" in rows["sim2"] and "sim1" in rows["real1"]
        # the real drone avoids the virtual obstacle: its filter changes its command because of the ball
        assert "ball" in rows["real2"]
        assert max(r["intervention"] for r in records if r["kind"] == "command" and r["src"] == "real2") > 1e-3
        # every setpoint at a stand-in is one of that agent's recorded filtered commands (yaw
        # rate negated for the firmware), or the guard's own zero-thrust setpoint (the thrust
        # unlock, the keep-alive once the motors are off)
        cal = cfg.agents[0].crazyflie.thrust
        for aid, st in stand.items():
            sent = [
                (math.degrees(u[0]), math.degrees(u[1]), -math.degrees(u[2]), thrust_command(u[3], cal))
                for u in (r["u"] for r in records if r["kind"] == "command" and r["src"] == aid)
            ] + [(0.0, 0.0, 0.0, 0)]
            assert st.setpoints[0].thrust == 0  # the first setpoint unlocks the thrust (crtp_commander_rpyt.c)
            assert len(st.setpoints) > 100
            for s in st.setpoints[::10]:
                g = (s.roll_deg, s.pitch_deg, s.yawrate_dps, s.thrust)
                assert any(np.allclose(g[:3], c[:3], atol=1e-4) and g[3] == c[3] for c in sent), (aid, g)
            assert len(st.poses) > 100
    finally:
        for st in stand.values():
            st.close()


STALL_S = 2.5  # s of the wall clock the world is stopped for (SIGSTOP)


def test_a_world_starved_of_cpu_keeps_the_wall_clock_and_hides_no_real_drone(tmp_path):
    """configs/mixed_mock.yaml with the world stopped mid-run (at 1.5 s of its own time, for
    2.5 s of the wall clock), as a machine with more work than cores can starve it: whatever its
    speed, the world then finds itself that far behind. The real drones do not wait, and their
    measurements are stamped on the wall clock. A world that ran its backlog tick by tick fell
    further and further behind them: past 1 s (how far a neighbour's state may be ahead of the
    newest tick an agent has heard of, ``Plausible.ahead_s``) its simulated agents dropped the
    real drones' states as from ahead of the run, and flew into them. Now the world flies the
    ticks it lacks unpublished once it is ``time.max_lag_s`` behind, and goes on at the wall
    clock's tick: no state is dropped, no clock is missing from the recording."""
    from swarm.config import load
    from swarm.net.statewire import AHEAD
    from swarm.runs.launch import RunHandle

    stand = {"real1": StandIn.start(), "real2": StandIn.start()}
    try:
        # the real agents keep their drones through the starved spell (motion capture comes late);
        # by 8 s the simulated drones have passed them (real2 near 2 s, real1 near 4.5 s)
        cfg = load(ROOT / "configs" / "mixed_mock.yaml", {"duration_s": 8.0, "time": {"late_command": "brake"}})
        agents = [
            a.model_copy(
                update={"crazyflie": a.crazyflie.model_copy(update={"uri": stand[a.id].uri, "mocap_timeout_s": 2.0})}
            )
            if a.id in stand
            else a
            for a in cfg.agents
        ]
        h = RunHandle.start(cfg.model_copy(update={"agents": agents}), tmp_path / "starved")
        h.wait_sim_time(1.5)
        # the world stalled for 2.5 s of the wall clock, as a machine with more work than cores can
        # starve it: however fast this machine is, it then finds itself 2.5 s behind the real drones
        world = h.procs["world"].pid
        os.kill(world, signal.SIGSTOP)
        try:
            time.sleep(STALL_S)  # (the stall itself is the stimulus: nothing to wait for)
        finally:
            os.kill(world, signal.SIGCONT)
        reason = h.wait()
        m = __import__("json").loads((h.out / "metrics.json").read_text())
        assert reason == "completed", (reason, m.get("exit_codes"))
        ahead = {name: o for name, o in m["offenders"].items() if AHEAD in o["reasons"]}
        assert ahead == {}, ahead
        behind_ticks = (STALL_S - cfg.time.max_lag_s) * cfg.time.control_hz
        assert m["skipped_ticks"] >= 0.5 * behind_ticks, (m["skipped_ticks"], behind_ticks)
        assert m["recording_gaps"] == [] and m["complete"], m["recording_gaps"]
        assert m["collisions"] == 0 and m["min_separation_m"] >= 2 * 0.07, m["collision_pairs"]
        for sim in ("sim1", "sim2"):
            assert m["agents"][sim]["max_path_deviation_m"] > 0.1  # it went around the real drone
    finally:
        for st in stand.values():
            st.close()
