"""The rotor-speed lag by its definition (63 % at the time constant, up faster than down),
and the seeded per-drone thrust and mass factors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.model import QuadParams
from swarm.realism.motors import MotorParams, Motors, drone_factors, plant_airframe
from swarm.realism.rng import Stream

KF = QuadParams().kf
HOVER = QuadParams().weight_N / 4
DT = 1 / 240  # the world's physics step; 12.5 ms and 25 ms are 3 and 6 of them


def motors(p: MotorParams, f0: float, n: int = 1, factor: float = 1.0) -> Motors:
    return Motors(p, DT, np.full(n, KF), np.full(n, factor), np.full((n, 4), f0))


def speed(f_N: float) -> float:
    return math.sqrt(f_N / KF) * 2 * math.pi / 60


def test_a_step_up_reaches_63_percent_of_its_speed_at_the_up_time_constant():
    m = motors(MotorParams(), 0.0)
    f_cmd = np.full((1, 4), 2 * HOVER)
    for _ in range(3):  # 12.5 ms
        f = m.step(f_cmd)
    assert m.omega_rad_s[0] == pytest.approx((1 - math.exp(-1)) * speed(2 * HOVER), rel=1e-12)
    assert f[0] == pytest.approx((1 - math.exp(-1)) ** 2 * 2 * HOVER, rel=1e-12)  # thrust goes with speed^2
    for _ in range(300):
        f = m.step(f_cmd)
    assert f[0] == pytest.approx(2 * HOVER, rel=1e-12)


def test_a_step_down_falls_to_37_percent_of_its_speed_at_the_down_time_constant():
    m = motors(MotorParams(), HOVER)
    for _ in range(6):  # 25 ms
        m.step(np.zeros((1, 4)))
    assert m.omega_rad_s[0] == pytest.approx(math.exp(-1) * speed(HOVER), rel=1e-12)


def test_up_is_faster_than_down_and_each_rotor_is_its_own():
    m = motors(MotorParams(), HOVER)
    w0 = speed(HOVER)
    m.step(np.array([[4 * HOVER, HOVER, 0.0, HOVER]]))  # M1 up to 2 w0, M3 down to 0
    up, down = (m.omega_rad_s[0, 0] - w0) / w0, (w0 - m.omega_rad_s[0, 2]) / w0
    assert up == pytest.approx(1 - math.exp(-DT / 0.0125)) and down == pytest.approx(1 - math.exp(-DT / 0.025))
    assert up > down and m.omega_rad_s[0, 1] == pytest.approx(w0) and m.omega_rad_s[0, 3] == pytest.approx(w0)


def test_without_lag_and_factors_the_commanded_thrusts_come_back_bit_for_bit():
    m = motors(MotorParams(time_constant_up_s=0.0, time_constant_down_s=0.0), HOVER, n=3)
    f_cmd = np.random.default_rng(1).uniform(0, 0.15, (3, 4))
    assert m.step(f_cmd) is f_cmd
    assert m.omega_sum_rad_s == pytest.approx(np.sqrt(f_cmd / KF).sum(axis=1) * 2 * math.pi / 60)


def test_a_thrust_factor_scales_the_thrust_not_the_rotor_speed():
    m = motors(MotorParams(time_constant_up_s=0.0, time_constant_down_s=0.0), HOVER, factor=0.9)
    f = m.step(np.full((1, 4), HOVER))
    assert f[0] == pytest.approx(0.9 * HOVER) and m.omega_rad_s[0, 0] == pytest.approx(speed(HOVER))


def test_factors_are_seeded_per_drone_and_have_the_asked_spread():
    a = drone_factors(7, 20_000, 0.1, 0.05, Stream.MASS_FACTOR)
    assert np.array_equal(a, drone_factors(7, 20_000, 0.1, 0.05, Stream.MASS_FACTOR))
    assert np.array_equal(a[:5], drone_factors(7, 5, 0.1, 0.05, Stream.MASS_FACTOR))  # drone i's own, whatever n
    assert not np.array_equal(a[:5], drone_factors(8, 5, 0.1, 0.05, Stream.MASS_FACTOR))
    assert not np.array_equal(a[:5], drone_factors(7, 5, 0.1, 0.05, Stream.THRUST_FACTOR))
    assert a.mean() == pytest.approx(1.1, abs=4 * 0.05 / math.sqrt(20_000))
    assert a.std() == pytest.approx(0.05, rel=0.03)
    assert a.min() >= 1.1 - 3 * 0.05 and a.max() <= 1.1 + 3 * 0.05
    assert np.all(drone_factors(7, 4, -0.2, 0.0, Stream.MASS_FACTOR) == 0.8)


def test_a_heavier_airframe_keeps_its_motors():
    nominal = QuadParams()
    heavy = plant_airframe(nominal, 1.3)
    assert heavy.mass_kg == pytest.approx(1.3 * nominal.mass_kg)
    assert heavy.Izz_kgm2 == pytest.approx(1.3 * nominal.Izz_kgm2)
    assert heavy.f_max_N == pytest.approx(nominal.f_max_N)
