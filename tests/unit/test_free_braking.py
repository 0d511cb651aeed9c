"""Free braking of live rows (swarm.safety.barriers, "Free braking") by its definition.

A live row (a neighbour's or an obstacle's) outside its cone, above the blend speed, whose reference's relative
acceleration brakes ``w`` (``<w, a_ref> < 0``) is the condition of ``B = h / |w|^lambda``,
``lambda = max(0, min(1, 1 - v_c / BRAKE_CLOSING_MPS))`` (``v_c = -<p, w>/|p|``), times
``|w|^lambda``; every other row is the plain live row:

* its gradient is ``|w|^lambda`` times B's (finite differences), and a relative
  acceleration that satisfies it satisfies the exact ``B' + gamma B >= 0``;
* braking along ``w`` leaves a row with ``lambda = 1`` unchanged;
* on the cone (``h = 0``) it is the plain row, so ``h >= 0`` stays invariant; rows
  inside the cone, references that do not brake and pairs closing fast keep the plain
  row; an obstacle's row is a neighbour's, as above the blend speed both are the cone's;
* a drift away from a neighbour may be braked as fast as the reference asks (the plain
  row forbids it), and the filter, at rho 0.5 among hovering neighbours, passes such a
  reference unchanged;
* pairs pulled at each other and braking, flown on their rows, never come inside their
  safety radius."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from swarm.config import FilterSettings
from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.safety.barriers import BRAKE_CLOSING_MPS, LIVE_W_HI_MPS
from swarm.safety.filter import FilterConfig, FilterStatus, SafetyFilter
from swarm.safety.obstacles import ObstacleArrays

from .helpers import central_gradients, closest_approach, directions, live_rows, outside, satisfying, vec

GAMMA = 1.0
SPHERE = np.zeros(3)  # no cylinder axis


def exact_h(p, w, r):
    return p @ w + np.linalg.norm(w) * math.sqrt(p @ p - r * r)


def lam_of(p, w, a_ref):
    """lambda from the definition (0 where the reference does not brake)."""
    if w @ a_ref >= 0:
        return 0.0
    closing = -(p @ w) / np.linalg.norm(p)
    return min(1.0, max(0.0, 1.0 - closing / BRAKE_CLOSING_MPS))


def exact_B(p, w, r, lam):
    return exact_h(p, w, r) / np.linalg.norm(w) ** lam


def rows(p, w, r, a_ref, free=True, nb=True):
    return live_rows(p, w, r, SPHERE, a_ref, nb, free_braking=free)


@settings(max_examples=500, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 1.0), a_ref=vec, acc=vec, nb=st.booleans())
def test_the_row_is_the_exact_condition_of_h_over_a_power_of_the_speed(p, w, r, a_ref, acc, nb):
    p = outside(p, r, SPHERE)
    assume(p is not None)
    assume(np.linalg.norm(w) >= 2 * LIVE_W_HI_MPS)
    assume(exact_h(p, w, r) >= 1e-6)  # outside the cone
    lam = lam_of(p, w, a_ref)
    row = rows(p, w, r, a_ref, nb=nb)
    scale = np.linalg.norm(w) ** lam
    assert row.h[0] == pytest.approx(exact_h(p, w, r), rel=1e-9, abs=1e-12)
    num = central_gradients(lambda p, w: exact_B(p, w, r, lam), p, w)  # |w|^lambda times B's gradient
    tol = 1e-5 * (1 + np.linalg.norm(p)) * (1 + 1 / np.linalg.norm(w))
    for grad, fd in zip((row.dh_dp[0], row.dh_dw[0]), num, strict=True):
        np.testing.assert_allclose(grad, scale * fd, rtol=1e-5, atol=tol)
    # an admitted relative acceleration satisfies B' + gamma B >= 0 (central difference along the motion)
    acc = satisfying(row.dh_dw[0], row.dh_dp[0] @ w + GAMMA * row.h[0], acc)
    dt = 1e-6
    B_plus = exact_B(p + dt * w + 0.5 * dt * dt * acc, w + dt * acc, r, lam)
    B_minus = exact_B(p - dt * w + 0.5 * dt * dt * acc, w - dt * acc, r, lam)
    rate = (B_plus - B_minus) / (2 * dt)
    size = (1 + np.linalg.norm(w) + np.linalg.norm(acc)) ** 2 * (1 + np.linalg.norm(p)) / scale
    assert rate + GAMMA * exact_B(p, w, r, lam) >= -1e-4 * size


@settings(max_examples=300, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 1.0), brake=st.floats(0.1, 5.0), other=vec, nb=st.booleans())
def test_braking_along_w_is_free_where_lambda_is_one(p, w, r, brake, other, nb):
    p = outside(p, r, SPHERE)
    assume(p is not None)
    assume(np.linalg.norm(w) >= 2 * LIVE_W_HI_MPS and p @ w >= 0)  # receding or sliding past: lambda = 1
    assume(exact_h(p, w, r) >= 1e-6)
    a_ref = -brake * w / np.linalg.norm(w)
    row = rows(p, w, r, a_ref, nb=nb)
    assert row.dh_dw[0] @ w == pytest.approx(0.0, abs=1e-9 * (1 + np.linalg.norm(p)) * (1 + np.linalg.norm(w)))
    # so a braking component added to any admitted acceleration keeps it admitted
    acc = satisfying(row.dh_dw[0], row.dh_dp[0] @ w + GAMMA * row.h[0], other)
    gap = row.dh_dw[0] @ (acc + a_ref) + row.dh_dp[0] @ w + GAMMA * row.h[0]
    assert gap >= -1e-9 * (1 + np.linalg.norm(p)) * (1 + np.linalg.norm(w) + brake + np.linalg.norm(other))


@settings(max_examples=300, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 1.0), a_ref=st.one_of(st.none(), vec))
def test_every_other_row_is_the_plain_live_row(p, w, r, a_ref):
    p = outside(p, r, SPHERE)
    assume(p is not None)
    h = exact_h(p, w, r)
    nw = np.linalg.norm(w)
    for nb in (True, False):
        plain = rows(p, w, r, a_ref, free=False, nb=nb)
        if a_ref is None or nw < LIVE_W_HI_MPS or h < 0 or lam_of(p, w, a_ref) == 0.0:
            np.testing.assert_array_equal(rows(p, w, r, a_ref, nb=nb).coef, plain.coef)
    if nw >= LIVE_W_HI_MPS:  # the cone's row either way: an obstacle's is a neighbour's
        np.testing.assert_array_equal(rows(p, w, r, a_ref, nb=False).coef, rows(p, w, r, a_ref).coef)


@settings(max_examples=300, deadline=None)
@given(direction=vec, r=st.floats(0.05, 1.0), dist=st.floats(0.1, 3.0), side=vec, a_ref=vec, acc=vec)
def test_on_the_cone_the_row_is_the_plain_one(direction, r, dist, side, a_ref, acc):
    """At h = 0 (w on a boundary generator) both rows ask h' >= 0 of every acceleration."""
    assume(np.linalg.norm(direction) > 0.1)
    p = (r + dist) * direction / np.linalg.norm(direction)
    t = side - (side @ p) / (p @ p) * p  # across p
    assume(np.linalg.norm(t) > 0.1)
    s = math.sqrt(p @ p - r * r)
    gen = -(s / np.linalg.norm(p)) * p / np.linalg.norm(p) + (r / np.linalg.norm(p)) * t / np.linalg.norm(t)
    w = 0.5 * gen  # a generator of the cone: h = 0
    assert abs(exact_h(p, w, r)) < 1e-9
    free, plain = rows(p, w, r, a_ref), rows(p, w, r, a_ref, free=False)
    lhs = [x.dh_dw[0] @ acc + x.dh_dp[0] @ w for x in (free, plain)]
    assert lhs[0] == pytest.approx(lhs[1], abs=1e-6 * (1 + np.linalg.norm(acc)) * (1 + np.linalg.norm(p)))


def test_a_drift_away_from_a_neighbour_may_be_braked_at_once():
    """An agent drifting at 0.3 m/s away from a hovering neighbour 1.2 m off (r = 0.2 m), its
    reference braking at 2 m/s^2: the plain row lets the relative speed decay only at about
    gamma and forbids it; with free braking it is admitted. A pair closing fast (2 m/s),
    or slowly inside the cone, keeps the plain row."""
    p, r = np.array([1.0, 0.6, 0.0]), 0.2
    w = np.array([0.3, 0.0, 0.0])  # = -(the agent's velocity): receding
    a_ref = np.array([-2.0, 0.0, 0.0])  # = -(the agent's acceleration): braking the drift
    admitted = []
    for free in (False, True):
        row = rows(p, w, r, a_ref, free=free)
        admitted.append(bool(row.dh_dw[0] @ a_ref + row.dh_dp[0] @ w + GAMMA * row.h[0] >= 0))
    assert admitted == [False, True]
    closing = np.array([-2.0, 0.0, 0.0])
    np.testing.assert_array_equal(rows(p, closing, r, -a_ref).coef, rows(p, closing, r, -a_ref, free=False).coef)
    inside = np.array([-0.2, -0.1, 0.0])  # closing slowly inside the cone (h < 0): the plain row
    assert exact_h(p, inside, r) < 0 and inside @ -a_ref < 0
    np.testing.assert_array_equal(rows(p, inside, r, -a_ref).coef, rows(p, inside, r, -a_ref, free=False).coef)


def test_the_filter_lets_a_drifting_agent_brake_as_its_reference_asks():
    """An agent drifting at 0.3 m/s away from three hovering neighbours 1.2 to 1.4 m off, at
    rho = 0.5, its reference braking at 2 m/s^2 (attitude level: the thrust vector [N,
    world]): with free braking the command is the reference; with the cone's rows the filter
    keeps less than half of the braking."""
    model = QuadModel()
    m, g = model.params.mass_kg, model.params.g_mps2
    u_ref = m * np.array([2.0, 0.0, g])
    braking = {}
    for free in (False, True):
        filt = SafetyFilter(model, FilterConfig(level=CommandLevel.ATTITUDE, rho=0.5, free_braking=free))
        agent = QuadState.hover([0.0, 0.0, 1.0])
        agent.v_w = np.array([-0.3, 0.0, 0.0])
        centres = np.array([[1.0, 0.6, 1.0], [1.0, -0.6, 1.0], [1.3, 0.0, 1.4]]) + [0.0, 0.0, model.params.l_m]
        others = ObstacleArrays.build(centres, [filt.r_own_m] * 3, np.zeros((3, 3)), is_neighbour=[True] * 3)
        res = filt.filter(agent, u_ref, others)
        assert res.status is FilterStatus.OK and (res.h > 0).all()
        braking[free] = res.u[0] / m  # m/s^2 along +x
    assert braking[True] == pytest.approx(2.0, rel=1e-6)
    assert braking[False] < 0.5 * 2.0


@settings(max_examples=60, deadline=None)
@given(
    direction=directions,
    dist=st.floats(0.5, 4.0),
    r=st.floats(0.1, 0.6),
    w0=st.one_of(st.just(np.zeros(3)), arrays(np.float64, 3, elements=st.floats(-2, 2))),
    pull=arrays(np.float64, 3, elements=st.floats(-1, 1)),
    brake=st.floats(0.0, 6.0),
    gain=st.floats(1.0, 3.0),
)
def test_flying_on_the_row_at_the_other_never_enters_the_safety_radius(direction, dist, r, w0, pull, brake, gain):
    """A pair in relative coordinates from any admitted start (h >= 0), the agent pulled at
    the other (3 m/s^2, plus ``pull``) and braking the relative velocity at ``brake`` [1/s],
    every 5 ms the nearest relative acceleration its row admits. (Touching the radius is the
    cone's grazing contact; a 5 ms step overshoots it by a millimetre or two.)"""
    d = direction / np.linalg.norm(direction)
    assume(dist > r + 0.1)
    p, w = dist * d, w0
    assume(exact_h(p, w, r) >= 0)
    pulled = closest_approach(
        lambda p, w, ref: rows(p, w, r, ref),
        p,
        w,
        lambda p, w: -3.0 * (p / np.linalg.norm(p) + pull) - brake * w,
        gain,
        1200,  # 6 s
    )
    assert pulled > r - 2e-3


def test_free_braking_is_on_by_default_and_can_be_turned_off():
    assert FilterConfig().free_braking is True
    assert FilterSettings().free_braking is True
    off = FilterSettings(free_braking=False)
    assert off.filter_config(FilterConfig().level).free_braking is False
