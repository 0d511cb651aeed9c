"""The live rows' velocity buffer (swarm.safety.constraints, "Velocity buffer") by its definition.

A row's buffered form asks ``h' + g k h >= g k_b v |dh/dw|`` (``g k`` the row's class-K gain,
``k`` the far-neighbour factor, ``v = min(buffer, BUFFER_PER_SPEED |w|)``), so:

* the buffer is that term, times the row's share (and for a neighbour row with h > 0 the
  far-neighbour factor, at most BUFFER_FAR_GAIN_MAX), and nothing inside a safety radius or
  at zero relative velocity; a command that holds the buffered rows holds the rows;
* with the exact h (finite difference along the motion) a relative acceleration that
  holds a buffered row gives ``h' + gamma h >= gamma v |dh/dw|``;
* the filter keeps the buffer where it can and falls back to the rows themselves, still
  OK, where the buffered rows cannot all hold (a pinwheel of neighbours on their cones);
* in closed loop, the perturbed 8-drone circle that needed least-violation ticks without
  the buffer (21 for seed 1 at commit dd98862) flies with none, as ``swarm scenario``
  writes it (gamma 2, buffer 0.1 m/s) and with the defaults of a hand-written config
  (gamma 1, buffer 0.05 m/s).
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from swarm.config import WorldSettings, resolve
from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.offline.closed_loop import fly_scenario, outcome
from swarm.offline.scenario import SwapSettings, circle_swap
from swarm.safety.barriers import RATE
from swarm.safety.constraints import BUFFER_FAR_GAIN_MAX, BUFFER_PER_SPEED
from swarm.safety.filter import FilterConfig, FilterStatus, SafetyFilter
from swarm.safety.obstacles import ObstacleArrays

from .helpers import outside, satisfying, vec

MODEL = QuadModel()
MASS = MODEL.params.mass_kg
G = MODEL.params.g_mps2
HOVER = np.array([0.0, 0.0, MASS * G])  # N, world: the attitude level's hover command


def attitude_filter(**kw: object) -> SafetyFilter:
    return SafetyFilter(MODEL, FilterConfig(level=CommandLevel.ATTITUDE, floor_z_m=None, **kw))


def one_obstacle(c, cd, r, nb=False) -> ObstacleArrays:
    """One sphere of radius ``r`` [m] at ``c`` [m] moving at ``cd`` [m/s]; ``nb``: another agent."""
    return ObstacleArrays.build(np.array([c]), np.array([r]), np.array([cd]), is_neighbour=np.array([nb]))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31),
    n=st.integers(1, 10),
    buffer=st.sampled_from([0.0, 0.02, 0.05, 0.3]),
    rho=st.sampled_from([1.0, 0.5]),
    gamma=st.sampled_from([1.0, 2.5]),
    at_rest=st.booleans(),
)
def test_the_buffer_is_its_definition_and_only_tightens(seed, n, buffer, rho, gamma, at_rest):
    rng = np.random.default_rng(seed)
    filt = attitude_filter(buffer_mps=buffer, rho=rho, gamma=gamma)
    state = QuadState.hover(rng.uniform(-0.5, 0.5, 3) + [0, 0, 1.0])
    v = np.zeros(3) if at_rest else rng.uniform(-1.5, 1.5, 3)
    state.v_w = v.copy()
    c = state.x_w + rng.uniform(-2.0, 2.0, (n, 3))
    cd = np.tile(v, (n, 1)) if at_rest else rng.uniform(-1.5, 1.5, (n, 3))  # at rest: w = 0 for every row
    nb = rng.random(n) < 0.5
    radii = rng.uniform(0.05, 0.4, n)
    obs = ObstacleArrays.build(c, radii, cd, is_neighbour=nb)
    u_ref = HOVER + rng.uniform(-0.1, 0.1, 3)
    rows = filt.rows(state, obs, u_ref)
    bar = rows.barrier
    W = bar.Y[:, 1]
    # the same scene with half the buffer, and (for the shares) with each agent taking it all
    half = attitude_filter(buffer_mps=buffer / 2, rho=rho, gamma=gamma).rows(state, obs, u_ref).buffer
    whole = attitude_filter(buffer_mps=buffer, rho=1.0, gamma=gamma).rows(state, obs, u_ref).buffer
    for i in range(n):
        if bar.inside[i] or buffer == 0.0:
            assert rows.buffer[i] == 0.0
            continue
        if not nb[i] and bar.Y[i, 0] @ W[i] > 0.0:  # moving away from a still obstacle: no buffer to keep
            assert rows.buffer[i] == 0.0
            continue
        speed = float(np.linalg.norm(W[i]))
        # the buffer speed is min(buffer, BUFFER_PER_SPEED |w|): linear in buffer_mps below the cap ...
        if buffer <= BUFFER_PER_SPEED * speed:
            assert rows.buffer[i] == pytest.approx(2 * half[i], rel=1e-9, abs=1e-15)
        elif buffer / 2 >= BUFFER_PER_SPEED * speed:  # ... and no more above it
            assert rows.buffer[i] == pytest.approx(half[i], rel=1e-9, abs=1e-15)
        # a neighbour's share inside the cone; outside the cone the allowance is the agent's whole
        share = rho if nb[i] and bar.h[i] <= 0.0 else 1.0
        assert rows.buffer[i] == pytest.approx(share * whole[i], rel=1e-9, abs=1e-15)
        # never more than the largest gain times the buffer speed times |dh/dw|
        cap = max(gamma, bar.coef[i, RATE]) * BUFFER_FAR_GAIN_MAX * min(buffer, BUFFER_PER_SPEED * speed)
        assert rows.buffer[i] <= cap * np.linalg.norm(bar.dh_dw[i]) * (1 + 1e-9)
    assert (rows.buffer >= 0.0).all() and np.isfinite(rows.buffer).all()
    if at_rest:
        assert (rows.buffer == 0.0).all()  # nothing to keep a buffer against: a swarm at rest stays put
    # every command that holds the buffered rows holds the rows
    for _ in range(20):
        u = HOVER + rng.uniform(-0.3, 0.3, 3)
        if (rows.G @ u <= rows.b - rows.buffer).all():
            assert (rows.G @ u <= rows.b).all()


def exact_h(p, w, r):
    return p @ w + np.linalg.norm(w) * math.sqrt(p @ p - r * r)


@settings(max_examples=400, deadline=None)
@given(p=vec, w=vec, r_obstacle=st.floats(0.0, 0.5), acc=vec, buffer=st.sampled_from([0.02, 0.05, 0.3]))
def test_a_buffered_row_keeps_the_exact_h_a_buffer_above_its_condition(p, w, r_obstacle, acc, buffer):
    """A static sphere seen from a drone at the attitude level, above the blend speed and
    outside the cone, where a live row is the exact row, closing on it (moving away from a
    still obstacle keeps no buffer): a relative acceleration that holds the buffered row
    gives the exact ``h' + gamma h >= gamma v |dh/dw|``."""
    filt = attitude_filter(buffer_mps=buffer)
    r = r_obstacle + filt.r_own_m  # the row's safety radius [m]
    p = outside(p, r, np.zeros(3))
    assume(p is not None)
    assume(
        np.linalg.norm(w) > 0.05 and exact_h(p, w, r) > 1e-3 and p @ w < -1e-9 * np.linalg.norm(p) * np.linalg.norm(w)
    )
    state = QuadState.hover(np.zeros(3))
    state.v_w = -w  # w = c' - x_b' with the sphere at rest
    obstacle = one_obstacle(p + filt._own(state).xv_b[0], np.zeros(3), r_obstacle)
    rows = filt.rows(state, obstacle)
    # the relative acceleration a = -(F/m - g e3), moved onto the buffered row's half-space
    Lg, lower, buf = rows.Lg_h[0], rows.lower[0], rows.buffer[0]
    F = satisfying(Lg, -(lower + buf), HOVER - MASS * acc)  # Lg F - lower - buf >= 0
    a = G * np.array([0.0, 0.0, 1.0]) - F / MASS
    dt = 1e-5  # a central difference along the motion: error of order dt^2
    later = exact_h(p + dt * w + 0.5 * dt * dt * a, w + dt * a, r)
    earlier = exact_h(p - dt * w + 0.5 * dt * dt * a, w - dt * a, r)
    rate = (later - earlier) / (2 * dt)
    s = math.sqrt(p @ p - r * r)
    grad_w = p + s * w / np.linalg.norm(w)  # the exact dh/dw
    want = min(buffer, BUFFER_PER_SPEED * np.linalg.norm(w)) * np.linalg.norm(grad_w)
    scale = (1 + np.linalg.norm(w) + np.linalg.norm(a)) * (1 + np.linalg.norm(p))
    tol = 1e-6 * scale  # rounding of the difference quotient and of the QP row
    assume(tol < 0.01 * want)  # (the tolerance is far below the term it tests)
    assert rate + exact_h(p, w, r) >= want - tol


def pinwheel() -> tuple[QuadState, ObstacleArrays]:
    """A drone at rest with three neighbours 1 m away at 120 degrees, each gliding along its
    collision cone's boundary in the same turning sense (h = 0): the buffered rows' normals
    surround the drone, so no command keeps every buffer, but hovering holds every row."""
    state = QuadState.hover([0.0, 0.0, 1.0])
    r = 2 * MODEL.params.body_radius_m + 0.02
    c, cd = [], []
    for k in range(3):
        th = 2 * math.pi * k / 3
        u_p = np.array([math.cos(th), math.sin(th), 0.0])
        t = np.array([-math.sin(th), math.cos(th), 0.0])
        s = math.sqrt(1.0 - r * r)
        c.append(state.x_w + MODEL.params.l_m * np.array([0, 0, 1.0]) + u_p)
        cd.append(0.8 * (-s * u_p + r * t))  # along the cone's generator: h = 0
    obs = ObstacleArrays.build(
        np.array(c), np.full(3, MODEL.params.body_radius_m), np.array(cd), is_neighbour=np.ones(3, bool)
    )
    return state, obs


def test_the_filter_keeps_the_buffer_where_it_can_and_the_rows_where_it_cannot():
    filt = attitude_filter()
    # one neighbour closing head on: the buffered rows hold, with their margin
    state = QuadState.hover([0.0, 0.0, 1.0])
    ahead = one_obstacle([2.0, 0.05, 1.0 + MODEL.params.l_m], [-1.0, 0.0, 0.0], MODEL.params.body_radius_m, nb=True)
    res = filt.filter(state, HOVER, ahead)
    assert res.status is FilterStatus.OK and res.buffered
    assert res.buffer[0] > 0.0 and res.constraint[0] >= res.buffer[0] - 1e-9
    assert res.active[0]  # it binds at its buffer
    # the pinwheel: every row at h = 0, the buffers cannot all hold, the rows can
    state, obs = pinwheel()
    res = filt.filter(state, HOVER, obs)
    assert np.abs(res.h).max() < 1e-9 and (res.buffer > 0).all()
    assert res.status is FilterStatus.OK and not res.buffered
    assert res.constraint.min() >= -1e-9
    # the same without a buffer: the rows alone, OK at once
    plain = attitude_filter(buffer_mps=0.0).filter(state, HOVER, obs)
    assert plain.status is FilterStatus.OK and plain.buffered and (plain.buffer == 0).all()


_GRAZING = pytest.mark.xfail(
    strict=True,
    reason="a known defect: at the paper's gain, with the keep-out ellipsoid and the neighbours' states of tick "
    "k-1, two drones crossing one over the other at 1.5 m/s graze the ellipsoid's top and a tick flies the "
    "least-violation command (no contact, no margin violation; CHANGELOG, Known issues)",
)


@pytest.mark.parametrize(
    ("gains", "seed"),
    [("generated", 1), ("generated", 2), pytest.param("defaults", 1, marks=_GRAZING), ("defaults", 2)],
)
def test_a_perturbed_circle_swap_from_rest_flies_without_a_least_violation_tick(seed, gains):
    raw = circle_swap(8, 2.0, SwapSettings(perturb_m=0.05, seed=seed))
    if gains == "defaults":
        for key in ("gamma", "buffer_mps"):
            del raw["defaults"]["filter"][key]
    cfg = resolve(raw)
    want = (2.0, 0.1) if gains == "generated" else (1.0, 0.1)
    assert all((a.filter.gamma, a.filter.buffer_mps) == want for a in cfg.agents)
    log = fly_scenario(cfg.model_copy(update={"world": WorldSettings()}))
    o = outcome(cfg, log)
    assert o.success and o.collisions == 0 and o.deadlocked == 0
    assert o.infeasible_ticks == 0
