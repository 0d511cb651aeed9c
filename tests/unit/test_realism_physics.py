"""PhysicsWorld.apply_external_all in real PyBullet: a hovering drone under a constant extra
force accelerates as F / m, a body torque turns it as tau / I in the body frame, and a zero
wrench leaves the world bit for bit as it was."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.model import QuadModel, QuadParams
from swarm.sim.physics import PhysicsWorld

P = QuadParams()
HZ = 240.0


def hover_world(yaw_rad: float = 0.0) -> PhysicsWorld:
    w = PhysicsWorld(HZ)
    w.add_drone("a", QuadModel(P), np.array([0.0, 0.0, 1.0]), yaw_rad=yaw_rad)
    return w


def fly(w: PhysicsWorld, steps: int, force_w=None, torque_b=None):
    hover = np.full((1, 4), P.weight_N / 4)
    for _ in range(steps):
        s = w.read_states(["a"])
        w.apply_rotors_all(["a"], hover, s)
        if force_w is not None:
            w.apply_external_all(["a"], np.array([force_w]), np.array([torque_b]), s)
        w.step()
    return w.read_states(["a"])


def test_a_hovering_drone_under_a_constant_force_accelerates_as_f_over_m():
    w = hover_world()
    try:
        F = np.array([0.01, -0.004, 0.003])  # N, world
        steps = 120
        s = fly(w, steps, F, np.zeros(3))
        t = steps / HZ
        a = F / P.mass_kg
        assert s.v_w[0] == pytest.approx(a * t, rel=0.01)
        assert s.x_w[0] - [0, 0, 1] == pytest.approx(a * t**2 / 2, rel=0.02)
        assert np.abs(s.Omega_b[0]).max() < 1e-9  # at the centre of mass: no turning
    finally:
        w.close()


def test_a_body_torque_turns_the_drone_about_its_own_axis():
    w = hover_world(yaw_rad=math.pi / 2)  # body x is world y
    try:
        tau_b = np.array([2e-7, 0.0, 0.0])
        steps = 24
        s = fly(w, steps, np.zeros(3), tau_b)
        t = steps / HZ
        assert s.Omega_b[0] == pytest.approx([tau_b[0] / P.Ixx_kgm2 * t, 0.0, 0.0], rel=0.01, abs=1e-9)
        R = s.R[0]
        assert R[:, 0] == pytest.approx([0.0, 1.0, 0.0], abs=1e-3)  # it rolled about world y
    finally:
        w.close()


def test_a_zero_wrench_changes_nothing_bit_for_bit():
    a, b = hover_world(), hover_world()
    try:
        sa = fly(a, 50)
        sb = fly(b, 50, np.zeros(3), np.zeros(3))
        assert np.array_equal(sa.x_w, sb.x_w) and np.array_equal(sa.v_w, sb.v_w) and np.array_equal(sa.q, sb.q)
    finally:
        a.close()
        b.close()
