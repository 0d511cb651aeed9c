"""The safety filter by residuals and the barrier condition (hypothesis properties)."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarm.errors import InputError
from swarm.model import CommandLevel, QuadModel, QuadParams, QuadState
from swarm.safety.barriers import BarrierKind
from swarm.safety.filter import FilterConfig, FilterStatus, SafetyFilter
from swarm.safety.obstacles import ObstacleArrays

from .helpers import random_state

MODEL = QuadModel()
FILTERS = {
    (level, backend, kind): SafetyFilter(MODEL, FilterConfig(level=level, backend=backend, kind=kind, rho=0.5))
    for level in CommandLevel
    for backend in ("daqp", "osqp")
    for kind in BarrierKind
}


def scene(seed: int, n: int, level: CommandLevel):
    rng = np.random.default_rng(seed)
    state = random_state(rng, rates=1.0)
    c = state.x_w + rng.uniform(-2.0, 2.0, (n, 3))
    obs = ObstacleArrays.build(
        c,
        rng.uniform(0.05, 0.4, n),
        rng.uniform(-1.5, 1.5, (n, 3)),
        axis_w=np.where(rng.random((n, 1)) < 0.3, rng.normal(size=(n, 3)), 0.0),
        is_neighbour=rng.random(n) < 0.4,
    )
    if level is CommandLevel.ROTORS:
        u_ref = rng.uniform(0.0, MODEL.params.f_max_N, 4)
    else:
        u_ref = np.array([*rng.uniform(-0.15, 0.15, 2), rng.uniform(0.1, 0.5)])
    return state, obs, u_ref


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31),
    n=st.integers(0, 12),
    level=st.sampled_from(list(CommandLevel)),
    backend=st.sampled_from(["daqp", "osqp"]),
    kind=st.sampled_from(list(BarrierKind)),
)
def test_filter_result_satisfies_rows_and_bounds(seed, n, level, backend, kind):
    state, obs, u_ref = scene(seed, n, level)
    filt = FILTERS[(level, backend, kind)]
    res = filt.filter(state, u_ref, obs)
    assert np.isfinite(res.u).all() and np.isfinite(res.h).all() and np.isfinite(res.slack).all()
    rows = filt.rows(state, obs.subset(res.row_index), u_ref)
    residual = rows.Lg_h @ res.u - rows.lower  # >= 0 means the barrier condition holds
    np.testing.assert_allclose(residual, res.constraint, atol=1e-12)
    assert filt.input_set.violation(res.u) <= 1e-6
    if res.status is FilterStatus.OK:
        assert residual.min(initial=0.0) >= -1e-6
        assert res.slack.max(initial=0.0) == 0.0
        if not res.active.any() and filt.input_set.contains(u_ref):
            np.testing.assert_array_equal(res.u, u_ref)
    else:
        assert res.status in (FilterStatus.INFEASIBLE, FilterStatus.COLLISION)
        assert (res.slack >= 0).all()
        # the slack says by how much each row is violated
        np.testing.assert_allclose(np.maximum(-residual, 0.0), res.slack, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(1, 10), level=st.sampled_from(list(CommandLevel)))
def test_backends_agree_on_the_optimum(seed, n, level):
    state, obs, u_ref = scene(seed, n, level)
    a = FILTERS[(level, "daqp", BarrierKind.C3BF)].filter(state, u_ref, obs)
    b = FILTERS[(level, "osqp", BarrierKind.C3BF)].filter(state, u_ref, obs)
    if a.status is FilterStatus.OK and b.status is FilterStatus.OK:
        cost_a, cost_b = np.sum((a.u - u_ref) ** 2), np.sum((b.u - u_ref) ** 2)
        assert abs(cost_a - cost_b) <= 1e-6 * max(1e-6, cost_a)


def test_feasible_reference_passes_unchanged():
    filt = SafetyFilter(MODEL)
    state = QuadState.hover()
    state.v_w = np.array([-0.5, -0.5, 0.0])  # moving away from both: h > 0
    obs = ObstacleArrays.build([[5.0, 0.0, 1.0], [0.0, 4.0, 1.0]], [0.3, 0.3])
    u_ref = np.full(4, MODEL.params.weight_N / 4)
    res = filt.filter(state, u_ref, obs)
    assert res.status is FilterStatus.OK and not res.active.any()
    assert res.u is u_ref or np.array_equal(res.u, u_ref)
    assert res.intervention == 0.0 and res.min_h >= 0.0


def test_infeasible_rows_give_a_flagged_least_violation_command():
    """Two obstacles closing in from opposite sides faster than the drone can react."""
    filt = SafetyFilter(MODEL, FilterConfig(level=CommandLevel.ATTITUDE))
    state = QuadState.hover()
    obs = ObstacleArrays.build(
        [[0.6, 0, 1.0], [-0.6, 0, 1.0], [0, 0.6, 1], [0, -0.6, 1]],
        [0.2] * 4,
        [[-4.0, 0, 0], [4.0, 0, 0], [0, -4, 0], [0, 4, 0]],
    )
    res = filt.filter(state, np.array([0, 0, MODEL.params.weight_N]), obs)
    assert res.status is FilterStatus.INFEASIBLE
    assert np.isfinite(res.u).all() and res.slack.max() > 0
    assert filt.input_set.contains(res.u, 1e-9)


def test_inside_an_obstacle_commands_the_escape():
    filt = SafetyFilter(MODEL, FilterConfig(level=CommandLevel.ATTITUDE))
    state = QuadState.hover()
    obs = ObstacleArrays.build([0.1, 0.0, 1.0], [0.2])  # 0.1 m away, radius 0.2: inside
    res = filt.filter(state, np.array([0, 0, MODEL.params.weight_N]), obs)
    assert res.status is FilterStatus.COLLISION and res.inside.all()
    assert res.u[0] < 0  # pushes away from the obstacle at +x
    assert np.isfinite(res.u).all()


def test_sensing_radius_and_row_limit():
    filt = SafetyFilter(MODEL, FilterConfig(sensing_radius_m=2.0, max_rows=3))
    state = QuadState.hover()
    c = np.array([[1.0, 0, 1], [3.0, 0, 1], [0, 1.5, 1], [0, -1.2, 1], [0, 0, 2.9]])
    nb = ObstacleArrays.build(c, [0.1] * 5, is_neighbour=[True] * 5)
    assert sorted(filt.select(state, nb).tolist()) == [0, 2, 3]  # within 2 m, nearest 3
    static = ObstacleArrays.build(c, [0.1] * 5)
    with pytest.raises(InputError, match="max_rows"):
        filt.filter(state, np.full(4, 0.066), static)


def _select_by_definition(c, is_nb, x, radius, max_rows):
    """The row selection as the docs state it, in plain numpy: every non-neighbour, the
    neighbours within ``radius``, and of those only the nearest (stable) while rows remain."""
    d2 = ((c - x) ** 2).sum(axis=1)
    keep = ~is_nb | (d2 <= radius**2)
    idx = np.flatnonzero(keep)
    if idx.size <= max_rows:
        return idx
    fixed = np.flatnonzero(~is_nb)
    near = np.flatnonzero(keep & is_nb)
    near = near[np.argsort(d2[near], kind="stable")[: max_rows - fixed.size]]
    return np.sort(np.concatenate([fixed, near]))


@settings(max_examples=300, deadline=None)
@given(
    st.integers(0, 12),
    st.integers(1, 6),
    st.floats(0.5, 3.0),
    st.integers(0, 2**32 - 1),
    st.booleans(),
)
def test_row_selection_matches_its_definition(n, max_rows, radius, seed, ties):
    rng = np.random.default_rng(seed)
    c = rng.uniform(-3, 3, (n, 3))
    if ties and n:  # equal distances: the earlier index must win
        c[:] = c[0]
    is_nb = rng.random(n) < 0.7
    filt = SafetyFilter(MODEL, FilterConfig(sensing_radius_m=radius, max_rows=max_rows))
    state = QuadState.hover([0.1, -0.2, 0.3])
    obs = ObstacleArrays.build(c.reshape(-1, 3), [0.1] * n, is_neighbour=is_nb)
    if (~is_nb).sum() > max_rows:
        with pytest.raises(InputError, match="max_rows"):
            filt.select(state, obs)
    else:
        want = _select_by_definition(c, is_nb, state.x_w, radius, max_rows)
        np.testing.assert_array_equal(filt.select(state, obs), want)


@pytest.mark.parametrize(
    "make",
    [
        lambda: SafetyFilter(MODEL).filter(
            QuadState(np.array([0, 0, np.nan]), np.zeros(3), np.array([0, 0, 0, 1.0]), np.zeros(3)),
            np.full(4, 0.06),
            ObstacleArrays.empty(),
        ),
        lambda: SafetyFilter(MODEL).filter(
            QuadState(np.zeros(3), np.array([np.inf, 0, 0]), np.array([0, 0, 0, 1.0]), np.zeros(3)),
            np.full(4, 0.06),
            ObstacleArrays.empty(),
        ),
        lambda: SafetyFilter(MODEL).filter(QuadState.hover(), np.array([0.1, np.nan, 0, 0]), ObstacleArrays.empty()),
        lambda: ObstacleArrays.build([1.0, 0, 0], [-0.1]),
        lambda: ObstacleArrays.build([1.0, np.nan, 0], [0.1]),
        lambda: QuadModel(QuadParams(mass_kg=0.0)),
        lambda: FilterConfig(max_rows=0),
        lambda: FilterConfig(gamma=-1.0),
        lambda: FilterConfig(rho=0.0),
        lambda: FilterConfig(backend="nope") and SafetyFilter(MODEL, FilterConfig(backend="nope")),
    ],
)
def test_bad_input_raises_a_specific_error(make):
    with pytest.raises(InputError) as err:
        make()
    assert str(err.value)  # names the field and the reason


def test_reciprocal_rows_add_up_to_the_pair_condition():
    """rho = 0.5: the two agents' rows sum to the pair's h' + kappa(h) >= 0, kappa(h) =
    2 gamma h outside the cone (each agent keeps its row's whole allowance) and gamma h
    inside it (the recovery shared; swarm.safety.constraints, "Responsibility share"). The paper's
    smoothed rows, whose formula this spells out, on both sides of the cone (the sphere: the
    keep-out ellipsoid's pair is in test_keep_out.py)."""
    cfg = FilterConfig(level=CommandLevel.ATTITUDE, rho=0.5, live=False, ellipsoid=False)
    filt = SafetyFilter(MODEL, cfg)
    signs = set()
    for v_b in ([-1.0, -0.3, -0.1], [-1.0, 1.5, 0.0]):  # head on, inside the cone; outside it
        signs.add(_pair_sum_is_the_pair_condition(filt, cfg, np.array(v_b)))
    assert signs == {-1.0, 1.0}


def _pair_sum_is_the_pair_condition(filt: SafetyFilter, cfg: FilterConfig, v_b: np.ndarray) -> float:
    """Checks the sum of the two rows for agent b flying ``v_b`` [m/s, world] at agent a
    (flying +x at 1 m/s); returns the sign of h."""
    a, b = QuadState.hover([0, 0, 1]), QuadState.hover([2.0, 0.3, 1.1])
    a.v_w, b.v_w = np.array([1.0, 0, 0]), v_b
    r_nb = filt.r_own_m  # each agent of the pair as big as the filter keeps itself
    up = np.array([0.0, 0.0, MODEL.params.l_m])  # each reports its body centre (level: l above the centre)
    ra = filt.rows(a, ObstacleArrays.build(b.x_w + up, [r_nb], b.v_w, is_neighbour=[True]))
    rb = filt.rows(b, ObstacleArrays.build(a.x_w + up, [r_nb], a.v_w, is_neighbour=[True]))
    assert ra.h[0] == pytest.approx(rb.h[0], rel=1e-12)  # h symmetric in the pair
    rng = np.random.default_rng(0)
    Fa, Fb = rng.uniform(0.1, 0.4, 3), rng.uniform(0.1, 0.4, 3)
    lhs = (ra.Lg_h[0] @ Fa - ra.lower[0]) + (rb.Lg_h[0] @ Fb - rb.lower[0])
    # the pair's true h' with both accelerations: w' = a_b - a_a (gravity cancels)
    p, w = b.x_w - a.x_w, b.v_w - a.v_w
    acc = (Fb - Fa) / MODEL.params.mass_kg
    s = math.sqrt(p @ p - (2 * r_nb) ** 2)
    nw = math.sqrt(w @ w + cfg.eps_w_mps**2) - cfg.eps_w_mps
    dh_dp = w + nw / s * p
    dh_dw = p + s * w / math.sqrt(w @ w + cfg.eps_w_mps**2)
    kappa = (2.0 if ra.h[0] > 0 else 1.0) * cfg.gamma * ra.h[0]
    assert lhs == pytest.approx(dh_dp @ w + dh_dw @ acc + kappa, rel=1e-9)
    return float(np.sign(ra.h[0]))


def kkt_residual(filt: SafetyFilter, state, obs, u_ref, res) -> tuple[float, float]:
    """(stationarity residual, scale) of the filter's QP at ``res.u`` from the QP's own
    definition, min |u - u_ref|^2 s.t. the barrier rows (their buffered form where the
    command holds it) and the input set, independently of either solver: multipliers of
    the active constraints by non-negative least squares."""
    from scipy.optimize import nnls

    rows = filt.rows(state, obs.subset(res.row_index), u_ref)
    ins = filt.input_set
    u, m = res.u, filt.m
    # every constraint as  a_i . u <= c_i
    a_all = np.vstack([-rows.Lg_h.reshape(-1, m), ins.C.reshape(-1, m), np.eye(m), -np.eye(m)])
    lower = rows.lower + (res.buffer if res.buffered else 0.0)  # the buffered rows ask Lg_h u >= lower + buffer
    c_all = np.concatenate([-lower, ins.d, ins.ub, -ins.lb])
    scale = 1.0 + np.abs(a_all).sum(axis=1) * (1.0 + np.abs(u).max())
    active = a_all @ u - c_all >= -1e-7 * scale
    grad = 2.0 * (u - u_ref)  # of |u - u_ref|^2: the identity cost the filter is defined with
    if not active.any():
        return float(np.abs(grad).max()), 1.0 + float(np.abs(u_ref).max())
    _lam, r = nnls(a_all[active].T, -grad)
    return float(r), 1.0 + float(np.linalg.norm(grad))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31),
    n=st.integers(0, 12),
    level=st.sampled_from(list(CommandLevel)),
    kind=st.sampled_from(list(BarrierKind)),
)
def test_the_command_is_the_optimum_by_the_kkt_conditions(seed, n, level, kind):
    """Optimality, not only feasibility: at an OK command the cost's gradient is a
    non-negative combination of the active constraints' normals (KKT), with the cost
    matrix the filter is defined with (a scaled one would fail)."""
    state, obs, u_ref = scene(seed, n, level)
    filt = FILTERS[(level, "daqp", kind)]
    res = filt.filter(state, u_ref, obs)
    if res.status is not FilterStatus.OK:
        return
    r, scale = kkt_residual(filt, state, obs, u_ref, res)
    assert r <= 1e-6 * scale, (r, scale)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31),
    n_obs=st.integers(1, 3),
    n_nb=st.integers(1, 3),
    level=st.sampled_from(list(CommandLevel)),
)
def test_where_the_rows_cannot_all_hold_the_obstacles_rows_hold_before_the_neighbours(seed, n_obs, n_nb, level):
    """Obstacles closing in from one side, neighbours from the other, faster than the drone can
    react: where the obstacles' rows alone can hold (the filter solves them cleanly), the
    least-violation command holds every obstacle row and only neighbour rows take slack. An
    obstacle never gives way; a neighbour does its share and sees the flagged tick."""
    rng = np.random.default_rng(seed)
    filt = SafetyFilter(MODEL, FilterConfig(level=level, rho=0.5))
    state = QuadState.hover()
    side = rng.normal(size=2)
    side /= np.linalg.norm(side)
    k = n_obs + n_nb
    bearing = np.array([1.0] * n_obs + [-1.0] * n_nb)[:, None] * side + rng.uniform(-0.5, 0.5, (k, 2))
    bearing /= np.linalg.norm(bearing, axis=1, keepdims=True)
    dist = rng.uniform(0.6, 1.2, (k, 1))
    c = np.column_stack([dist * bearing, np.ones(k) + rng.uniform(-0.1, 0.1, k)])
    v = np.column_stack([-rng.uniform(1.0, 3.0, (k, 1)) * bearing, np.zeros(k)])
    is_nb = np.arange(k) >= n_obs
    r = rng.uniform(0.05, 0.2, k)
    obs = ObstacleArrays.build(c, r, v, is_neighbour=is_nb)
    w = MODEL.params.weight_N
    u_ref = np.full(4, w / 4) if level is CommandLevel.ROTORS else np.array([0.0, 0.0, w])
    res = filt.filter(state, u_ref, obs)
    assert np.isfinite(res.u).all() and filt.input_set.contains(res.u, 1e-7)
    alone = filt.filter(state, u_ref, ObstacleArrays.build(c[~is_nb], r[~is_nb], v[~is_nb]))
    if res.status is FilterStatus.INFEASIBLE and alone.status is FilterStatus.OK:
        own = ~is_nb[res.row_index]
        assert (res.constraint[own] >= -1e-6).all() and (res.slack[own] <= 1e-9).all(), (res.constraint, own)
        assert res.slack[~own].max() > 0
