"""What the rows hold of the paper's rate h' >= -gamma h (swarm.safety.barriers: "Far
neighbours", "Free braking", inside the cone), measured by its definition: the effective gain
-h'/h of the exact h along the motion a row admits.

* far gain: a neighbour row allows ``h' >= -gamma k h`` with ``k <= max(1, R / (2 r))`` within
  the sensing radius ``R`` (9.4 gamma at the defaults), and reaches it;
* free braking: ``h' >= -(gamma k + lambda |w'| / |w|) h``, far above gamma at low speed;
* inside the cone: ``|H(t)| <= |H(0)| exp(-2 int dt / T_c)``, ``(1 - t / T_0)^2`` at a held
  closing speed; still inside at half the time to contact."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.safety.barriers import (
    BRAKE_CLOSING_MPS,
    FAR_GAIN_RADII,
    LIVE_W_HI_MPS,
    RATE,
    BarrierKind,
    evaluate_pw,
    far_gain,
)
from swarm.safety.filter import FilterConfig, SafetyFilter
from swarm.safety.obstacles import ObstacleArrays

from .helpers import satisfying, vec

GAMMA = 1.0


@settings(max_examples=300, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 0.5), R=st.floats(0.5, 5.0))
def test_the_far_gain_is_at_most_the_sensing_radius_over_two_radii(p, w, r, R):
    d = float(np.linalg.norm(p))
    assume(r * 1.01 < d <= R)
    assert 1.0 <= far_gain(p, w, r) <= max(1.0, R / (FAR_GAIN_RADII * r)) + 1e-12


def test_a_neighbour_rows_effective_gain_reaches_nine_gamma_at_the_defaults():
    """Through the filter (defaults: sensing radius 3 m, safety radius 0.16 m across; free
    braking off so the row is h' + gamma k h >= 0): the lowest h' a neighbour row admits,
    over h, is gamma k; a neighbour at the sensing radius drifting away reaches k = R / (2 r)."""
    filt = SafetyFilter(QuadModel(), FilterConfig(level=CommandLevel.ATTITUDE, free_braking=False, buffer_mps=0.0))
    R, r = 3.0, 0.16
    bound = R / (FAR_GAIN_RADII * r)
    rng = np.random.default_rng(4)
    gains = []
    for _ in range(300):
        state = QuadState.hover([0.0, 0.0, 1.0])
        state.v_w = rng.normal(0, 0.5, 3)
        d = rng.normal(size=3)
        c = state.x_w + d / np.linalg.norm(d) * rng.uniform(0.3, R - 0.02)
        obs = ObstacleArrays.build(c, [0.07], rng.normal(0, 0.5, 3), is_neighbour=[True])
        rows = filt.rows(state, obs)
        if rows.inside[0] or rows.h[0] <= 1e-9:
            continue
        gains.append((rows.b[0] - rows.Lf_h[0]) / rows.h[0] / GAMMA)  # the row: h' >= -(b - Lf) ... = -g h
    assert max(gains) <= bound + 1e-9
    state = QuadState.hover([0.0, 0.0, 1.0])
    away = ObstacleArrays.build(state.x_w + [R - 1e-6, 0, 0], [0.07], [0.3, 0, 0], is_neighbour=[True])
    rows = filt.rows(state, away)
    assert (rows.b[0] - rows.Lf_h[0]) / rows.h[0] == pytest.approx(bound * GAMMA, rel=1e-5)  # 9.4 gamma


def _exact_hdot(p, w, r, acc):
    """h' of the exact C3BF along the relative acceleration ``acc`` (the live row above
    ``w_hi`` without free braking is the exact cone row: its gradients are h's)."""
    exact = evaluate_pw(BarrierKind.C3BF, p[None], w[None], np.array([r]), live=True, a_ref=acc[None])
    return exact.h[0], exact.dh_dp[0] @ w + exact.dh_dw[0] @ acc


@settings(max_examples=400, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 0.5), brake=st.floats(0.5, 10.0), side=vec)
def test_free_braking_keeps_h_but_lets_it_fall_at_gamma_plus_lambda_w_dot_over_w(p, w, r, brake, side):
    """Every relative acceleration a free-braking row admits (a braking reference moved onto
    its half-space) has ``h' >= -(gamma + lambda |w'| / |w|) h`` of the exact h."""
    assume(np.linalg.norm(p) > r * 1.05 and np.linalg.norm(w) > 2 * LIVE_W_HI_MPS)
    u = w / np.linalg.norm(w)
    a_ref = -brake * u + 0.3 * side  # braking (<w, a_ref> < 0 for these)
    assume(w @ a_ref < 0)
    row = evaluate_pw(
        BarrierKind.C3BF, p[None], w[None], np.array([r]), live=True, a_ref=a_ref[None], free_braking=True
    )
    assume(row.h[0] > 1e-6 and not row.inside[0])
    acc = satisfying(row.dh_dw[0], row.dh_dp[0] @ w + GAMMA * row.h[0], a_ref)
    h, hdot = _exact_hdot(p, w, r, acc)
    lam = min(1.0, max(0.0, 1.0 + (p @ w) / np.linalg.norm(p) / BRAKE_CLOSING_MPS))
    bound = GAMMA + lam * np.linalg.norm(acc) / np.linalg.norm(w)
    assert -hdot <= bound * h * (1 + 1e-9) + 1e-9


def test_free_braking_lets_h_fall_far_faster_than_gamma_at_low_speed():
    """3 cm/s beside an obstacle, the reference braking at 5 m/s^2: admitted whole, the exact
    h falls at more than 100 gamma (the paper's row would hold it to gamma)."""
    p, w, r = np.array([1.0, 0.6, 0.0]), np.array([0.0, 0.03, 0.0]), 0.3
    a_ref = np.array([0.0, -5.0, 0.0])
    fb = evaluate_pw(BarrierKind.C3BF, p[None], w[None], np.array([r]), live=True, a_ref=a_ref[None], free_braking=True)
    acc = satisfying(fb.dh_dw[0], fb.dh_dp[0] @ w + GAMMA * fb.h[0], a_ref)
    np.testing.assert_allclose(acc, a_ref)  # braking is free
    h, hdot = _exact_hdot(p, w, r, acc)
    assert -hdot / h > 100 * GAMMA
    assert -hdot / h <= GAMMA + np.linalg.norm(acc) / np.linalg.norm(w)
    plain = evaluate_pw(BarrierKind.C3BF, p[None], w[None], np.array([r]), live=True, a_ref=a_ref[None])
    acc = satisfying(plain.dh_dw[0], plain.dh_dp[0] @ w + GAMMA * plain.h[0], a_ref)
    assert -_exact_hdot(p, w, r, acc)[1] / h == pytest.approx(GAMMA, rel=1e-6)  # the paper's rate, held


def test_inside_the_cone_the_violation_shrinks_with_the_time_to_contact_squared():
    """A pair inside the cone, closing at 1 m/s 1.5 s from contact, flown on its row with
    the least relative acceleration it admits (the row binding: H' = g |H|, g = max(gamma,
    2 / T_c)): |H| follows |H(0)| exp(-2 int dt / T_c) (the bound, met with equality), and is
    still a quarter or more of |H(0)| at half the time to contact: the row does not leave
    the cone within half the time to contact."""
    r = 0.5
    p, w = np.array([2.0, 0.0, 0.0]), np.array([-1.0, 0.05, 0.0])
    t0 = (np.linalg.norm(p) - r) / 1.0

    def row(p, w):
        return evaluate_pw(BarrierKind.C3BF, p[None], w[None], np.array([r]), live=True, a_ref=np.zeros((1, 3)))

    H0 = row(p, w).h[0]
    assert H0 < 0
    dt, t, integral = 1e-3, 0.0, 0.0
    while t < 0.5 * t0 - 1e-9:
        rw = row(p, w)
        H, g = rw.h[0], max(GAMMA, rw.coef[0, RATE])
        v_c = -(p @ w) / np.linalg.norm(p)
        assert g == pytest.approx(max(GAMMA, 2 * v_c / (np.linalg.norm(p) - r)))
        assert abs(H) <= abs(H0) * math.exp(-integral) * (1 + 1e-3)
        acc = satisfying(rw.dh_dw[0], rw.dh_dp[0] @ w + g * H, np.zeros(3))
        integral += 2 * dt * v_c / (np.linalg.norm(p) - r)
        p, w, t = p + w * dt + 0.5 * acc * dt * dt, w + acc * dt, t + dt
    H_half = row(p, w).h[0]
    assert H_half < 0 and abs(H_half) >= 0.25 * abs(H0) * 0.98  # (1 - 1/2)^2, as the pair closes at ~its speed
    assert abs(H_half) == pytest.approx(abs(H0) * math.exp(-integral), rel=1e-2)
