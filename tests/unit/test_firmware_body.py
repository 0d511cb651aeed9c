"""The body a Crazyflie firmware flies in the loop (swarm.world.fw_body) and the thrust maps
(swarm.crazyflie_fw.ThrustMap), checked by their definitions: the project's rigid body, the
firmware's force-torque distribution inverted, the IMU scales sensors_sitl.c reads with."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from swarm.agents.crazyflie import thrust_command
from swarm.config import ConfigError, ThrustCalibration, resolve
from swarm.crazyflie_fw import CRAZYSIM, ThrustMap, collective_thrust_N, thrust_map
from swarm.model import QuadModel, QuadParams, step_rk4
from swarm.realism.motors import MotorParams
from swarm.rotation import euler_to_quat, quat_to_R
from swarm.world.fw_body import DEG_PER_LSB, G_PER_LSB, FirmwareBody, firmware_mixer, rk4
from swarm.world.fw_crtp import FwState, fw_state

from .helpers import random_state, real_drone_raw

DT = 0.001


def test_the_compiled_step_is_the_project_rigid_body():
    """fw_body.rk4 is swarm.model.step_rk4, compiled: the same state after a step, to rounding."""
    rng = np.random.default_rng(3)
    model = QuadModel()
    p = model.params
    for _ in range(20):
        st = random_state(rng)
        f = rng.uniform(0.0, 0.15, 4)
        ref = step_rk4(model, st, f, 0.004)
        s = np.concatenate([st.x_w, st.v_w, st.q, st.Omega_b])
        rk4(s, f, model.B, model.J, model.J_inv, p.mass_kg, p.g_mps2, 0.004)
        assert s == pytest.approx(np.concatenate([ref.x_w, ref.v_w, ref.q, ref.Omega_b]), abs=1e-12)


def _force_torque_distribution(thrust_N, tx, ty, tz, arm_m, k_m):
    """power_distribution_sitl.c powerDistributionForceTorque, before the PWM: motor forces M1..M4 [N]."""
    arm = 0.707106781 * arm_m
    roll, pitch, thrust, yaw = 0.25 / arm * tx, 0.25 / arm * ty, 0.25 * thrust_N, 0.25 * tz / k_m
    return np.array(
        [
            thrust - roll - pitch - yaw,
            thrust - roll + pitch + yaw,
            thrust + roll + pitch - yaw,
            thrust + roll - pitch + yaw,
        ]
    )


def test_the_motor_layout_inverts_the_firmware_force_torque_distribution():
    """M1 front right ... M4 front left, M1 and M3 turning the body clockwise: the wrench the body
    feels is the one the firmware distributed."""
    B = firmware_mixer()
    rng = np.random.default_rng(4)
    for _ in range(10):
        w = np.array([rng.uniform(0.2, 0.4), *rng.uniform(-1e-3, 1e-3, 3)])
        f = _force_torque_distribution(*w, CRAZYSIM.arm_m, CRAZYSIM.thrust_to_torque_m)
        assert B @ f == pytest.approx(w, rel=1e-6, abs=1e-12)
    # a faster M1 (front right) pushes the right side and the nose up: negative roll and pitch torques
    assert (B @ np.array([1.0, 0.0, 0.0, 0.0]))[1] < 0 and (B @ np.array([1.0, 0.0, 0.0, 0.0]))[2] < 0


def test_the_simulated_motors_are_quadratic_as_the_firmware_states():
    m = CRAZYSIM.thrust
    assert m.collective_N(20_000) == pytest.approx(0.1167, abs=2e-4)  # the 0.117 N
    assert m.collective_N(60_000) == pytest.approx(0.5547, abs=2e-4)  # and 0.55 N
    hover = QuadParams(mass_kg=CRAZYSIM.mass_kg).weight_N
    assert m.collective_N(m.command(hover)) == pytest.approx(hover, rel=1e-12)
    for cmd in (0.0, 1000.0, 36_000.0, 65_535.0):
        assert m.command(m.collective_N(cmd)) == pytest.approx(cmd, abs=1e-6)
    lin = thrust_map("2026.04")
    assert lin == ThrustMap(0.0, 0.12) and lin.command(lin.collective_N(30_000)) == pytest.approx(30_000)
    # the 2026.04 (linear) map on these motors: the hover they make is short of the hover meant
    made = m.collective_N(thrust_command(hover, ThrustCalibration()))
    assert made < 0.99 * hover
    sitl = ThrustCalibration(firmware="crazysim")
    assert m.collective_N(thrust_command(hover, sitl)) == pytest.approx(hover, rel=1e-4)


def test_a_thrust_calibration_can_be_quadratic():
    cal = ThrustCalibration(pwm_to_thrust_a=0.09, pwm_to_thrust_b=0.07)
    assert cal.map == ThrustMap(0.09, 0.07)
    assert cal.max_thrust_N == pytest.approx(4 * (0.09 * (60_000 / 65535) ** 2 + 0.07 * 60_000 / 65535))
    assert ThrustCalibration(firmware="crazysim").max_thrust_N == pytest.approx(CRAZYSIM.thrust.collective_N(60_000))
    assert collective_thrust_N(36_000, "crazysim") == pytest.approx(CRAZYSIM.thrust.collective_N(36_000))
    for bad in ({"pwm_to_thrust_a": 0.09}, {"pwm_per_newton": 1e5, "pwm_to_thrust_a": 0.1, "pwm_to_thrust_b": 0.1}):
        with pytest.raises(ConfigError):
            resolve(real_drone_raw(thrust=bad))
    with pytest.raises(ValueError, match="quadratic"):
        _ = ThrustCalibration(firmware="crazysim").per_newton
    # the filter plans with what 60000 commands make on the simulated motors (2.09 times the weight)
    me = resolve(real_drone_raw(thrust={"firmware": "crazysim"})).agents[0]
    assert me.quad_params().f_max_N * 4 == pytest.approx(CRAZYSIM.thrust.collective_N(60_000))


def test_the_imu_reads_as_the_firmware_scales_it():
    body = FirmwareBody(np.array([0.0, 0.0, 0.0]), math.radians(30), motors=MotorParams(0.0, 0.0))  # thrust at once
    body.step(DT)
    assert list(body.imu) == [0, 0, round(1.0 / G_PER_LSB), 0, 0, 0]  # at rest on the floor: 1 g up, any yaw
    body.s[2] = 1.0  # in the air, motors off: free fall, the accelerometer feels nothing
    body.step(DT)
    assert np.abs(body.imu[:3]).max() <= 1
    body.s[2], body.s[3:6] = 1.0, 0.0
    body.pwm[:] = 40_000
    body.step(DT)
    lift_g = CRAZYSIM.thrust.collective_N(40_000) / (body.m * body.g)
    assert body.imu[2] == pytest.approx(lift_g / G_PER_LSB, abs=1.0)
    body.s[10:13] = [1.0, -0.5, 0.2]  # rad/s, body
    body.pwm[:] = 0
    body.step(DT)
    assert body.imu[3:] == pytest.approx(np.degrees(body.s[10:13]) / DEG_PER_LSB, abs=1.0)
    body.s[10] = 100.0  # beyond the gyro's 2000 deg/s: the int16 saturates
    body.step(DT)
    assert body.imu[3] == 32767


def test_the_rotors_lag_as_the_simulated_motors_do():
    """A rotor's speed reaches 63 % of a step in its time constant (12.5 ms up, 25 ms down:
    swarm.realism.motors' CrazySim values), its thrust 40 %; held, it makes the thrust the PWM
    asks for (the firmware's map)."""
    up_s, down_s = MotorParams().time_constant_up_s, MotorParams().time_constant_down_s
    assert (up_s, down_s) == (0.0125, 0.025)
    body = FirmwareBody(np.array([0.0, 0.0, 1.0]), 0.0)
    target = CRAZYSIM.thrust.collective_N(40_000)
    body.pwm[:] = 40_000
    for _ in range(25):  # 25 ms: two time constants up
        body.step(DT)
    assert body.thrust_N == pytest.approx((1 - math.exp(-2)) ** 2 * target, rel=1e-9)
    for _ in range(300):
        body.step(DT)
    assert body.thrust_N == pytest.approx(target, rel=1e-9)
    body.pwm[:] = 0
    for _ in range(25):  # one time constant down: speed e^-1 of it, thrust e^-2
        body.step(DT)
    assert body.thrust_N == pytest.approx(math.exp(-2) * target, rel=1e-9)


def test_a_body_rests_on_the_floor_level_until_its_motors_lift_it():
    body = FirmwareBody(np.array([1.0, 2.0, 0.0]), 0.5)
    body.s[6:10] = euler_to_quat(0.1, -0.05, 0.5)  # landed tilted: it settles level at its yaw
    body.pwm[:] = 30_000  # below the weight
    for _ in range(100):
        body.step(DT)
    assert body.x_w == pytest.approx([1.0, 2.0, 0.0]) and np.abs(body.s[3:6]).max() == 0.0
    assert quat_to_R(body.q)[2, 2] == pytest.approx(1.0) and quat_to_R(body.q)[1, 0] == pytest.approx(math.sin(0.5))
    body.pwm[:] = 45_000  # above it: it climbs
    for _ in range(200):
        body.step(DT)
    assert body.x_w[2] > 0.01 and body.x_w[:2] == pytest.approx([1.0, 2.0])


@pytest.mark.parametrize(
    ("info", "setpoint", "state"),
    [
        (0b0000_0000, (0.0, 0.0, 0.0, 0.0), FwState.NOT_READY),
        (0b0000_1110, (0.0, 0.0, 0.0, 0.0), FwState.READY),  # auto-armed, armed, can fly
        (0b0001_1110, (1.2, -0.3, 0.0, 36_000.0), FwState.FLYING),
        (0b0001_1110, (0.0, 0.0, 0.0, 36_000.0), FwState.LEVEL_OUT),  # supervisorOverrideSetpoint
        (0b0100_0100, (0.0, 0.0, 0.0, 0.0), FwState.LOCKED),
        (0b1000_0100, (0.0, 0.0, 0.0, 0.0), FwState.CRASHED),
    ],
)
def test_supervisor_states_from_its_log(info, setpoint, state):
    assert fw_state(info, *setpoint) is state


def test_a_zero_attitude_setpoint_is_levelling_out_only_once_the_client_is_silent():
    flying, zero = 0b0001_1110, (0.0, 0.0, 0.0, 36_000.0)
    assert fw_state(flying, *zero, setpoint_age_s=0.01) is FwState.FLYING  # a vertical climb, sent so
    assert fw_state(flying, *zero, setpoint_age_s=0.52) is FwState.LEVEL_OUT


def test_the_relay_outlives_a_client_that_falls_silent_mid_flight():
    """``--until-handed-back`` ends the relay once every client is done with its drone: handed
    back (and its supervisor no longer counting it flying, for at most HANDED_BACK_SETTLE_S), or
    silent for 3 s with the drone resting on the floor. A client silent in flight is not done
    (the relay carries the other drones' links; ending it refuses them)."""
    from swarm.world.sitl_fw import HANDED_BACK_SETTLE_S, HANDED_BACK_SILENT_S, FirmwareDrone

    d = FirmwareDrone("real1", 0, [0.0, 0.0, 0.0], 0.0, cf2=Path("/nonexistent"))
    try:
        assert not d.done(100.0)  # never talked
        d.talked_s = 100.0
        later = 100.0 + HANDED_BACK_SILENT_S + 0.1
        assert not d.done(100.5) and d.done(later)  # silent, on the floor, motors off
        d.body.s[2], d.body.pwm[:] = 1.0, 30000.0  # flying
        assert not d.done(later)
        d.body.s[2] = 0.0  # on the floor, motors still spinning
        assert not d.done(later)
        d.handed_back, d.handed_back_s, d.state = True, 100.0, FwState.FLYING  # (the supervisor's 2 s)
        assert not d.done(100.5) and d.done(100.0 + HANDED_BACK_SETTLE_S + 0.1)
        d.state = FwState.READY  # landed
        assert d.done(100.5)
    finally:
        d.fw_sock.close()
        d.cl_sock.close()


def test_the_relay_asks_again_what_the_firmware_left_unanswered():
    """The firmware's link queue drops what comes while it is full, and cflib asks nothing again
    over UDP: the relay sends a request (a port and channel the firmware answers) again after
    RESEND_AFTER_S without an answer on that port and channel, up to RESENDS times, and counts one
    given up. An answered request, a setpoint and the relay's own log requests are not sent again.
    Real sockets: the test holds the firmware's end and the client's."""
    import socket

    from swarm.world.fw_crtp import RESEND_AFTER_S, RESENDS
    from swarm.world.sitl_fw import FirmwareDrone

    d = FirmwareDrone("real1", 0, [0.0, 0.0, 0.0], 0.0, cf2=Path("/nonexistent"))
    fw, client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM), socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        fw.bind(("127.0.0.1", 0))
        fw.settimeout(1.0)
        d.fw_addr, d.ready, d.monitor.stage = fw.getsockname(), True, "running"
        client.connect(d.cl_sock.getsockname())
        client.settimeout(1.0)
        now = 10.0

        def run_for(seconds: float) -> list[bytes]:
            """The relay's 1 kHz loop for ``seconds`` of its clock; what reached the firmware but
            the sensor packets."""
            nonlocal now
            got = []
            for _ in range(round(seconds * 1000)):
                now += 0.001
                d.poll(now)
                d.tick(now, 1, 0.001)
                fw.setblocking(False)
                while True:
                    try:
                        pk = fw.recv(64)
                    except BlockingIOError:
                        break
                    if pk[0] >> 4 != 9:  # (the sensor packet)
                        got.append(pk)
                fw.setblocking(True)
            return got

        toc_item = bytes([0x5C, 2, 0xE7, 0])  # log TOC (port 5, channel 0): item 231
        setpoint = bytes([0x3C]) + bytes(14)  # an RPYT setpoint (port 3): never answered
        client.send(toc_item)
        client.send(setpoint)
        assert run_for(0.01) == [toc_item, setpoint]  # as they came
        assert run_for(RESEND_AFTER_S) == [toc_item]  # no answer: asked again, the setpoint not
        fw.sendto(bytes([0x50, 2, 0xE7, 0, 7]) + b"kalman\0rtFinal\0", d.fw_sock.getsockname())
        assert run_for(3 * RESEND_AFTER_S) == []  # answered: never again
        assert client.recv(64)[:4] == bytes([0x50, 2, 0xE7, 0])  # and the client has its answer
        assert d.counters.resent == 1 and d.counters.unanswered == 0

        version = bytes([0xDD, 0])  # the platform's protocol version (port 13, channel 1): never answered
        client.send(version)
        got = run_for((RESENDS + 2) * (RESEND_AFTER_S + 0.01))
        assert got == [version] * (1 + RESENDS)
        assert d.counters.resent == 1 + RESENDS and d.counters.unanswered == 1

        d.monitor.restart_block()  # the client reset the firmware's logging: the relay's own request
        mine = run_for(3 * RESEND_AFTER_S)
        assert mine and all(pk[0] >> 4 == 5 for pk in mine) and d.asked == {}  # (the monitor asks on its own)
    finally:
        for s in (fw, client, d.fw_sock, d.cl_sock):
            s.close()
