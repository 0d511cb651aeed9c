"""The contact horizon of live neighbour rows (swarm.safety.barriers, "Contact horizon") by its definition.

``h_T = <p, w> + |w| S``, ``S = sqrt(|p|^2 - rho^2)``, ``rho = r (1 - (1 - k) psi(t_c))``,
``t_c = (|p| - r) / v_c`` the time to contact at the closing speed ``v_c = -<p, w>/|p|``
(infinite when not closing), ``psi`` the smoothstep from 0 at ``t_c = T`` to 1 at ``2 T``,
``k = CONTACT_FLOOR``:

* a live neighbour row's h is a lower bound of ``h_T``, equal to it above ``live_hi_mps``
  outside the relaxed cone, with the gradient of ``h_T`` there (finite differences, which
  check the terms of ``rho``'s own dependence on p and w);
* a relative acceleration that satisfies a row keeps ``h_T`` above the row's
  ``h (1 - gamma dt)`` along the motion, and above the blend speed satisfies the exact
  ``h_T' + gamma h_T >= 0``;
* the row is the plain live row where contact is nearer than ``T`` and for obstacles;
* the set ``h_T >= 0`` is collision-free: pairs pulled at each other from rest, or closing
  head on, flown on their rows, never come inside their safety radius."""

import math

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from swarm.config import FilterSettings
from swarm.errors import InputError
from swarm.safety.barriers import CONTACT_FLOOR, LIVE_W_HI_MPS
from swarm.safety.filter import FilterConfig

from .helpers import central_gradients, closest_approach, directions, live_rows, outside, satisfying, vec

GAMMA = 1.0
SPHERE = np.zeros(3)  # no cylinder axis
T_s = st.floats(0.3, 3.0)


def rho_of(p, w, r, T):
    """The relaxed radius [m], straight from the definition."""
    pw = p @ w
    with np.errstate(over="ignore", divide="ignore"):  # (a closing speed of 1e-300 m/s: t_c infinite)
        tc = (np.linalg.norm(p) - r) / (-pw / np.linalg.norm(p)) if pw < 0 else math.inf
        x = min(max(tc / T - 1.0, 0.0), 1.0)
    return r * (1.0 - (1.0 - CONTACT_FLOOR) * x * x * (3.0 - 2.0 * x))


def exact_h_T(p, w, r, T):
    rho = rho_of(p, w, r, T)
    return p @ w + np.linalg.norm(w) * math.sqrt(p @ p - rho * rho)


def rows(p, w, r, a_ref, T, nb=True):
    return live_rows(p, w, r, SPHERE, a_ref, nb, contact_s=T)


@settings(max_examples=500, deadline=None)
@given(
    p=vec,
    w=vec,
    w_scale=st.sampled_from([0.0, 1e-9, 1e-3, 0.01, 0.1, 1.0]),
    r=st.floats(0.05, 1.0),
    a_ref=st.one_of(st.none(), vec),
    T=T_s,
    acc=vec,
)
def test_a_row_bounds_h_T_from_below_and_keeps_it_along_the_motion(p, w, w_scale, r, a_ref, T, acc):
    p = outside(p, r, SPHERE)
    assume(p is not None)
    w = w * w_scale
    row = rows(p, w, r, a_ref, T)
    h_row, h_T = row.h[0], exact_h_T(p, w, r, T)
    assert h_row <= h_T + 1e-12 * (1 + abs(h_T))
    # a relative acceleration that satisfies the row, d held: h_T stays above h_row (1 - gamma dt)
    acc = satisfying(row.dh_dw[0], row.dh_dp[0] @ w + GAMMA * h_row, acc)
    dt = 1e-5
    later = exact_h_T(p + dt * w + 0.5 * dt * dt * acc, w + dt * acc, r, T)
    scale = (1 + np.linalg.norm(w) + np.linalg.norm(acc)) ** 2 * (1 + np.linalg.norm(p)) * (1 + 1 / T) ** 2
    assert later >= h_row * (1 - GAMMA * dt) - 1e3 * scale * dt * dt


@settings(max_examples=500, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 1.0), T=T_s, acc=vec)
# a closing speed of 5e-324 m/s: the time to contact's denominator underflowed to 0 (ZeroDivisionError)
@example(p=np.array([-5e-324, 2.0, 0.0]), w=np.array([1.0, 0.0, 1.0]), r=1.0, T=0.5, acc=np.zeros(3))
def test_above_the_blend_speed_outside_the_cone_the_row_is_the_exact_h_T_condition(p, w, r, T, acc):
    p = outside(p, r, SPHERE)
    assume(p is not None)
    assume(np.linalg.norm(w) >= 2 * LIVE_W_HI_MPS)
    assume(exact_h_T(p, w, r, T) >= 1e-6)  # outside the relaxed cone
    row = rows(p, w, r, None, T)
    h = exact_h_T(p, w, r, T)
    assert row.h[0] == pytest.approx(h, rel=1e-9, abs=1e-12)
    num = central_gradients(lambda p, w: exact_h_T(p, w, r, T), p, w)  # rho's terms included
    for grad, fd in zip((row.dh_dp[0], row.dh_dw[0]), num, strict=True):
        np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-5 * (1 + 1 / T))
    # an admitted acceleration satisfies h_T' + gamma h_T >= 0 (central difference along the motion)
    acc = satisfying(row.dh_dw[0], row.dh_dp[0] @ w + GAMMA * h, acc)
    dt = 1e-6
    h_plus = exact_h_T(p + dt * w + 0.5 * dt * dt * acc, w + dt * acc, r, T)
    h_minus = exact_h_T(p - dt * w + 0.5 * dt * dt * acc, w - dt * acc, r, T)
    rate = (h_plus - h_minus) / (2 * dt)
    scale = (1 + np.linalg.norm(w) + np.linalg.norm(acc)) ** 2 * (1 + np.linalg.norm(p)) * (1 + 1 / T)
    assert rate + GAMMA * h >= -1e-4 * scale


@settings(max_examples=300, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 1.0), a_ref=st.one_of(st.none(), vec), T=T_s)
def test_near_contact_and_for_obstacles_the_row_is_the_plain_live_row(p, w, r, a_ref, T):
    p = outside(p, r, SPHERE)
    assume(p is not None)
    plain = rows(p, w, r, a_ref, 0.0)
    obstacle = rows(p, w, r, a_ref, T, nb=False)  # only neighbour rows relax
    np.testing.assert_array_equal(obstacle.coef, rows(p, w, r, a_ref, 0.0, nb=False).coef)
    if rho_of(p, w, r, T) == r:  # contact within T: the full cone
        np.testing.assert_array_equal(rows(p, w, r, a_ref, T).coef, plain.coef)


def test_a_slow_collision_course_is_admitted_and_a_fast_one_is_not():
    """Two agents 1 m apart (r = 0.2 m) on a collision course that misses by 0.1 m: closing
    at 0.1 m/s (contact in 8 s) the row lets the agent keep accelerating at the other, as
    the cone alone does not; closing at 1 m/s (contact in 0.8 s < T = 1 s) it is the
    cone's row and forbids it."""
    p, r, pull = np.array([1.0, 0.1, 0.0]), 0.2, np.array([-1.0, 0.0, 0.0])  # w' = -(agent's acceleration)
    for v, admitted in ((0.1, True), (1.0, False)):
        w = np.array([-v, 0.0, 0.0])
        for T, relaxed in ((1.0, admitted), (0.0, False)):
            row = rows(p, w, r, pull, T)
            ok = bool(row.dh_dw[0] @ pull + row.dh_dp[0] @ w + GAMMA * row.h[0] >= 0)
            assert ok is relaxed, (v, T)


@settings(max_examples=60, deadline=None)
@given(
    direction=directions,
    dist=st.floats(0.5, 4.0),
    r=st.floats(0.1, 0.6),
    T=T_s,
    w0=st.one_of(st.just(np.zeros(3)), arrays(np.float64, 3, elements=st.floats(-2, 2))),
    pull=arrays(np.float64, 3, elements=st.floats(-1, 1)),
    gain=st.floats(1.0, 3.0),
)
def test_flying_on_the_row_at_the_other_never_enters_the_safety_radius(direction, dist, r, T, w0, pull, gain):
    """A pair in relative coordinates, starting in the safe set (``h_T >= 0``: at rest, or
    any relative velocity ``w0`` the row admits, slow collision courses included), the agent
    pulled straight at the other (3 m/s^2, plus ``pull``), its relative acceleration every
    5 ms the nearest one to that reference that the row admits. (Touching the radius is the
    cone's own limit, a grazing contact; a step of 5 ms overshoots it by a millimetre or two.)"""
    d = direction / np.linalg.norm(direction)
    assume(dist > r + 0.1)
    p, w = dist * d, w0
    assume(exact_h_T(p, w, r, T) >= 0)
    pulled = closest_approach(
        lambda p, w, ref: rows(p, w, r, ref, T),
        p,
        w,
        lambda p, w: -3.0 * (p / np.linalg.norm(p) + pull),
        gain,
        1200,  # 6 s
    )
    assert pulled > r - 2e-3


def test_the_contact_horizon_is_checked_where_it_is_set():
    for bad in (-1.0, math.inf, math.nan):
        with pytest.raises(InputError, match="contact_s"):
            FilterConfig(contact_s=bad)
        with pytest.raises(ValueError, match="contact_s"):
            FilterSettings(contact_s=bad)
    assert FilterConfig(contact_s=0.0).contact_s == 0.0
