"""The horizon allowance of live rows (swarm.safety.barriers, "Horizon allowance") by its definition.

``h_tau = <p, w> + |w| s + s^2 / (2 tau)`` (``s = sqrt(|P p|^2 - r^2)``):

* every live row's h is a lower bound of ``h_tau``, equal to it above ``live_hi_mps`` outside
  the cone, with the gradient of ``h_tau`` there (finite differences);
* a relative acceleration that satisfies a row keeps ``h_tau`` above the row's
  ``h (1 - gamma dt)`` along the motion, and above the blend speed satisfies the exact
  ``h_tau' + gamma h_tau >= 0`` (finite difference of the exact ``h_tau``);
* the set ``h_tau >= 0`` is collision-free: a pair whose relative acceleration is the
  nearest one to a reference that the row admits never comes inside its safety radius."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from swarm.errors import InputError
from swarm.safety.barriers import LIVE_W_HI_MPS
from swarm.safety.filter import FilterConfig

from .helpers import central_gradients, closest_approach, directions, live_rows, outside, proj, satisfying, vec

GAMMA = 1.0
tau_s = st.floats(0.5, 20.0)
axis_or_none = st.one_of(
    st.just(np.zeros(3)), vec.filter(lambda a: np.linalg.norm(a) > 0.1).map(lambda a: a / np.linalg.norm(a))
)


def exact_h_tau(p, w, r, a, tau):
    P, W = proj(a, p), proj(a, w)
    s2 = P @ P - r * r
    return P @ W + np.linalg.norm(W) * math.sqrt(s2) + s2 / (2 * tau)


def rows(p, w, r, a, a_ref, tau, nb=False):
    return live_rows(p, w, r, a, a_ref, nb, horizon_s=tau)


@settings(max_examples=500, deadline=None)
@given(
    p=vec,
    w=vec,
    w_scale=st.sampled_from([0.0, 1e-9, 1e-3, 0.01, 1.0]),
    r=st.floats(0.05, 1.0),
    a=axis_or_none,
    a_ref=st.one_of(st.none(), vec),
    tau=tau_s,
    acc=vec,
    nb=st.booleans(),
)
def test_a_row_bounds_h_tau_from_below_and_keeps_it_along_the_motion(p, w, w_scale, r, a, a_ref, tau, acc, nb):
    p = outside(p, r, a)
    assume(p is not None)
    w = w * w_scale
    row = rows(p, w, r, a, a_ref, tau, nb)
    h_row, h_tau = row.h[0], exact_h_tau(p, w, r, a, tau)
    assert h_row <= h_tau + 1e-12 * (1 + abs(h_tau))
    plain = rows(p, w, r, a, a_ref, None, nb)  # the live row without the allowance
    s2 = proj(a, p) @ proj(a, p) - r * r
    assert h_row == pytest.approx(plain.h[0] + s2 / (2 * tau), rel=1e-12, abs=1e-12)  # the same row, plus (2)
    # a relative acceleration that satisfies the row, d held: h_tau stays above h_row (1 - gamma dt)
    acc = satisfying(row.dh_dw[0], row.dh_dp[0] @ w + GAMMA * h_row, acc)
    dt = 1e-4
    later = exact_h_tau(p + dt * w + 0.5 * dt * dt * acc, w + dt * acc, r, a, tau)
    scale = (1 + np.linalg.norm(w) + np.linalg.norm(acc)) ** 2 * (1 + np.linalg.norm(p)) * (1 + 1 / tau)
    assert later >= h_row * (1 - GAMMA * dt) - 50 * scale * dt * dt


@settings(max_examples=400, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 1.0), a=axis_or_none, tau=tau_s, acc=vec)
def test_above_the_blend_speed_outside_the_cone_the_row_is_the_exact_h_tau_condition(p, w, r, a, tau, acc):
    p = outside(p, r, a)
    assume(p is not None)
    P, W = proj(a, p), proj(a, w)
    assume(np.linalg.norm(W) >= 2 * LIVE_W_HI_MPS)
    assume(P @ W + np.linalg.norm(W) * math.sqrt(P @ P - r * r) >= 1e-6)  # outside the cone
    row = rows(p, w, r, a, None, tau)
    h = exact_h_tau(p, w, r, a, tau)
    assert row.h[0] == pytest.approx(h, rel=1e-9, abs=1e-12)
    num = central_gradients(lambda p, w: exact_h_tau(p, w, r, a, tau), p, w)  # the gradient of h_tau
    for grad, fd in zip((row.dh_dp[0], row.dh_dw[0]), num, strict=True):
        np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-5)
    # an admitted acceleration satisfies h_tau' + gamma h_tau >= 0 (central difference along the motion)
    acc = satisfying(row.dh_dw[0], row.dh_dp[0] @ w + GAMMA * h, acc)
    dt = 1e-5
    h_plus = exact_h_tau(p + dt * w + 0.5 * dt * dt * acc, w + dt * acc, r, a, tau)
    h_minus = exact_h_tau(p - dt * w + 0.5 * dt * dt * acc, w - dt * acc, r, a, tau)
    rate = (h_plus - h_minus) / (2 * dt)
    scale = (1 + np.linalg.norm(w) + np.linalg.norm(acc)) ** 2 * (1 + np.linalg.norm(p))
    assert rate + GAMMA * h >= -1e-4 * scale


@settings(max_examples=60, deadline=None)
@given(
    direction=directions,
    dist=st.floats(1.5, 4.0),
    r=st.floats(0.1, 0.6),
    tau=tau_s,
    speed=st.floats(0.2, 0.9),  # of the allowance's head-on bound: strictly inside it
    pull=arrays(np.float64, 3, elements=st.floats(-1, 1)),
)
def test_flying_on_the_row_from_inside_the_cone_never_enters_the_safety_radius(direction, dist, r, tau, speed, pull):
    """A pair in relative coordinates (``p`` = obstacle minus agent) that starts on a
    collision course the allowance admits (``h < 0 < h_tau``), the agent pulled at the
    obstacle (1 m/s^2, plus ``pull``), its relative acceleration every 5 ms the nearest one
    to that reference that the row admits. (Touching the radius is the cone's own limit,
    a grazing contact; a step of 5 ms at up to 3 m/s overshoots it by a millimetre or two.)"""
    d = direction / np.linalg.norm(direction)
    s = math.sqrt(dist * dist - r * r)
    v = min(speed * s * s / (2 * tau * (dist - s)), 3.0)  # head on, below the allowance's bound
    a = np.zeros(3)
    p, w = dist * d, -v * d
    assert exact_h_tau(p, w, r, a, tau) > 0 > p @ w + v * s  # inside the cone, admitted
    closest = closest_approach(
        lambda p, w, ref: rows(p, w, r, a, ref, tau),
        p,
        w,
        lambda p, w: -(p / np.linalg.norm(p) + pull),  # w' = -(agent's acceleration): a static obstacle
        GAMMA,
        800,  # 4 s
    )
    assert closest > r - 2e-3


def test_the_horizon_is_checked_where_it_is_set():
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(InputError, match="horizon_s"):
            FilterConfig(horizon_s=bad)


@settings(max_examples=200, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 1.0), a=axis_or_none, a_ref=st.one_of(st.none(), vec), tau=tau_s, tau_all=tau_s)
def test_the_obstacle_horizon_is_the_horizon_of_obstacle_rows_alone(p, w, r, a, a_ref, tau, tau_all):
    """``obstacle_horizon_s`` gives an obstacle row the allowance ``horizon_s`` would, and
    leaves a neighbour's row as it is (with ``horizon_s`` as well: its own for each)."""
    p = outside(p, r, a)
    assume(p is not None)
    for nb in (False, True):
        obs_only = live_rows(p, w, r, a, a_ref, nb, obstacle_horizon_s=tau)
        expect = live_rows(p, w, r, a, a_ref, nb, horizon_s=None if nb else tau)
        np.testing.assert_array_equal(obs_only.coef, expect.coef)
        both = live_rows(p, w, r, a, a_ref, nb, horizon_s=tau_all, obstacle_horizon_s=tau)
        expect = live_rows(p, w, r, a, a_ref, nb, horizon_s=tau_all if nb else tau)
        np.testing.assert_array_equal(both.coef, expect.coef)


def test_the_obstacle_horizon_is_checked_where_it_is_set():
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(InputError, match="obstacle_horizon_s"):
            FilterConfig(obstacle_horizon_s=bad)
