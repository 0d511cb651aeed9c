"""The barriers by their definitions: gradients against finite differences of h,
and a defined, finite answer in every edge case of ``swarm.safety.barriers``'s docstring."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.safety.barriers import BarrierKind, evaluate_pw

from .helpers import vec

unit_or_zero = st.one_of(
    st.just(np.zeros(3)), vec.filter(lambda a: np.linalg.norm(a) > 0.1).map(lambda a: a / np.linalg.norm(a))
)


def h_of(kind, p, w, r, a, **kw):
    return evaluate_pw(kind, p[None], w[None], np.array([r]), a[None], **kw).h[0]


def assert_gradients(rows, kind, p, w, r, a, d=1e-6, **kw):
    """dh/dp and dh/dw of the row against central differences of h."""
    for grad, which in ((rows.dh_dp[0], "p"), (rows.dh_dw[0], "w")):
        num = np.zeros(3)
        for i in range(3):
            e = np.zeros(3)
            e[i] = d
            if which == "p":
                num[i] = (h_of(kind, p + e, w, r, a, **kw) - h_of(kind, p - e, w, r, a, **kw)) / (2 * d)
            else:
                num[i] = (h_of(kind, p, w + e, r, a, **kw) - h_of(kind, p, w - e, r, a, **kw)) / (2 * d)
        np.testing.assert_allclose(grad, num, rtol=1e-5, atol=1e-5)


@settings(max_examples=300, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 1.0), a=unit_or_zero, kind=st.sampled_from(list(BarrierKind)))
def test_gradients_match_finite_differences(p, w, r, a, kind):
    Pp = p - a * (a @ p)
    if np.linalg.norm(Pp) < r + 0.05:
        p = p + (r + 0.1) * (np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0]))
        Pp = p - a * (a @ p)
        if np.linalg.norm(Pp) < r + 0.05:
            return
    kw = dict(eps=1e-3, gamma_ho=0.7)
    rows = evaluate_pw(kind, p[None], w[None], np.array([r]), a[None], **kw)
    assert not rows.inside[0]
    assert_gradients(rows, kind, p, w, r, a, **kw)


def test_c3bf_matches_the_formula_and_the_cone():
    p = np.array([[2.0, 0.0, 0.0]])
    r = np.array([1.0])
    # heading straight at it: inside the cone, h < 0
    assert evaluate_pw(BarrierKind.C3BF, p, np.array([[-1.0, 0, 0]]), r).h[0] < 0
    # obstacle centre moving away: h > 0
    assert evaluate_pw(BarrierKind.C3BF, p, np.array([[1.0, 0, 0]]), r).h[0] > 0
    # exactly on the cone boundary: relative velocity tangent to the sphere
    half = np.arcsin(1.0 / 2.0)
    w = -np.array([[np.cos(half), np.sin(half), 0.0]])
    assert abs(evaluate_pw(BarrierKind.C3BF, p, w, r, eps=1e-12).h[0]) < 1e-9
    s = np.sqrt(4 - 1)
    wv = np.array([[-0.3, 0.4, 0.1]])
    expect = p[0] @ wv[0] + np.linalg.norm(wv) * s
    assert (
        evaluate_pw(BarrierKind.C3BF, p, wv, r, eps=1e-12).h[0] == np.float64(expect).round(12)
        or abs(evaluate_pw(BarrierKind.C3BF, p, wv, r, eps=1e-12).h[0] - expect) < 1e-9
    )


def test_smoothed_norm_keeps_h_below_the_true_cone_value():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(200, 3)) * 3
    w = rng.normal(size=(200, 3)) * 0.01
    r = np.full(200, 0.1)
    ok = np.linalg.norm(p, axis=1) > 0.2
    rows = evaluate_pw(BarrierKind.C3BF, p[ok], w[ok], r[ok], eps=1e-2)
    true = np.sum(p[ok] * w[ok], 1) + np.linalg.norm(w[ok], axis=1) * np.sqrt(np.sum(p[ok] ** 2, 1) - 0.01)
    assert np.all(rows.h <= true + 1e-15)


def test_edge_cases_are_finite():
    r = np.array([0.3] * 6)
    p = np.array([[1, 0, 0], [1, 0, 0], [0.1, 0, 0], [0, 0, 0], [1, 0, 0], [0.29, 0, 0.0]], dtype=float)
    w = np.array([[0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 0, 0], [0, 0, 2.0], [0, 0, 0]], dtype=float)
    a = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 0], [0, 0, 0], [0, 0, 1], [0, 0, 1.0]])
    for kind in BarrierKind:
        rows = evaluate_pw(kind, p, w, r, a)
        for arr in (rows.h, rows.dh_dp, rows.dh_dw):
            assert np.isfinite(arr).all()
        # hovering pair: on the boundary (h = 0 for C3BF, <p,w> = 0)
        if kind is BarrierKind.C3BF:
            assert rows.h[0] == 0.0
            # cylinder with motion only along its axis: P w = 0, same answer
            assert rows.h[4] == 0.0
        np.testing.assert_array_equal(rows.inside, [False, False, True, True, False, True])
        # inside rows hold the escape barrier: separating at 1 m/s from 0.1 m gives h = 1 - v_esc
        assert rows.h[2] == np.float64(1.0 - 0.3)


def _proj(a, v):
    return v - a * (a @ v)


@settings(max_examples=300, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 1.0), a=unit_or_zero, gamma_ho=st.floats(0.1, 5.0))
def test_hocbf_h_is_its_formula_with_its_gain(p, w, r, a, gamma_ho):
    """HO-CBF: h = <Pp, Pw> + gamma_ho sqrt(|Pp|^2 - r^2) outside the safety radius (a gain
    ignored or fixed would differ: gamma_ho is drawn)."""
    P, W = _proj(a, p), _proj(a, w)
    if P @ P <= (r + 0.05) ** 2:
        return
    rows = evaluate_pw(BarrierKind.HOCBF, p[None], w[None], np.array([r]), a[None], gamma_ho=gamma_ho)
    assert not rows.inside[0]
    want = P @ W + gamma_ho * np.sqrt(P @ P - r * r)
    np.testing.assert_allclose(rows.h[0], want, rtol=1e-12, atol=1e-12)


@settings(max_examples=300, deadline=None)
@given(
    p=vec,
    w=vec,
    r=st.floats(0.2, 1.0),
    a=unit_or_zero,
    kind=st.sampled_from(list(BarrierKind)),
    depth=st.floats(0.1, 0.9),
    v_esc=st.floats(0.1, 1.0),
)
def test_escape_row_inside_the_radius_is_its_formula_and_its_gradients(p, w, r, a, kind, depth, v_esc):
    """Inside the safety radius every barrier kind holds the escape barrier
    h = <Pp, Pw>/|Pp| - v_esc (separate at v_esc), with gradients by finite differences."""
    P = _proj(a, p)
    if np.linalg.norm(P) < 1e-3:
        return
    p = p - P + P / np.linalg.norm(P) * depth * r  # the same direction, at depth * r from the axis or centre
    P, W = _proj(a, p), _proj(a, w)
    kw = dict(escape_speed=v_esc, gamma_ho=0.7)
    rows = evaluate_pw(kind, p[None], w[None], np.array([r]), a[None], **kw)
    assert rows.inside[0]
    np.testing.assert_allclose(rows.h[0], P @ W / np.linalg.norm(P) - v_esc, rtol=1e-12, atol=1e-12)
    assert_gradients(rows, kind, p, w, r, a, **kw)
