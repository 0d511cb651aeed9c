"""The lag between the filter's commanded acceleration and the plant's (``tools.bench_lag``), by
its definitions: the attitude loop's effective lag is ``kOm / kR`` (the integral of its tilt error
for a unit step), the collective acts at once in the ideal world and through the rotors' lag in
the lab's; and the commanded accelerations ``fly_scenario`` logs are the ones the drones fly,
each at its tick."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.config import resolve
from swarm.control import AttitudeGains
from swarm.model import QuadParams
from swarm.offline.closed_loop import fly_scenario
from swarm.offline.scenario import SwapSettings, circle_swap
from swarm.rotation import E3
from tools.bench_lag import fly_step, world_settings

pytestmark = pytest.mark.unit

PARAMS = QuadParams()
CONTROL_HZ, PHYSICS_HZ = 100.0, 300.0
X = np.array([1.0, 0.0, 0.0])


def tau(world: str, a_w: np.ndarray) -> float:
    return fly_step(PARAMS, world, a_w, 0.5, CONTROL_HZ, PHYSICS_HZ, 0).tau_eff_s(float(np.linalg.norm(a_w)))


def test_the_attitude_loops_lag_is_its_rate_gain_over_its_attitude_gain():
    g = AttitudeGains()
    want = 2 * g.zeta / g.wn_rp_radps  # kOm / kR = J 2 zeta wn / (J wn^2)
    assert tau("ideal", 0.5 * X) == pytest.approx(want, rel=0.03)
    # the same for a weak, heavy drone: thrust and inertia scale kR and kOm alike
    lab, heavy = tau("lab", 0.5 * X), tau("lab_3sigma", 0.5 * X)
    assert heavy == pytest.approx(lab, rel=0.01)
    assert world_settings("lab_3sigma")[1:] == pytest.approx((0.85, 1.09))


def test_the_collective_acts_at_once_in_the_ideal_world_and_through_the_rotors_lag_in_the_lab():
    for a in (1.0, -3.0):
        assert abs(tau("ideal", a * E3)) < 1e-9
    up, down = tau("lab_motors", 1.0 * E3), tau("lab_motors", -1.0 * E3)
    dt = 1.0 / PHYSICS_HZ  # the plant's rotor speed at a substep's end acts over the substep
    assert 0.0125 - dt < up < 0.0125 * 1.1
    assert 0.025 - dt < down < 0.025 * 1.1
    # the lab's radio: each command one tick late (none of these is lost at seed 0)
    assert tau("lab", 1.0 * E3) - up == pytest.approx(1.0 / CONTROL_HZ, abs=1e-6)


def test_the_swarms_logged_commands_are_the_accelerations_its_drones_fly():
    raw = circle_swap(2, 1.0, SwapSettings(realism="ideal"))
    cfg = resolve(raw)
    t = cfg.time
    log = fly_scenario(cfg)
    assert log.accel_cmd_w is not None and log.accel_cmd_w.shape == log.v_w.shape
    a = log.accel_cmd_w[:-1]  # the commands flown before the last tick's velocity (log.v_w: at a tick's start)
    assert log.all_reached
    # from hover (0) the drones' velocity follows the commands but for the lag of the last one, tau a[-1]
    gap_mps = a.sum(axis=0) / t.control_hz - log.v_w[-1]  # (N, 3)
    g = AttitudeGains()
    lag_mps = 2 * g.zeta / g.wn_rp_radps * a[-1]
    assert np.abs(a[-1, :, :2]).max() > 1.0  # (still braking at the goal: a gap to measure)
    # horizontal, to a first-order reading of the lag (0.033 here, on the world's PyBullet plant)
    assert np.abs(gap_mps[:, :2] - lag_mps[:, :2]).max() < 0.04
