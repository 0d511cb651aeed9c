"""The keep-out ellipsoid between drones (swarm.safety.barriers, "Keep-out ellipsoid") by its
definition: h < 0 exactly when the straight relative motion enters the ellipsoid (its closest
approach in the ellipsoid's metric), gradients against finite differences, the frame S = I
bit for bit the sphere's rows, a pair's two rows mirror images that add up to the pair's
condition, the still-obstacle target clear of a stopped drone's ellipsoid, the config's pair
rule, and two drones that would pass 0.2 m apart one over the other kept out of it."""

import math

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from swarm.config import resolve
from swarm.errors import ConfigError, InputError
from swarm.model import CommandLevel, QuadModel, QuadParams, QuadState
from swarm.net.neighbours import NeighbourTable
from swarm.safety.barriers import LIVE_W_HI_MPS, BarrierKind, cone_h, evaluate_pw, keep_out_frame, scaled_distance
from swarm.safety.constraints import free_target
from swarm.safety.filter import FilterConfig, SafetyFilter
from swarm.safety.obstacles import ObstacleArrays

from .helpers import central_gradients, vec

MODEL = QuadModel()
radius = st.floats(0.05, 1.0)


def ellipsoid_miss(p, w, r_xy, r_z):
    """The closest approach of ``p + t w`` (t >= 0) in the ellipsoid's metric: the smallest
    ``|S (p + t w)| / r_xy`` (below 1: the straight motion enters the ellipsoid)."""
    s = np.array([1.0, 1.0, r_xy / r_z])
    q, v = s * p, s * w
    t = max(0.0, -float(q @ v) / float(v @ v)) if v @ v > 0 else 0.0
    return float(np.linalg.norm(q + t * v)) / r_xy


@settings(max_examples=400, deadline=None)
@given(p=vec, w=vec, r_xy=radius, r_z=radius)
@example(p=np.array([1.0, 1.0, 1.0]), w=np.array([0.0, 0.0, -1.0]), r_xy=1.0, r_z=0.0625)  # S = diag(1, 1, 16)
def test_h_is_negative_exactly_when_the_straight_motion_enters_the_ellipsoid(p, w, r_xy, r_z):
    """The exact barrier the figures use (``cone_h`` with the frame), and the rows the filter
    holds at speed: the paper's (smoothing far below the speed) and the live row (the exact
    C3BF row from ``w_hi``, taken in the frame where the ellipsoid is a ball)."""
    sz = r_xy / r_z
    assume(scaled_distance(p, r_xy, r_z) > 1.01)
    miss = ellipsoid_miss(p, w, r_xy, r_z)
    assume(abs(miss - 1.0) > 1e-3 and np.linalg.norm(w * [1, 1, sz]) > 10 * LIVE_W_HI_MPS)
    h, inside = cone_h(p[None], w[None], np.array([r_xy]), scale_z=np.array([sz]))
    assert not inside[0] and (h[0] < 0) == (miss < 1.0)
    for live in (False, True):
        row = evaluate_pw(BarrierKind.C3BF, p[None], w[None], np.array([r_xy]), live=live, eps=1e-9, scale_z=[sz])
        assert not row.inside[0]
        assert (row.h[0] < 0) == (miss < 1.0)
        if h[0] >= 0 or not live:  # (inside the cone a live row holds a lower bound of h)
            scale = 1.0 + np.linalg.norm(p * [1, 1, sz])  # the paper's smoothing: at most eps s
            assert row.h[0] == pytest.approx(h[0], rel=1e-8, abs=1e-8 * scale)


@settings(max_examples=200, deadline=None)
@given(u=vec, w=vec, r_xy=radius, r_z=radius, depth=st.floats(0.05, 0.99))
def test_inside_the_ellipsoid_is_the_escape_row_of_its_frame(u, w, r_xy, r_z, depth):
    """A row already inside the ellipsoid (scaled distance below 1) holds the escape
    barrier of the frame: ``<S p, S w> / |S p| - v_esc``, the scaled gap opening."""
    assume(np.linalg.norm(u) > 0.1)
    p = u / scaled_distance(u, r_xy, r_z) * depth  # at scaled distance ``depth``
    sz = r_xy / r_z
    row = evaluate_pw(BarrierKind.C3BF, p[None], w[None], np.array([r_xy]), scale_z=[sz], escape_speed=0.3)
    assert row.inside[0]
    q, v = p * [1, 1, sz], w * [1, 1, sz]
    assert row.h[0] == pytest.approx(q @ v / np.linalg.norm(q) - 0.3, rel=1e-12, abs=1e-12)
    _, inside = cone_h(p[None], w[None], np.array([r_xy]), scale_z=np.array([sz]))
    assert inside[0]


@settings(max_examples=300, deadline=None)
@given(
    p=vec,
    w=vec,
    r_xy=radius,
    r_z=radius,
    kind=st.sampled_from(list(BarrierKind)),
    live=st.booleans(),
    horizon_s=st.sampled_from([None, 2.0]),
    contact_s=st.sampled_from([0.0, 0.8]),
)
def test_gradients_map_back_by_the_frame(p, w, r_xy, r_z, kind, live, horizon_s, contact_s):
    """dh/dp and dh/dw in the world, ``S dh/dp'`` and ``S dh/dw'``, against central
    differences of the row's h in world coordinates (live rows outside the cone, where at
    speed they are the exact C3BF row: inside it they turn with the side rule), with the
    horizon allowance and the contact horizon of a neighbour's row taken in the frame too."""
    sz = r_xy / r_z
    assume(scaled_distance(p, r_xy, r_z) > 1.05 and np.linalg.norm(w * [1, 1, sz]) > 10 * LIVE_W_HI_MPS)
    assume(not live or cone_h(p[None], w[None], [r_xy], scale_z=[sz])[0][0] > 1e-3)
    kw = dict(
        eps=1e-3, gamma_ho=0.7, live=live, scale_z=[sz], horizon_s=horizon_s, contact_s=contact_s, is_neighbour=[True]
    )

    def h(pp, ww):
        return evaluate_pw(kind, pp[None], ww[None], np.array([r_xy]), **kw).h[0]

    row = evaluate_pw(kind, p[None], w[None], np.array([r_xy]), **kw)
    num_p, num_w = central_gradients(h, p, w)
    np.testing.assert_allclose(row.dh_dp[0], num_p, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(row.dh_dw[0], num_w, rtol=1e-5, atol=1e-5)


@settings(max_examples=200, deadline=None)
@given(
    r=st.floats(0.01, 1.0),
    k_xy=st.floats(0.0, 1.0),
    k_z=st.floats(0.0, 1.0),
    p=vec,
)
def test_the_frame_is_the_stated_rule_and_scaled_distance_the_ellipsoid(r, k_xy, k_z, p):
    r_xy, sz = keep_out_frame(r, k_xy, k_z)
    assert r_xy == max(r, k_xy) and sz == pytest.approx(max(r, k_xy) / max(r, k_z), rel=1e-15)
    r_z = r_xy / sz
    d = scaled_distance(p, r_xy, r_z)
    assert d == pytest.approx(math.sqrt((p[0] ** 2 + p[1] ** 2) / r_xy**2 + p[2] ** 2 / r_z**2), rel=1e-12)


def test_without_a_keep_out_the_frame_is_the_identity_bit_for_bit():
    assert keep_out_frame(0.16, 0.0, 0.0) == (0.16, 1.0)
    assert keep_out_frame(0.16, 0.4, 0.4) == (0.4, 1.0)  # a keep-out that is a sphere: S = I too
    rng = np.random.default_rng(3)
    p, w, a = rng.normal(size=(50, 3)) * 2, rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    r = np.full(50, 0.3)
    nb = rng.random(50) < 0.5
    for live in (False, True):
        plain = evaluate_pw(BarrierKind.C3BF, p, w, r, live=live, a_ref=a, is_neighbour=nb, free_braking=True)
        framed = evaluate_pw(
            BarrierKind.C3BF, p, w, r, live=live, a_ref=a, is_neighbour=nb, free_braking=True, scale_z=np.ones(50)
        )
        np.testing.assert_array_equal(plain.coef, framed.coef)
        np.testing.assert_array_equal(plain.Y, framed.Y)
        np.testing.assert_array_equal(plain.dh_dw, framed.dh_dw)


def _scene(rng, n=8):
    state = QuadState(
        np.array([0.0, 0.0, 1.0]), rng.normal(0, 0.5, 3), np.array([0.0, 0.0, 0.0, 1.0]), rng.normal(0, 1.0, 3)
    )
    c = state.x_w + rng.uniform(-1.5, 1.5, (n, 3))
    cd = rng.normal(0, 0.6, (n, 3))
    return state, c, cd


@pytest.mark.parametrize("level", list(CommandLevel))
def test_a_filter_without_the_ellipsoid_flies_the_spheres_rows_bit_for_bit(level):
    """Drones' rows with the ellipsoid off, or with a keep-out inside the bodies' sphere,
    are the rows of the same spheres as plain neighbours and obstacles (no frame at all):
    command, h, constraint and buffer identical to the bit."""
    rng = np.random.default_rng(11)
    off = SafetyFilter(MODEL, FilterConfig(level=level, ellipsoid=False))
    small = SafetyFilter(
        QuadModel(QuadParams(keep_out_xy_m=0.1, keep_out_z_m=0.12)), FilterConfig(level=level)
    )  # 0.12 m + 0.02 m margin < the 0.16 m sphere
    for _ in range(30):
        state, c, cd = _scene(rng)
        nb = rng.random(len(c)) < 0.6
        drones = ObstacleArrays.build(c, np.full(len(c), 0.07), cd, is_neighbour=nb, is_agent=True)
        spheres = ObstacleArrays.build(c, np.full(len(c), 0.07), cd, is_neighbour=nb, is_agent=False)
        u_ref = np.array([0.1, -0.05, 0.3]) if level is CommandLevel.ATTITUDE else np.full(4, 0.075)
        want = off.filter(state, u_ref, spheres)
        for filt in (off, small):
            got = filt.filter(state, u_ref, drones)
            for f in ("u", "h", "constraint", "buffer", "slack"):
                np.testing.assert_array_equal(getattr(got, f), getattr(want, f))


def test_a_pairs_two_rows_are_mirror_images_and_add_up_to_the_pair_condition():
    """rho = 0.5, the paper's rows, both drones' keep-out ellipsoids: each agent's row is
    the other's seen from the other side (the same h), and the two rows together ask the
    pair's ``h' + kappa(h) >= 0`` with the ellipsoid's h (h' by a central difference along
    both drones' accelerations)."""
    cfg = FilterConfig(level=CommandLevel.ATTITUDE, rho=0.5, live=False, eps_w_mps=1e-9)
    filt = SafetyFilter(MODEL, cfg)
    r_nb = MODEL.params.body_radius_m
    up = np.array([0.0, 0.0, MODEL.params.l_m])  # each reports its body centre (level: l above the centre)
    rng = np.random.default_rng(2)
    signs = set()
    for v_b in ([-1.0, -0.1, -0.45], [-1.0, 1.5, 0.2]):  # down onto a's path, inside the cone; outside it
        a, b = QuadState.hover([0, 0, 1]), QuadState.hover([1.2, 0.1, 1.5])
        a.v_w, b.v_w = np.array([0.6, 0, 0.1]), np.array(v_b)
        ra = filt.rows(a, ObstacleArrays.build(b.x_w + up, [r_nb], b.v_w, is_neighbour=[True]))
        rb = filt.rows(b, ObstacleArrays.build(a.x_w + up, [r_nb], a.v_w, is_neighbour=[True]))
        assert ra.barrier.sz[0] == rb.barrier.sz[0] < 1.0
        assert ra.h[0] == pytest.approx(rb.h[0], rel=1e-12)
        Fa, Fb = rng.uniform(0.1, 0.4, 3), rng.uniform(0.1, 0.4, 3)
        lhs = (ra.Lg_h[0] @ Fa - ra.lower[0]) + (rb.Lg_h[0] @ Fb - rb.lower[0])
        r_xy, sz = keep_out_frame(filt.r_own_m + r_nb, 0.12 + 0.02, 0.30 + 0.02)
        p, w = b.x_w - a.x_w, b.v_w - a.v_w
        acc = (Fb - Fa) / MODEL.params.mass_kg

        def h_at(t, p=p, w=w, acc=acc, r_xy=r_xy, sz=sz):
            return cone_h((p + w * t + 0.5 * acc * t * t)[None], (w + acc * t)[None], [r_xy], scale_z=[sz])[0][0]

        hdot = (h_at(1e-6) - h_at(-1e-6)) / 2e-6
        kappa = (2.0 if ra.h[0] > 0 else 1.0) * cfg.gamma * ra.h[0]
        assert lhs == pytest.approx(hdot + kappa, rel=1e-6, abs=1e-8)
        signs.add(np.sign(ra.h[0]))
    assert signs == {-1.0, 1.0}


def test_the_still_target_keeps_out_of_a_stopped_drones_ellipsoid():
    """A drone taken whole (not its share) and at rest 0.45 m above: a reference 25 degrees
    off straight up is outside the sphere's cone (21 degrees) but inside the ellipsoid's
    (45 degrees in its frame). The still obstacles' target is the reference for the sphere,
    and a direction clear of the ellipsoid's cone for the drone."""
    xv_b = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    A0 = -5.0 * np.array([math.sin(math.radians(25)), 0.0, math.cos(math.radians(25))])  # relative: it comes closer
    sel = np.array([0], dtype=np.int64)
    r_own = 0.09
    for agent in (False, True):
        obs = ObstacleArrays.build([[0.0, 0.0, 1.45]], [0.07], is_agent=[agent])
        target = free_target(obs.rec, sel, r_own, xv_b, A0.copy(), LIVE_W_HI_MPS, 0.14, 0.32)
        if not agent:
            np.testing.assert_array_equal(target, A0)
            continue
        assert not np.array_equal(target, A0)
        r_xy, sz = keep_out_frame(0.16, 0.14, 0.32)
        P, T = np.array([0.0, 0.0, 0.45 * sz]), target * [1, 1, sz]
        assert P @ T + math.sqrt(P @ P - r_xy**2) * np.linalg.norm(T) >= 0.0  # outside the cone of its frame
        assert np.linalg.norm(target) == pytest.approx(np.linalg.norm(A0))


def test_a_neighbours_keep_out_grows_on_both_axes_with_its_states_age():
    """A neighbour's row in an imperfect world grows by ``g = (a/2 age + e) age`` for its
    state's age (``NeighbourTable``'s prediction bounds, plus a lost neighbour's growth): its
    keep-out ellipsoid grows by ``g`` on both axes, the row of a fresh state with keep-out radii
    ``k + g`` (up to rounding); a fresh state (g = 0) keeps ``k``, bit for bit."""
    a, e, age = 6.9, 0.05, 0.08
    table = NeighbourTable(timeout_s=0.05, growth_mps=0.5, hard_limit_s=2.0, accel_bound_mps2=a, velocity_error_mps=e)
    x_b, v_b = np.array([0.3, 0.1, 1.35]), np.array([-0.4, 0.0, -0.2])
    table.update("b", 1.0, 100, x_b, v_b, 0.07)
    g = 0.5 * (age - 0.05) + (0.5 * a * age + e) * age  # lost growth past the timeout, and the prediction bound
    rows = table.arrays(1.0 + age)
    assert rows.is_agent.tolist() == [True]
    assert rows.grow_m[0] == pytest.approx(g, rel=1e-12) and rows.radius_m[0] == pytest.approx(0.07 + g, rel=1e-12)
    state = QuadState.hover([0.0, 0.0, 1.0])
    state.v_w = np.array([0.5, 0.0, 0.1])
    for level in CommandLevel:
        cfg = FilterConfig(level=level)
        got = SafetyFilter(MODEL, cfg).rows(state, rows)
        grown = QuadModel(QuadParams(keep_out_xy_m=0.12 + g, keep_out_z_m=0.30 + g))
        fresh = ObstacleArrays.build(rows.c_w, rows.radius_m, rows.c_dot_w, is_neighbour=[True])
        want = SafetyFilter(grown, cfg).rows(state, fresh)
        assert got.barrier.sz[0] < 1.0 and got.barrier.sz[0] == pytest.approx(want.barrier.sz[0], rel=1e-12)
        assert got.h[0] == pytest.approx(want.h[0], rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(got.Lg_h, want.Lg_h, rtol=1e-9, atol=1e-12)
        table_now = NeighbourTable(timeout_s=0.05, growth_mps=0.5, hard_limit_s=2.0, accel_bound_mps2=a)
        table_now.update("b", 1.0, 100, x_b, v_b, 0.07)
        now = table_now.arrays(1.0)
        assert now.grow_m[0] == 0.0
        plain = ObstacleArrays.build(x_b, [0.07], v_b, is_neighbour=[True])
        np.testing.assert_array_equal(
            SafetyFilter(MODEL, cfg).rows(state, now).h, SafetyFilter(MODEL, cfg).rows(state, plain).h
        )


def test_a_drone_row_is_a_sphere_without_an_axis():
    with pytest.raises(InputError, match="obstacles.is_agent"):
        ObstacleArrays.build([[1.0, 0, 1]], [0.07], axis_w=[[0, 0, 1.0]], is_agent=[True])
    rows = ObstacleArrays.build(
        [[1.0, 0, 1], [2.0, 0, 1]], [0.07, 0.07], axis_w=[[0, 0, 1.0], [0, 0, 0]], is_neighbour=[True, True]
    )
    assert rows.is_agent.tolist() == [False, True]  # by default the neighbours that are spheres


def _pair(**agent: object) -> dict:
    return {
        "version": 1,
        "name": "stack",
        "duration_s": 8.0,
        "goal_tolerance_m": 0.1,
        "defaults": {"speed_mps": 0.8, "tiebreak": {"kind": "none"}, **agent},
        "agents": [
            {"id": "low", "start": [0.0, 0.0, 1.0], "goal": [3.0, 0.0, 1.0]},
            {"id": "high", "start": [3.0, 0.0, 1.2], "goal": [0.0, 0.0, 1.2]},
        ],
    }


def test_the_pair_keeps_the_larger_airframes_keep_out_and_a_bad_one_is_refused():
    raw = _pair()
    raw["agents"][1]["airframe"] = {"keep_out_z_m": 0.5}
    cfg = resolve(raw)
    assert [a.quad_params().keep_out_z_m for a in cfg.agents] == [0.5, 0.5]  # the larger, for both rows
    assert [a.quad_params().keep_out_xy_m for a in cfg.agents] == [0.12, 0.12]  # Crazyswarm's, by default
    assert cfg.agents[0].filter.filter_config(CommandLevel.ATTITUDE).ellipsoid
    raw["agents"][1]["airframe"] = {"keep_out_z_m": -0.1}
    with pytest.raises(ConfigError, match=r"agents\.1\.airframe\.keep_out_z_m"):
        resolve(raw)
    off = resolve(_pair(filter={"ellipsoid": False}))
    assert not off.agents[0].filter.filter_config(CommandLevel.ATTITUDE).ellipsoid


def test_two_drones_passing_one_over_the_other_keep_out_of_the_downwash():
    """Head on, one 0.2 m above the other's path: the spheres (0.16 m) let them pass straight,
    the upper drone's rotors 0.2 m over the lower; the ellipsoid (0.30 m up and down) keeps the
    pair out of it, and the figures say so."""
    from swarm.config import WorldSettings
    from swarm.offline.closed_loop import fly_scenario, outcome

    got = {}
    for ellipsoid in (False, True):
        cfg = resolve(_pair(filter={"ellipsoid": ellipsoid}))
        log = fly_scenario(cfg.model_copy(update={"world": WorldSettings()}))
        got[ellipsoid] = outcome(cfg, log)
    assert got[False].downwash_pairs == 1 and got[False].downwash_pair_ticks >= 5
    assert got[False].min_downwash_distance < 0.8
    assert got[True].downwash_pairs == 0 and got[True].downwash_pair_ticks == 0
    assert got[True].min_downwash_distance >= 1.0
    assert got[True].success and got[True].collisions == 0 and got[True].margin_violations == 0


def test_metrics_count_the_pairs_inside_the_downwash_ellipsoid():
    """metrics.json: a pair 0.2 m apart up and down, 0.05 m across, for two of four ticks is
    inside Crazyswarm's 0.12 m / 0.30 m ellipsoid (scaled distance 0.80), never inside the
    0.16 m sphere (no margin violation)."""
    from swarm.offline.metrics import compute

    cfg = resolve(_pair())
    recs = []
    offsets = ([1.0, 0.0, 0.2], [0.05, 0.0, 0.2], [0.05, 0.0, -0.25], [0.0, 0.4, 0.0])
    for k, d in enumerate(offsets):
        for aid, x in (("low", np.array([1.0, 0.0, 1.0])), ("high", np.array([1.0, 0.0, 1.0]) + d)):
            recs.append(
                {"kind": "measurement", "topic": f"/swarm/r/world/{aid}/measurement", "k": k, "t": 0.1 * k,
                 "x": x.tolist(), "q": [0, 0, 0, 1], "v": [0, 0, 0], "w": [0, 0, 0]}
            )  # fmt: skip
    recs.append({"kind": "status", "t": 0.4, "k": 4, "live": ["low", "high"], "done": True})
    m = compute(cfg, recs)
    assert m["downwash_pairs"] == 1 and m["downwash_pair_names"] == ["low|high"]
    assert m["downwash_pair_ticks"] == 2
    want = min(scaled_distance(np.array(d), 0.12, 0.30) for d in offsets)
    assert m["min_downwash_distance"] == pytest.approx(want) and want == pytest.approx(
        math.hypot(0.05 / 0.12, 0.2 / 0.3)
    )
    assert m["margin_violations"] == 0
