"""Downwash, rotor drag and ground effect against gym-pybullet-drones' formulas and cf2x.urdf
coefficients (BaseAviary._downwash, _drag, _groundEffect), computed here by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swarm.model import QuadParams, rotor_geometry
from swarm.realism.aero import AeroParams, downwash_force_w, drag_force_w, ground_effect
from swarm.rotation import euler_to_quat, quat_to_R

# cf2x.urdf <properties>, typed from the file
DW1, DW2, DW3 = 2267.18, 0.16, -0.11
PROP_R = 2.31348e-2
DRAG_XY, DRAG_Z = 9.1785e-7, 10.311e-7
GND = 11.36859
KF = 3.16e-10  # N / rpm^2 (cf2x.urdf kf, swarm.model.QuadParams.kf)
W = QuadParams().weight_N
P = AeroParams()


def upstream_downwash(dz: float, dxy: float) -> float:
    """BaseAviary._downwash, line for line (the force's magnitude)."""
    alpha = DW1 * (PROP_R / (4 * dz)) ** 2
    beta = DW2 * dz + DW3
    return alpha * math.exp(-0.5 * (dxy / beta) ** 2)


@pytest.mark.parametrize("dz, dxy", [(1.0, 0.0), (1.0, 0.03), (0.8, 0.02), (2.0, 0.1), (0.6, 0.01)])
def test_downwash_is_upstreams_where_the_cap_does_not_bind(dz, dxy):
    x = np.array([[0.0, 0.0, 1.0], [dxy, 0.0, 1.0 + dz]])
    F = downwash_force_w(x, np.array([W, W]), P)
    assert F[0, 2] == pytest.approx(-upstream_downwash(dz, dxy), rel=1e-12)
    assert np.all(F[0, :2] == 0.0) and np.all(F[1] == 0.0)  # straight down, and nothing on the upper drone


def test_downwash_by_hand_at_one_metre():
    # alpha = 2267.18 (0.0231348 / 4)^2 = 0.0758399 N; beta = 0.05 m; exp(-0.5 (0.03 / 0.05)^2) = exp(-0.18)
    x = np.array([[0.0, 0.0, 0.5], [0.0, 0.03, 1.5]])
    assert downwash_force_w(x, np.array([W, W]), P)[0, 2] == pytest.approx(-0.0758399 * math.exp(-0.18), rel=1e-5)


def test_downwash_is_capped_at_the_upper_drones_thrust():
    x = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.25]])
    assert upstream_downwash(0.25, 0.0) == pytest.approx(1.2135, rel=1e-4)  # 4.6 weights, unbounded below
    assert downwash_force_w(x, np.array([W, W]), P)[0, 2] == pytest.approx(-W)  # capped: the thrust above
    assert downwash_force_w(x, np.array([W, 0.0]), P)[0, 2] == 0.0  # motors off above: no wake
    half = AeroParams(downwash_cap_thrust_fraction=0.5)
    assert downwash_force_w(x, np.array([W, W]), half)[0, 2] == pytest.approx(-W / 2)
    # where the cap starts to bind for two hovering Crazyflies: alpha(dz) = W
    dz_cap = PROP_R / 4 * math.sqrt(DW1 / W)
    assert dz_cap == pytest.approx(0.535, abs=1e-3)
    for dz, capped in ((dz_cap - 0.01, True), (dz_cap + 0.01, False)):
        f = -downwash_force_w(np.array([[0, 0, 0.0], [0, 0, dz]]), np.array([W, W]), P)[0, 2]
        assert bool(f == pytest.approx(W)) == capped


def test_downwash_where_upstreams_width_vanishes_has_no_nan():
    dz = -DW3 / DW2  # beta = 0
    on_axis = downwash_force_w(np.array([[0, 0, 0.0], [0, 0, dz]]), np.array([W, 10.0]), P)
    assert on_axis[0, 2] == pytest.approx(-DW1 * (PROP_R / (4 * dz)) ** 2)  # the limit along the axis
    off_axis = downwash_force_w(np.array([[0, 0, 0.0], [0.01, 0, dz]]), np.array([W, 10.0]), P)
    assert off_axis[0, 2] == 0.0


def test_downwash_adds_up_over_the_drones_above_and_ignores_far_ones():
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.02, 0.0, 2.0], [11.0, 0.0, 1.0]])
    F = downwash_force_w(x, np.full(4, W), P)
    want = upstream_downwash(1.0, 0.0) + upstream_downwash(2.0, 0.02)
    assert F[0, 2] == pytest.approx(-want)
    assert F[1, 2] == pytest.approx(-upstream_downwash(1.0, 0.02))
    assert F[2, 2] == 0.0 and F[3, 2] == 0.0  # the highest, and one 11 m away from all


_coord = st.floats(-50, 50, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(_coord, _coord, _coord), min_size=1, max_size=8),
    st.lists(st.floats(0, 1), min_size=8, max_size=8),
)
@example(points=[(0.0, 0.0, 1e-176), (0.0, 5.0, 0.0)], thrusts=[0.0] * 8)  # inf * 0 once
@example(points=[(0.0, 0.0, 1e-176), (0.0, 0.0, 0.0)], thrusts=[0.3] * 8)
def test_downwash_is_finite_downward_bounded_and_zero_with_none_above(points, thrusts):
    x = np.array(points, float)
    T = np.array(thrusts[: len(points)])
    F = downwash_force_w(x, T, P)
    assert np.all(np.isfinite(F)) and np.all(F[:, :2] == 0.0) and np.all(F[:, 2] <= 0.0)
    for i in range(len(x)):
        above = x[:, 2] > x[i, 2]
        assert -F[i, 2] <= P.downwash_cap_thrust_fraction * T[above].sum() * (1 + 1e-12)
        if not above.any():
            assert F[i, 2] == 0.0


def hover_omega_sum() -> float:
    return 4 * math.sqrt((W / 4) / KF) * 2 * math.pi / 60  # rad/s


def test_rotor_drag_of_a_level_drone_by_hand():
    w = hover_omega_sum()
    assert w == pytest.approx(6063.6, rel=1e-4)  # 4 x 14476 rpm
    R = np.eye(3)[None]
    F = drag_force_w(R, np.array([[1.0, -0.5, 0.2]]), np.array([w]), P)
    assert F[0] == pytest.approx(-w * np.array([DRAG_XY * 1.0, DRAG_XY * -0.5, DRAG_Z * 0.2]), rel=1e-12)
    assert -F[0, 0] / W == pytest.approx(0.0210, abs=1e-4)  # 2.1 % of the weight per m/s


def test_rotor_drag_acts_in_the_body_frame():
    R = quat_to_R(euler_to_quat(0.3, -0.4, 1.1))
    v = np.array([0.7, -0.2, 0.5])
    F = drag_force_w(R[None], v[None], np.array([5000.0]), P)
    K = np.diag([DRAG_XY, DRAG_XY, DRAG_Z])
    assert F[0] == pytest.approx(-5000.0 * R @ K @ R.T @ v, rel=1e-12)
    # moving with the air: no drag
    assert np.all(drag_force_w(R[None], np.zeros((1, 3)), np.array([5000.0]), P) == 0.0)


def test_ground_effect_of_a_level_drone_by_hand():
    params = QuadParams()
    rotors = rotor_geometry(params)[0][None]
    f = np.array([[0.06, 0.07, 0.08, 0.05]])
    h = 0.3
    F, tau = ground_effect(np.array([[0.0, 0.0, h]]), np.eye(3)[None], f, rotors, P)
    gain = GND * (PROP_R / (4 * h)) ** 2
    assert F[0] == pytest.approx([0.0, 0.0, f.sum() * gain], rel=1e-12)
    g = f[0] * gain  # every rotor at the same height: unequal thrusts give unequal pushes, r x (0, 0, g)
    want = np.array([np.sum(rotors[0, :, 1] * g), -np.sum(rotors[0, :, 0] * g), 0.0])
    assert tau[0] == pytest.approx(want, rel=1e-9, abs=1e-18)


def test_ground_effect_clips_and_tilts():
    params = QuadParams()
    rotors = rotor_geometry(params)[0][None]
    f = np.full((1, 4), W / 4)
    F, _ = ground_effect(np.array([[0.0, 0.0, 0.001]]), np.eye(3)[None], f, rotors, P)
    assert F[0, 2] == pytest.approx(W * 4 / 15, rel=1e-12)  # at most 4/15 of the thrust
    assert P.ground_clip_m == pytest.approx(0.25 * PROP_R * math.sqrt(15 * GND / 4))
    # rolled: the rotors on the low side push harder, rolling the drone back up
    R = quat_to_R(euler_to_quat(0.3, 0.0, 0.0))  # right side (-y) down
    F, tau = ground_effect(np.array([[0.0, 0.0, 0.1]]), R[None], f, rotors, P)
    assert F[0] / np.linalg.norm(F[0]) == pytest.approx(R[:, 2])
    assert tau[0, 0] < 0.0  # torque about body x towards less roll
    upside_down = quat_to_R(euler_to_quat(math.pi, 0.0, 0.0))
    F, tau = ground_effect(np.array([[0.0, 0.0, 0.1]]), upside_down[None], f, rotors, P)
    assert np.all(F == 0.0) and np.all(tau == 0.0)


def test_downwash_acts_only_inside_the_wake():
    """Side by side, one a millimetre higher, a drone feels nothing (upstream's model gives a whole
    weight there); wholly inside the wake the model is upstream's; in between the force fades with
    the share of the lower drone's rotor discs inside the wake, the wake widening below the drone."""
    T = np.full(2, 0.265)

    def below(d_m: float, dz_m: float) -> float:
        return -downwash_force_w(np.array([[0.0, 0.0, 1.0], [d_m, 0.0, 1.0 + dz_m]]), T, P)[0, 2]

    reach = 2 * P.downwash_wake_radius_m
    assert below(0.25, 0.001) == 0.0 and below(reach + 1e-6, 1e-6) == 0.0
    assert below(0.0, 0.3) == pytest.approx(P.downwash_cap_thrust_fraction * 0.265)  # wholly inside, capped
    assert below(0.02, 1.0) == pytest.approx(upstream_downwash(1.0, 0.02))  # wholly inside, below the cap
    fading = [below(d, 0.3) for d in np.linspace(0.0, reach + 0.3 * P.downwash_wake_spread, 40)]
    assert all(a >= b for a, b in zip(fading, fading[1:], strict=False)) and fading[-1] == 0.0


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 0.5), st.floats(0.001, 0.3), st.floats(0.001, 0.3))
def test_the_share_inside_the_wake_is_a_fraction_and_exact_at_its_ends(d, r_b, r_w):
    from swarm.realism.aero import _inside_fraction

    f = _inside_fraction(d, r_b, r_w)
    assert 0.0 <= f <= 1.0
    if d >= r_b + r_w:
        assert f == 0.0
    if d + r_b <= r_w:
        assert f == 1.0
    # by sampling the lower disc
    g = np.random.default_rng(0).uniform(-1, 1, (4000, 2))
    g = g[(g**2).sum(1) <= 1] * r_b
    inside = (((g - [d, 0.0]) ** 2).sum(1) <= r_w**2).mean()
    assert f == pytest.approx(inside, abs=0.04)


# --- the measured downwash (AeroParams.downwash_model = "measured") ---------------------------

M = AeroParams(downwash_model="measured")
T_CF = 0.032 * 9.81  # N: the 32 g Crazyflie of the Neural-Swarm logs, hovering above
# (dz [m], d [m], mean force [gf]) from the Neural-Swarm logs (swarm.realism.aero.downwash_force_w)
NEURAL_SWARM_GF = [
    (0.275, 0.011, 9.02),
    (0.275, 0.030, 7.16),
    (0.279, 0.051, 4.78),
    (0.278, 0.070, 3.09),
    (0.277, 0.090, 1.54),
    (0.313, 0.012, 9.74),
    (0.322, 0.029, 7.93),
    (0.324, 0.049, 6.48),
    (0.323, 0.070, 3.86),
    (0.323, 0.091, 1.70),
    (0.377, 0.011, 7.72),
    (0.376, 0.030, 6.41),
    (0.377, 0.050, 5.36),
    (0.375, 0.070, 3.51),
    (0.375, 0.090, 1.91),
    (0.412, 0.011, 6.15),
    (0.413, 0.031, 6.57),
    (0.415, 0.050, 5.09),
    (0.416, 0.071, 3.52),
    (0.416, 0.091, 2.10),
]


def measured(dz: float, d: float, T: float = T_CF, p: AeroParams = M) -> float:
    """The downward force [N] on a drone ``dz`` below and ``d`` beside one of thrust ``T``."""
    return -downwash_force_w(np.array([[0.0, 0.0, 1.0], [d, 0.0, 1.0 + dz]]), np.array([T, T]), p)[0, 2]


@pytest.mark.parametrize("dz, d, gf", NEURAL_SWARM_GF)
def test_measured_downwash_is_the_neural_swarm_data_within_1_25_gf(dz, d, gf):
    # the largest residual is 1.2 gf (dz 0.41 m on the axis: 18 samples, standard error 0.47 gf); RMS 0.49 gf
    assert measured(dz, d) / 9.81 * 1000 == pytest.approx(gf, abs=1.25)


def test_measured_downwash_rms_residual_is_half_a_gram():
    res = [measured(dz, d) / 9.81 * 1000 - gf for dz, d, gf in NEURAL_SWARM_GF]
    assert math.sqrt(np.mean(np.square(res))) < 0.6


def test_measured_downwash_is_a_third_of_upstreams_or_less_and_not_capped():
    """0.285 of the thrust above at 0.3 m (upstream: the whole cap), 0.11 at 1 m (upstream: 0.29)."""
    assert measured(0.3, 0.0, W) / W == pytest.approx(0.285, abs=0.002)
    assert measured(1.0, 0.0, W) / W == pytest.approx(0.107, abs=0.002)
    assert measured(0.27, 0.0, W) / W == pytest.approx(0.301, abs=0.002)
    assert measured(0.05, 0.0, W) == measured(0.27, 0.0, W)  # held above the fitted range
    assert -downwash_force_w(np.array([[0, 0, 0.0], [0, 0, 0.3]]), np.array([W, W]), P)[0, 2] == pytest.approx(W)


def test_measured_wake_widens_with_depth_and_conserves_its_momentum():
    def width_m(dz: float) -> float:  # where the force falls to exp(-1/2) of the axis value
        lo, hi = 0.0, 1.0
        for _ in range(60):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if measured(dz, mid) > measured(dz, 0.0) * math.exp(-0.5) else (lo, mid)
        return lo

    widths = [width_m(dz) for dz in (0.3, 0.5, 1.0, 2.0)]
    assert all(a < b for a, b in zip(widths, widths[1:], strict=False))
    assert widths[0] == pytest.approx(M.downwash_measured_width0_m + 0.3 * M.downwash_measured_spread_m_per_m, rel=1e-6)
    # the force integrated over the plane below is the same at every depth in and below the fitted range
    r = np.linspace(0.0, 1.5, 30001)
    totals = []
    for dz in (0.3, 0.5, 1.0):
        f = np.array([measured(dz, x) for x in r[::50]])
        totals.append(np.trapezoid(2 * np.pi * r[::50] * f, r[::50]))
    assert totals == pytest.approx([T_CF * M.downwash_measured_area_m2] * 3, rel=1e-3)


def test_measured_downwash_is_zero_above_and_beside():
    assert measured(0.0, 0.0) == 0.0 and measured(-0.3, 0.0) == 0.0 and measured(-1e-9, 0.0) == 0.0
    assert measured(1e-6, 0.12) < 0.001 * T_CF  # side by side, 12 cm apart: 0.09 % of the thrust
    assert measured(0.5, 0.0, 0.0) == 0.0  # motors off above: no wake


def test_measured_downwash_has_no_needle():
    """5 mm off the axis is within 1 % of the axis value at 0.5 m (upstream's width is zero at 0.69 m)."""
    for dz in (0.3, 0.5, 0.69, 1.0):
        assert measured(dz, 0.005) == pytest.approx(measured(dz, 0.0), rel=0.01)
    assert upstream_downwash(0.69, 0.005) < 1e-10 * upstream_downwash(0.69 + 1e-3, 0.0)


def test_measured_downwash_scales_with_the_thrust_above_and_adds_up():
    assert measured(0.4, 0.03, 2 * T_CF) == pytest.approx(2 * measured(0.4, 0.03))
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.4], [0.05, 0.0, 0.9]])
    F = downwash_force_w(x, np.full(3, T_CF), M)
    assert F[0, 2] == pytest.approx(-(measured(0.4, 0.0) + measured(0.9, 0.05)))
    assert F[1, 2] == pytest.approx(-measured(0.5, 0.05)) and F[2, 2] == 0.0
    assert np.all(F[:, :2] == 0.0)


def test_the_default_downwash_is_upstreams_bit_for_bit():
    from swarm.realism.settings import AeroSettings

    assert AeroSettings().params().downwash_model == "gym_pybullet" == P.downwash_model
    rng = np.random.default_rng(3)
    x = rng.uniform(-0.5, 0.5, (12, 3))
    T = rng.uniform(0.0, 0.4, 12)
    got = downwash_force_w(x, T, P)
    want = np.zeros_like(x)
    for i in range(12):
        for j in range(12):
            dz = x[j, 2] - x[i, 2]
            if j == i or dz <= 0:
                continue
            d = math.hypot(x[j, 0] - x[i, 0], x[j, 1] - x[i, 1])
            inside = _inside_fraction_py(
                d, P.downwash_wake_radius_m, P.downwash_wake_radius_m + P.downwash_wake_spread * dz
            )
            if inside == 0.0:
                continue
            want[i, 2] -= min(upstream_downwash(dz, d), P.downwash_cap_thrust_fraction * T[j] * inside)
    assert np.array_equal(got, want)


def _inside_fraction_py(d: float, r_b: float, r_w: float) -> float:
    from swarm.realism.aero import _inside_fraction

    return float(_inside_fraction.py_func(d, r_b, r_w))


def test_an_unknown_downwash_model_is_refused():
    with pytest.raises(ValueError, match="downwash_model"):
        downwash_force_w(np.zeros((2, 3)), np.ones(2), AeroParams(downwash_model="cfd"))
    from pydantic import ValidationError

    from swarm.realism.settings import AeroSettings

    with pytest.raises(ValidationError):
        AeroSettings(downwash_model="cfd")
    off = {"downwash": False, "drag": False, "ground_effect": False}  # the settings' defaults
    assert AeroSettings(downwash_model="measured").params() == AeroParams(downwash_model="measured", **off)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(_coord, _coord, _coord), min_size=1, max_size=8),
    st.lists(st.floats(0, 1), min_size=8, max_size=8),
)
@example(points=[(0.0, 0.0, 1e-176), (0.0, 0.0, 0.0)], thrusts=[0.3] * 8)
def test_measured_downwash_is_finite_downward_and_zero_with_none_above(points, thrusts):
    x = np.array(points, float)
    T = np.array(thrusts[: len(points)])
    F = downwash_force_w(x, T, M)
    assert np.all(np.isfinite(F)) and np.all(F[:, :2] == 0.0) and np.all(F[:, 2] <= 0.0)
    for i in range(len(x)):
        above = x[:, 2] > x[i, 2]
        assert -F[i, 2] <= 0.31 * T[above].sum() * (1 + 1e-12)  # at most 0.30 of the thrust above
        if not above.any():
            assert F[i, 2] == 0.0


@settings(max_examples=200, deadline=None)
@given(st.floats(1e-3, 5.0), st.floats(0.0, 2.0), st.floats(1e-3, 2.0))
def test_measured_downwash_decays_monotonically_off_the_axis(dz, d, step):
    assert measured(dz, d + step) <= measured(dz, d)
    if d > 1.0 + 0.5 * dz:  # far off the axis (over 10 widths): nothing left
        assert measured(dz, d) < 1e-12
