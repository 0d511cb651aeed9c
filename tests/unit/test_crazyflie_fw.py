"""The Crazyflie firmware's rules (swarm.crazyflie_fw, after crazyflie-firmware 2026.08)
and the client's side of them (swarm.agents.crazyflie, the guard's landing sequence, the
filter's thrust bounds). Each rule here is one a first lab flight would hit."""

import math

import pytest

from swarm.agents.crazyflie import rpyt, thrust_command
from swarm.config import ConfigError, ThrustCalibration, resolve
from swarm.crazyflie_fw import (
    RPYT_MAX_THRUST,
    Firmware,
    SupervisorState,
    collective_thrust_N,
    pwm_per_newton,
    wire_yaw_rate_dps,
)
from swarm.model import QuadParams

from .helpers import real_drone_raw

HOVER = 36_000  # a thrust command near hover for the 2.1 (0.265 N at 0.48 N full scale: 36187)


def test_the_thrust_stays_locked_until_a_zero_thrust_setpoint():
    fw = Firmware()
    fw.rpyt(0.0, 0.0, 0.0, 0.0, HOVER)  # a guard that starts with takeoff thrust
    assert fw.step(0.01).thrust_N == 0.0  # crtp_commander_rpyt.c: thrustLocked
    fw.rpyt(0.02, 0.0, 0.0, 0.0, 0)
    fw.rpyt(0.03, 0.0, 0.0, 0.0, HOVER)
    assert fw.step(0.04).thrust_N == pytest.approx(collective_thrust_N(HOVER, "2026.04"))


def test_thrust_map_by_release_and_the_rpyt_cap():
    assert pwm_per_newton("2026.04") == pytest.approx(65535 / 0.48)  # THRUST_MAX 0.12 N per motor
    assert pwm_per_newton("2025.12") == pytest.approx(65535 / 0.45)  # 0.1125 N
    assert pwm_per_newton("2026.04", "thrust_upgrade") == pytest.approx(65535 / 0.72)
    with pytest.raises(ValueError, match="2024.10"):
        pwm_per_newton("2024.10")
    fw = Firmware()
    fw.rpyt(0.0, 0.0, 0.0, 0.0, 0)
    fw.rpyt(0.01, 0.0, 0.0, 0.0, 65_000)
    assert fw.step(0.02).thrust_N == pytest.approx(collective_thrust_N(RPYT_MAX_THRUST, "2026.04"))
    # our default calibration is the firmware's own map: hover thrust in is hover thrust out
    weight = QuadParams().weight_N
    cal = ThrustCalibration()
    assert collective_thrust_N(thrust_command(weight, cal), "2026.04") == pytest.approx(weight, rel=1e-4)
    old = ThrustCalibration(pwm_per_newton=158_000.0)  # the old default: 16 % more than the drone makes
    assert collective_thrust_N(thrust_command(weight, old), "2026.04") > 1.15 * weight


def test_yaw_rate_goes_out_negated_and_turns_the_firmware_counter_clockwise():
    cal = ThrustCalibration(pwm_offset=1000.0, pwm_per_newton=150_000.0, max_pwm=60_000)
    r, p, y, t = rpyt(math.radians(5), math.radians(-3), math.radians(30), 0.2, cal)
    assert (r, p, y, t) == pytest.approx((5.0, -3.0, -30.0, 31_000))
    assert wire_yaw_rate_dps(30.0) == -30.0
    fw = Firmware()
    fw.rpyt(0.0, 0.0, 0.0, 0.0, 0)
    fw.rpyt(0.01, r, -p, y, t)  # as cflib puts it on the wire: pitch negated, yaw rate as given
    out = fw.step(0.02)
    assert out.yaw_rate_radps == pytest.approx(math.radians(30))  # what the agent asked: counter-clockwise
    assert out.pitch_rad == pytest.approx(math.radians(-3)) and out.roll_rad == pytest.approx(math.radians(5))


def _flying(fw: Firmware, t_end: float, dt: float = 0.01) -> float:
    fw.rpyt(0.0, 0.0, 0.0, 0.0, 0)
    t = 0.0
    while t < t_end:
        t += dt
        fw.rpyt(t, 5.0, 0.0, 10.0, HOVER)
        fw.step(t)
    return t


def test_setpoints_that_stop_mid_flight_level_out_at_500_ms_and_lock_at_2_s():
    fw = Firmware()
    t0 = _flying(fw, 1.0)
    assert fw.step(t0 + 0.45).roll_rad != 0.0 and fw.state is SupervisorState.FLYING
    out = fw.step(t0 + 0.55)
    assert fw.state is SupervisorState.LEVEL_OUT
    assert (out.roll_rad, out.yaw_rate_radps) == (0.0, 0.0) and out.thrust_N > 0.0  # level, last thrust kept
    assert fw.step(t0 + 2.05).thrust_N == 0.0 and fw.state is SupervisorState.LOCKED
    fw.rpyt(t0 + 2.1, 0.0, 0.0, 0.0, 0)
    fw.rpyt(t0 + 2.2, 0.0, 0.0, 0.0, HOVER)
    assert fw.step(t0 + 2.3).thrust_N == 0.0  # locked: only a reboot


def test_the_guards_landing_sequence_ends_landed_and_silence_right_after_the_stop_locks():
    """After the motors stop the supervisor counts the drone as flying for 2 s: silence then
    locks it (reboot required). Zero-thrust setpoints for 2.5 s, as the guard sends, land it."""
    silent, guarded = Firmware(), Firmware()
    for fw in (silent, guarded):
        t0 = _flying(fw, 1.0)
        fw.stop(t0)
    t = t0
    while t < t0 + 4.0:
        t += 0.05
        if t < t0 + 2.5:
            guarded.rpyt(t, 0.0, 0.0, 0.0, 0)
        silent.step(t)
        guarded.step(t)
    assert silent.state is SupervisorState.LOCKED
    assert guarded.state is SupervisorState.LANDED


def test_an_emergency_stop_locks_and_a_tumble_crashes_until_recovered_upright():
    fw = Firmware()
    t = _flying(fw, 0.5)
    fw.emergency_stop(t)
    assert fw.step(t + 0.01).thrust_N == 0.0 and not fw.recover(t + 0.02, tumbled=False)
    fw = Firmware()
    t = _flying(fw, 0.5)
    fw.step(t + 0.01, tilt_rad=math.radians(80))
    assert fw.state is SupervisorState.CRASHED
    assert not fw.recover(t + 0.02, tumbled=True)
    assert fw.recover(t + 0.03, tumbled=False) and fw.state is SupervisorState.READY


def _real(**thrust):
    return resolve(real_drone_raw(thrust=thrust)).agents[0]


def test_the_filter_plans_with_no_more_thrust_than_the_setpoint_can_ask():
    a = _real()
    p = a.quad_params()
    cap = ThrustCalibration().max_thrust_N  # 60000 commands at the 2026.04 map: 0.44 N
    assert 4 * p.f_max_N == pytest.approx(cap) and p.thrust_to_weight < 1.7
    assert QuadParams().thrust_to_weight == 2.25  # the simulated airframe keeps its own
    with pytest.raises(ConfigError, match="firmware"):
        _real(firmware="2019.02")
    assert _real(firmware="2019.02", pwm_per_newton=150_000.0).crazyflie.thrust.per_newton == 150_000.0
