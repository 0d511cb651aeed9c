import math

import numpy as np
import pytest

from swarm.errors import InputError
from swarm.model import (
    Layout,
    QuadModel,
    QuadParams,
    QuadState,
    drift_and_input,
    mixer,
    rigid_body_accel,
    setpoint_to_thrust_vector,
    step_rk4,
    thrust_vector_input_set,
    thrust_vector_to_setpoint,
)
from swarm.rotation import R_to_quat, euler_to_quat, quat_derivative, quat_to_R

from .helpers import random_state


def test_crazyflie_defaults_match_the_paper_table():
    p = QuadParams()
    assert (p.mass_kg, p.g_mps2, p.Ixx_kgm2, p.Izz_kgm2, p.kf, p.km, p.l_m, p.rotor_to_rotor_m) == (
        0.027,
        9.81,
        2.39e-5,
        3.23e-5,
        3.16e-10,
        7.94e-12,
        0.014,
        0.130,
    )
    assert p.f_max_N == pytest.approx(0.149, abs=5e-4)


@pytest.mark.parametrize("layout", [Layout.X, Layout.PLUS])
def test_mixer_hover_and_single_rotor_torques(layout):
    p = QuadParams(layout=layout)
    B = mixer(p)
    hover = B @ np.full(4, p.weight_N / 4)
    np.testing.assert_allclose(hover, [p.weight_N, 0, 0, 0], atol=1e-15)
    # each rotor's torque is r x (f e3) plus its spin reaction
    pos = {
        Layout.X: np.array([[1, -1], [-1, -1], [-1, 1], [1, 1]]) * p.arm_m / math.sqrt(2),
        Layout.PLUS: np.array([[1, 0], [0, 1], [-1, 0], [0, -1]]) * p.arm_m,
    }[layout]
    for i in range(4):
        f = np.zeros(4)
        f[i] = 0.1
        r = np.array([pos[i, 0], pos[i, 1], 0.0])
        np.testing.assert_allclose((B @ f)[1:3], np.cross(r, [0, 0, 0.1])[:2], atol=1e-15)
        assert abs((B @ f)[3]) == pytest.approx(0.1 * p.km / p.kf)
    assert np.linalg.matrix_rank(B) == 4


@pytest.mark.parametrize(
    "field, value",
    [
        ("mass_kg", 0.0),
        ("mass_kg", float("nan")),
        ("Ixx_kgm2", -1.0),
        ("thrust_to_weight", 0.9),
        ("l_m", -0.01),
    ],
)
def test_bad_parameters_name_the_field(field, value):
    with pytest.raises(InputError, match=field):
        QuadParams(**{field: value})


def test_control_affine_form_matches_the_dynamics():
    rng = np.random.default_rng(1)
    model = QuadModel()
    for _ in range(20):
        s = random_state(rng)
        f_rot = rng.uniform(0, model.params.f_max_N, 4)
        fx, gx = drift_and_input(model, s)
        xi_dot = fx + gx @ f_rot
        v_dot, Om_dot = rigid_body_accel(model, s, f_rot)
        np.testing.assert_allclose(xi_dot[0:3], s.v_w)
        np.testing.assert_allclose(xi_dot[3:6], v_dot, atol=1e-12)
        np.testing.assert_allclose(xi_dot[9:12], Om_dot, atol=1e-9)


def test_hover_is_an_equilibrium_and_free_fall_falls():
    model = QuadModel()
    s = QuadState.hover()
    for _ in range(100):
        s = step_rk4(model, s, np.full(4, model.params.weight_N / 4), 0.01)
    np.testing.assert_allclose(s.x_w, [0, 0, 1], atol=1e-12)
    s = QuadState.hover()
    for _ in range(100):
        s = step_rk4(model, s, np.zeros(4), 0.01)
    assert s.x_w[2] == pytest.approx(1 - 0.5 * 9.81, rel=1e-9)


def test_rotations_roundtrip_and_quaternion_rate():
    rng = np.random.default_rng(2)
    for _ in range(50):
        q = euler_to_quat(*rng.uniform(-1.5, 1.5, 3))
        R = quat_to_R(q)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        q2 = R_to_quat(R)
        np.testing.assert_allclose(quat_to_R(q2), R, atol=1e-12)
        # q' by finite difference of R' = R hat(Omega)
        Om = rng.normal(size=3)
        dt = 1e-7
        R_next = quat_to_R(q + dt * quat_derivative(q, Om))
        np.testing.assert_allclose((R_next - R) / dt, R @ _hat(Om), atol=1e-5)


def _hat(a):
    return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


def test_thrust_vector_setpoint_roundtrip_and_input_set():
    rng = np.random.default_rng(3)
    p = QuadParams()
    ins = thrust_vector_input_set(p)
    for _ in range(50):
        F = np.array([*rng.uniform(-0.1, 0.1, 2), rng.uniform(0.1, 0.5)])
        yaw = rng.uniform(-3, 3)
        roll, pitch, T = thrust_vector_to_setpoint(F, yaw)
        np.testing.assert_allclose(setpoint_to_thrust_vector(roll, pitch, yaw, T), F, atol=1e-12)
        if ins.contains(F):
            tilt = math.acos(F[2] / np.linalg.norm(F))
            assert tilt <= p.max_tilt_rad + 1e-12
            assert np.linalg.norm(F) <= 4 * p.f_max_N + 1e-12
