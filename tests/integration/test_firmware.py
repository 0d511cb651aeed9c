"""The real-drone path against the Crazyflie firmware itself: CrazySim's cf2 (the firmware's
commander, supervisor, Kalman estimator and PID controller), one process per drone, run by
swarm.world.sitl_fw, which flies its body from its motor commands, feeds it its IMU at 1 kHz,
relays cflib to it and logs what the firmware says (its supervisor's bits, the setpoint it
flies, its estimate). Nothing here is our reading of the firmware: the states, timings and
decoded setpoints are the firmware's own log. Realtime, as real drones fly.

The ``cf2`` fixture (conftest.py) builds the firmware once, or skips where it cannot (a
user's machine without ../shared); in CI (C3SWARM_CI) it fails instead."""

from __future__ import annotations

import json
import math
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from swarm.config import ScenarioConfig
from swarm.crazyflie_fw import CRAZYSIM
from swarm.rotation import R_to_euler, quat_to_R
from swarm.world.fw_trace import FirmwareTrace, read_trace

from .conftest import scenario

ROOT = Path(__file__).resolve().parents[2]
REAL = ("real1", "real2")
WEIGHT_N = CRAZYSIM.mass_kg * 9.81
POSE_LAG_S = 0.3  # how late an external pose may reach a firmware drone on a busy machine


WARM = """
from swarm.agents.agent import AgentProcess
from swarm.config import load
from swarm.world.main import World
cfg = load("configs/mixed_firmware.yaml")
World(cfg, "warm").warm_up()
AgentProcess(cfg, "real1", "warm"), AgentProcess(cfg, "sim1", "warm")
"""


@pytest.fixture(scope="module")
def warm_kernels() -> None:
    """numba's cache of the world's and the agents' kernels, filled before a firmware flies: a
    firmware drone takes off as soon as its agent is up, and agents compiling beside it (a cold
    cache, after an edit) would starve its agent past the firmware's 500 ms watchdog."""
    subprocess.run([sys.executable, "-c", WARM], cwd=ROOT, check=True, timeout=600, capture_output=True)


def _firmware_scenario(cf2: Path, **over: object) -> ScenarioConfig:
    """configs/mixed_firmware.yaml (14 s) with the test's firmware, run to its end (the simulated
    drones brake on a late command: a stalled CI machine is not what this tests)."""
    base: dict[str, object] = {
        "stop_when_all_reached": False,
        "time": {"late_command": "brake", "start_timeout_s": 120.0},
        "mocap": {"options": {"cf2": str(cf2)}},
    }
    return scenario("mixed_firmware.yaml", **{**base, **over})


def _log_tails(out: Path, lines: int = 12) -> dict[str, list[str]]:
    """The last lines of the real drones' agents' logs and of the firmware relay's (what a failure
    shows: a link error, a guard's stop)."""
    logs = [out / "logs" / f"agent-{name}.log" for name in REAL] + sorted((out / "logs").glob("*sitl*.log"))
    return {p.name: p.read_text(errors="replace").splitlines()[-lines:] for p in logs if p.exists()}


def _trace(out: Path, name: str) -> FirmwareTrace:
    return read_trace(out / "firmware" / f"{name}.jsonl")


def _first(t: np.ndarray, mask: np.ndarray, after: float) -> float:
    """The first time in ``t`` after ``after`` where ``mask`` holds (nan: never)."""
    hit = np.flatnonzero(mask & (t > after))
    return float(t[hit[0]]) if hit.size else math.nan


def test_firmware_drones_take_off_hold_let_the_others_cross_and_land(start_run, cf2, warm_kernels):
    """real1's agent has the simulated motors' own thrust map; real2's the 2026.04 release's linear
    one, which those motors do not follow (0.2627 N made for a hover's 0.2662 N meant). Each agent
    estimates its drone's disturbance once it has taken off, so both hold their heights (without
    the estimate real2 held 8-9 mm low).

    Each simulated drone's path runs through a firmware drone's hold, and both filter: on a busy
    machine the world falls behind the wall clock, and the simulated drones' safety monitors hold
    them while it is more than 0.1 s late (swarm.safety.monitor, world_late), so the firmware drone
    does the avoiding (up to 0.43 m above its hold, back at about 0.2 m/s) round drones that stay
    put; the crossing ended up to 16 s in. So the run is 24 s: the crossing must end by 19 s, and
    the hold is measured over the 1.5 s before the landing."""
    agents = yaml.safe_load((ROOT / "configs" / "mixed_firmware.yaml").read_text())["agents"]
    for a in agents:
        if a["id"] == "real2":
            a["crazyflie"]["thrust"] = {"firmware": "2026.04"}
    cfg = _firmware_scenario(cf2, agents=agents, duration_s=24.0)
    h = start_run(cfg, "fw")
    assert h.wait() == "completed", h.result
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["min_separation_m"] >= 2 * 0.07, (m["collision_pairs"], _log_tails(h.out))
    assert m["agents"]["sim1"]["reached_goal"] and m["agents"]["sim2"]["reached_goal"]
    crossed = max(m["agents"][s]["time_to_goal_s"] for s in ("sim1", "sim2"))
    cal = cfg.agents[0].crazyflie.thrust.map  # real1's calibration: the simulated motors' own map
    assert cfg.agents[1].crazyflie.thrust.map != cal
    for name in REAL:
        tr = _trace(h.out, name)
        # the link guard polls every 50 ms (cf_guard.POLL_S), not as fast as the relay answers
        span_s = tr.body_t[-1] - tr.body_t[0]
        assert 0 < tr.end["echoes_answered"] <= span_s / 0.05 + 10, (name, tr.end["echoes_answered"], span_s)
        t0 = tr.sp_t[0]  # the guard's first setpoint: the drone is in the run
        t, x = tr.body_t - t0, tr.body_x
        yaw = np.degrees([R_to_euler(quat_to_R(q))[2] for q in tr.body_q])
        assert x[0, 2] == 0.0 and abs(yaw[0] - 20.0) < 1e-6  # on the floor, turned 20 degrees off
        up = np.flatnonzero(np.abs(x[:, 2] - 1.0) < 0.03)
        assert up.size, f"{name} never reached its height: highest {x[:, 2].max():.3f} m"
        # the hold's last 1.5 s before the landing (the simulated drones are through by then: crossed)
        end = t[np.flatnonzero(x[:, 2] > 0.9)[-1]] - 0.5
        held = (t > end - 1.5) & (t < end)
        assert held.sum() > 100 and crossed < cfg.duration_s - 5.0, (name, held.sum(), crossed)
        z = x[held, 2]
        # within 2.5 cm, 1 cm on average: the issue's own measurement against this firmware held 1-2.4 cm
        assert np.abs(z - 1.0).max() < 0.025 and abs(z.mean() - 1.0) < 0.01, (name, z.min(), z.max(), z.mean())
        assert np.abs(yaw[held]).max() < 1.0  # it turned to its yaw
        assert x[-1, 2] == 0.0  # landed, on the floor
        # straight down, also after a world that ended behind the wall clock (its poses' stamps
        # go on without a jump: swarm.world.main.mocap_stamp)
        landing = t > end
        start = np.asarray(cfg.agent(name).start[:2])
        assert np.hypot(*(x[landing, :2] - start).T).max() < 0.05, (name, np.hypot(*(x[landing, :2] - start).T).max())
        # the thrust it made (its motors' PWM through their map) against the thrust meant (the setpoints')
        made = tr.body_thrust_N[held].mean()
        in_hold = (tr.sp_t - t0 > t[held][0]) & (tr.sp_t - t0 < t[held][-1])
        meant = np.mean([cal.collective_N(c) for c in tr.sp[in_hold, 3]])
        assert abs(made / WEIGHT_N - 1.0) < 0.01, (made, meant)
        if name == "real1":  # real2's map asks for more than its motors make: its estimate makes up the rest
            assert abs(made / meant - 1.0) < 0.01, (made, meant)
        # the setpoints it logs decode as sent: roll, pitch as on the wire, yaw rate negated, thrust
        sent = {(r, p, -y, float(c)) for r, p, y, c in tr.sp}
        flying = np.array([s == "flying" for s in tr.fw_state])
        logged = [tuple(v) for v in tr.fw_setpoint[flying]]
        exact = sum(any(all(abs(a - b) <= 1e-4 * max(1.0, abs(b)) for a, b in zip(v, s, strict=True))
                        for s in sent) for v in logged[::5])  # fmt: skip
        assert exact >= 0.9 * len(logged[::5]), (exact, len(logged[::5]))
        # its estimate (Kalman, fed the motion capture as an external pose) follows the body
        # while the agent flies it (from its first thrust and pose to its last thrust: after that
        # no pose comes): each sample against the nearest of the body's positions in the
        # POSE_LAG_S before it. The poses reach it through the world, the agent and the guard,
        # late by what a busy machine makes of that chain (gaps of 0.1-0.2 s in a CI run, where
        # the newest pose relayed was 2.8 cm p95 from the estimate and the body's path 1.3 cm).
        thrust_t = tr.sp_t[tr.sp[:, 3] > 0]
        posed = (tr.fw_t > max(thrust_t[0], tr.pose_t[0]) + 0.1) & (tr.fw_t < thrust_t[-1])
        lo = np.searchsorted(tr.body_t, tr.fw_t[posed] - POSE_LAG_S)
        hi = np.maximum(np.searchsorted(tr.body_t, tr.fw_t[posed], side="right"), lo + 1)
        err = np.array([np.linalg.norm(x[i0:i1] - est, axis=1).min()
                        for i0, i1, est in zip(lo, hi, tr.fw_estimate[posed], strict=True)])  # fmt: skip
        assert np.median(err) < 0.005 and np.percentile(err, 95) < 0.02, (np.median(err), np.percentile(err, 95))
        at_pose = np.column_stack([np.interp(tr.pose_t, tr.body_t, x[:, i]) for i in range(3)])
        assert np.median(np.linalg.norm(tr.pose_x - at_pose, axis=1)) < 0.01  # the poses are the body's
        # the supervisor's view: ready, flying, and ready again (landed), never locked
        states = [s for _, s in tr.transitions()]
        assert states[-1] == "ready" and "flying" in states and "locked" not in states, states
        assert [w for _, w in tr.packets if w.startswith("estop")] == []  # the link guard never stopped it
        assert "notify_stop" in [w for _, w in tr.packets]  # and handed it back (crtp_commander.c channel 1)


def test_the_firmware_locks_after_an_emergency_stop_and_its_watchdog_after_the_guard_falls_silent(
    start_run, cf2, warm_kernels
):
    """Both agents killed mid-flight: real1's guard sends the emergency stop (both forms, the
    localization packet is the one this firmware knows): locked at once. real2's guard goes silent
    (on_agent_loss: watchdog): the firmware levels it out 500 ms after its last setpoint and
    locks it at 2 s (supervisor.c COMMANDER_WDT_TIMEOUT_STABILIZE, _SHUTDOWN)."""
    agents = [
        {"id": "real1", "type": "real", "start": [1.0, 0.3, 1.0], "goal": [1.0, 0.3, 1.0],
         "crazyflie": {"uri": "udp://127.0.0.1:19850"}},
        {"id": "real2", "type": "real", "start": [-1.0, -0.3, 1.0], "goal": [-1.0, -0.3, 1.0],
         "crazyflie": {"uri": "udp://127.0.0.1:19851", "on_agent_loss": "watchdog"}},
        {"id": "sim1", "start": [-2.5, 0.3, 1.0], "goal": [2.5, 0.3, 1.0]},
    ]  # fmt: skip
    cfg = _firmware_scenario(cf2, agents=agents, duration_s=10.0)
    h = start_run(cfg, "faults")
    h.wait_sim_time(6.0)  # up and holding
    h.kill("agent-real1", signal.SIGKILL)
    h.kill("agent-real2", signal.SIGKILL)
    assert h.wait() == "completed", h.result

    tr = _trace(h.out, "real1")
    estops = [t for t, w in tr.packets if w.startswith("estop")]
    forms = [w for _, w in tr.packets if w.startswith("estop")]
    assert forms.count("estop") == 3 and forms.count("estop_supervisor_port") == 3, forms  # both, three times,
    assert estops[-1] - estops[0] > 0.09, estops  # 50 ms apart (one busy spell of the firmware drops not all)
    states = tr.transitions()
    locked = next(t for t, s in states if s == "locked")
    assert 0.0 < locked - estops[0] < 0.2, (locked - estops[0], states)
    assert states[-1][1] == "locked"
    after = tr.body_t > locked + 0.05
    assert tr.body_pwm[after].max() == 0.0 and tr.body_x[-1, 2] == 0.0  # motors off: it fell
    assert tr.body_thrust_N[tr.body_t > locked + 0.15].max() < 0.01 * WEIGHT_N  # (the rotors spun down)

    tr = _trace(h.out, "real2")
    assert not [w for _, w in tr.packets if w.startswith("estop")]
    last_sp = tr.sp_t[-1]
    st = np.array(tr.fw_state)
    zeroed = (tr.fw_setpoint[:, :3] == 0.0).all(axis=1) & (tr.fw_setpoint[:, 3] > 0)  # its log: attitude zeroed,
    level = _first(tr.fw_t, zeroed, last_sp) - last_sp  # thrust kept (supervisorOverrideSetpoint)
    locked = _first(tr.fw_t, st == "locked", last_sp) - last_sp
    # on the firmware's own clock (its log's timestamps: a busy machine slows it against the wall
    # clock): its rules (0.5 s, 2 s) to within its supervisor's 25 Hz, the log's 100 Hz and the
    # last setpoint's way through the relay's queue
    on_fw = np.interp([last_sp, last_sp + level, last_sp + locked], tr.fw_t, tr.fw_clock_s)
    level_fw, locked_fw = on_fw[1] - on_fw[0], on_fw[2] - on_fw[0]
    assert 0.45 < level_fw < 0.65 and 1.95 < locked_fw < 2.2, (level_fw, locked_fw, level, locked, tr.transitions())
    assert level < 1.0 and locked < 4.0, (level, locked)  # (and the wall clock not far off)
    between = (tr.body_t > last_sp + level + 0.05) & (tr.body_t < last_sp + locked - 0.05)
    assert tr.body_thrust_N[between].min() > 0.8 * WEIGHT_N  # levelled out with its thrust kept
    assert tr.body_pwm[tr.body_t > last_sp + locked + 0.05].max() == 0.0 and tr.body_x[-1, 2] == 0.0
    assert tr.transitions()[-1][1] == "locked"


PORT = 19857  # in cflib's UDP scan range (19850-19859), apart from the other tests' ports


def swarm_cf(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "swarm.cli", "cf", *args], capture_output=True, text=True, timeout=90, env=env
    )


def _relay(cf2: Path, out: Path) -> subprocess.Popen[bytes]:
    """One firmware drone on the floor at udp://127.0.0.1:PORT (swarm.world.sitl_fw)."""
    return subprocess.Popen(
        [sys.executable, "-m", "swarm.world.sitl_fw", "--cf2", str(cf2), "--mocap-port", "0",
         "--drone", f"cfA,{PORT},0,0,0,0", "--telemetry", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True,
    )  # fmt: skip


def _wait_ready(relay: subprocess.Popen[bytes], timeout_s: float = 60.0) -> float:
    """Until the drone answers a scan probe (it does once its firmware is calibrated and logged);
    returns how long that took [s]."""
    t0 = time.monotonic()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.settimeout(0.1)
        while True:
            assert relay.poll() is None, relay.stdout.read().decode() if relay.stdout else ""
            assert time.monotonic() - t0 < timeout_s, "the firmware drone never became ready"
            probe.sendto(b"\xff", ("127.0.0.1", PORT))
            try:
                probe.recv(64)
                return time.monotonic() - t0
            except TimeoutError:
                continue


def _stop(relay: subprocess.Popen[bytes]) -> None:
    if relay.poll() is not None:
        return
    os.killpg(relay.pid, signal.SIGTERM)
    try:
        relay.wait(10)
    except subprocess.TimeoutExpired:
        os.killpg(relay.pid, signal.SIGKILL)
        relay.wait()


@pytest.fixture
def firmware_drone(cf2, tmp_path):
    """One firmware drone on the floor at udp://127.0.0.1:PORT, ready."""
    relay = _relay(cf2, tmp_path / "firmware")
    try:
        _wait_ready(relay)
        yield f"udp://127.0.0.1:{PORT}", tmp_path, relay
    finally:
        _stop(relay)


def test_a_firmware_that_stalls_at_boot_is_restarted(cf2, tmp_path):
    """A firmware stopped after its hello, before it has its gyro bias (as a few boots in a hundred
    of this build stalls on two busy cores), is restarted by the relay: the drone is ready all the same."""
    relay = _relay(cf2, tmp_path)
    try:
        assert relay.stdout is not None
        assert relay.stdout.readline().startswith(b"sitl_fw: cfA at")  # printed after the firmware's hello
        children = Path(f"/proc/{relay.pid}/task/{relay.pid}/children").read_text().split()
        os.kill(int(children[0]), signal.SIGSTOP)  # calibrating takes a second of IMU packets: it has not yet
        assert _wait_ready(relay) > 5.0  # after the restart, not before
    finally:
        _stop(relay)
    assert read_trace(tmp_path / "cfA.jsonl").end["restarts"] >= 1  # (a restarted one may stall again: 1 in 20)


def test_swarm_cf_scan_status_check_and_cflib_against_the_firmware(firmware_drone):
    """The CLI against a protocol-7 firmware (2024): its supervisor's bits come from its log
    (supervisor.info), the check reads back what it decoded (ctrltarget, stabilizer.thrust) and
    leaves it landed, not locked; cflib's full connection reads the simulated motors' constants
    from its parameters (through the relay, which asks again what the firmware left unanswered:
    over UDP cflib does not); the older emergency stop locks it."""
    uri, tmp, relay = firmware_drone
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp / "cache"))  # the log table's cache: this test's own
    assert uri in swarm_cf("scan", env=env).stdout.split()
    res = swarm_cf("status", uri, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    states = res.stdout.strip().split(", ")
    assert "Can fly" in states and "Is locked" not in states and "Is flying" not in states, states
    res = swarm_cf("check", uri, "--firmware", "crazysim", env=env)
    lines = res.stdout.strip().splitlines()
    assert res.returncode == 0 and len(lines) == 4 and all(line.startswith("ok") for line in lines), res
    assert "pitch -10" in lines[1] and "yaw 30" in lines[2]
    res = swarm_cf("status", uri, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    states = res.stdout.strip().split(", ")
    assert "Can fly" in states and "Is locked" not in states, states  # the check let the supervisor land it

    from cflib.crazyflie.localization import Localization

    cf = _cflib_connect(uri, tmp / "cflib")
    try:
        p = cf.param
        assert cf.platform.get_protocol_version() == 7
        assert float(p.get_value("quadSysId.pwmToThrustA")) == pytest.approx(CRAZYSIM.thrust.a_N, rel=1e-6)
        assert float(p.get_value("quadSysId.pwmToThrustB")) == pytest.approx(CRAZYSIM.thrust.b_N, rel=1e-6)
        assert float(p.get_value("quadSysId.thrustToTorque")) == pytest.approx(CRAZYSIM.thrust_to_torque_m, rel=1e-6)
        assert float(p.get_value("quadSysId.armLength")) == pytest.approx(CRAZYSIM.arm_m, rel=1e-6)
        with warnings.catch_warnings():  # (cflib: protocol 7 has no supervisor port, this form is the one it knows)
            warnings.simplefilter("ignore", DeprecationWarning)
            Localization(cf).send_emergency_stop()
    finally:
        cf.close_link()
    res = swarm_cf("status", uri, "--timeout-s", "10", env=env)  # (a busy CI machine left 3 s unanswered once)
    states = res.stdout.strip().split(", ")
    assert "Is locked" in states, (states, res.stderr)
    _stop(relay)
    end = read_trace(tmp / "firmware" / "cfA.jsonl").end
    assert end["unanswered"] == 0, end


def test_the_relay_answers_a_link_echo_as_the_radio_does_while_its_firmware_runs(firmware_drone):
    """A Crazyflie's radio chip acknowledges every packet in its interrupt handler, whatever the
    main MCU's firmware is busy with (crazyflie2-nrf-firmware src/esb.c, esbInterruptHandler), so
    the link guard's poll is answered by the relay playing that radio: at once, also while the
    firmware process is stopped (on a busy machine its lowest-priority task, which echoes,
    crtpservice.c, went unscheduled for 0.5 s and the guard stopped a drone flying fine), and not
    at all once the firmware has ended."""
    uri, tmp, relay = firmware_drone
    fw = int(Path(f"/proc/{relay.pid}/task/{relay.pid}/children").read_text().split()[0])
    echo = bytes([0xFC]) + b"echo"  # port 15 (link), channel 0, as cflib's CRTPPacket sets the header

    def answered(timeout_s: float) -> bytes | None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as link:
            link.settimeout(timeout_s)
            link.sendto(echo, ("127.0.0.1", PORT))
            try:
                return link.recv(64)
            except TimeoutError:
                return None

    assert answered(1.0) == echo
    os.kill(fw, signal.SIGSTOP)  # its firmware stalled: the radio still acknowledges
    try:
        assert answered(1.0) == echo
    finally:
        os.kill(fw, signal.SIGCONT)
    pidfd = os.pidfd_open(fw)  # (readable once the process has ended: os.kill only delivers the signal)
    try:
        os.kill(fw, signal.SIGKILL)  # its firmware gone (power off): no answer once it has died
        assert select.select([pidfd], [], [], 10.0)[0], "the killed firmware did not die"
    finally:
        os.close(pidfd)
    assert answered(1.0) is None
    _stop(relay)
    assert read_trace(tmp / "firmware" / "cfA.jsonl").end["echoes_answered"] == 2


def _cflib_connect(uri: str, cache: Path, timeout_s: float = 30.0) -> Any:
    """cflib's full connection (log and parameter tables, every parameter's value)."""
    import cflib.crtp
    from cflib.crazyflie import Crazyflie

    cflib.crtp.init_drivers()
    cf = Crazyflie(rw_cache=str(cache))
    done = threading.Event()
    cf.fully_connected.add_callback(lambda _uri: done.set())
    cf.open_link(uri)
    if not done.wait(timeout_s):
        cf.close_link()
        raise AssertionError(f"cflib did not connect to {uri} in {timeout_s} s")
    return cf
