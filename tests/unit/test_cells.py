"""Interest by distance (swarm.net.cells): the cells of a point, the cells a ball meets, the
subscriptions an agent keeps as it moves (hysteresis, border crossings at full speed), the
world's near lists, and what the neighbour table does with neighbours that leave."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.net.cells import Interest, cell_of, cells_meeting_ball, near_lists
from swarm.net.neighbours import NeighbourTable

coord = st.floats(-50.0, 50.0, allow_nan=False)
point = st.tuples(coord, coord, st.floats(-2.0, 6.0))


def _box_distance(p, cell, cell_m):
    """Distance [m] from p to the cube of ``cell`` (brute force, per axis)."""
    d2 = 0.0
    for a in range(3):
        lo, hi = cell[a] * cell_m, (cell[a] + 1) * cell_m
        d2 += max(lo - p[a], 0.0, p[a] - hi) ** 2
    return math.sqrt(d2)


def test_cell_of_floors_each_coordinate_negative_ones_too():
    assert cell_of([0.0, 0.99, 1.0], 1.0) == (0, 0, 1)
    assert cell_of([-0.01, -1.0, -1.01], 1.0) == (-1, -1, -2)
    assert cell_of([7.0, 3.5, 0.0], 3.5) == (2, 1, 0)


@settings(max_examples=200, deadline=None)
@given(p=point, radius=st.floats(0.1, 6.0), cell_m=st.floats(0.3, 5.0))
def test_the_cells_of_a_ball_are_exactly_the_cells_it_meets(p, radius, cell_m):
    got = cells_meeting_ball(p, radius, cell_m)
    lo = [math.floor((p[a] - radius) / cell_m) - 1 for a in range(3)]
    hi = [math.floor((p[a] + radius) / cell_m) + 1 for a in range(3)]
    boxes = [
        (i, j, k) for i in range(lo[0], hi[0] + 1) for j in range(lo[1], hi[1] + 1) for k in range(lo[2], hi[2] + 1)
    ]
    # (a cell only touching the sphere from outside holds none of its points: cells are half-open;
    # and a box's edge i * cell_m may differ by an ulp from where floor(x / cell_m) changes)
    assert {c for c in boxes if _box_distance(p, c, cell_m) < radius - 1e-9} <= got
    assert got <= {c for c in boxes if _box_distance(p, c, cell_m) <= radius + 1e-9}


@settings(max_examples=100, deadline=None)
@given(p=point, radius=st.floats(0.1, 6.0), cell_m=st.floats(0.3, 5.0), seed=st.integers(0, 2**31))
def test_every_point_of_the_ball_is_in_one_of_its_cells(p, radius, cell_m, seed):
    cells = cells_meeting_ball(p, radius, cell_m)
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    pts = np.asarray(p) + d * radius * np.sqrt(rng.uniform(0, 1, 64))[:, None]
    pts[:8] = np.asarray(p) + d[:8] * radius  # on the sphere itself
    for q in pts:
        assert cell_of(q.tolist(), cell_m) in cells


def _walk(start, heading_deg, speed_mps, dt_s, n):
    h = math.radians(heading_deg)
    step = np.array([math.cos(h), math.sin(h), 0.0]) * speed_mps * dt_s
    return [np.asarray(start, float) + i * step for i in range(n)]


@settings(max_examples=25, deadline=None)
@given(start=point, heading=st.floats(0, 360), cell_m=st.floats(0.6, 4.0), seed=st.integers(0, 2**31))
def test_an_agent_crossing_cell_borders_at_full_speed_hears_every_neighbour_in_its_interest_radius(
    start, heading, cell_m, seed
):
    """Both at 3 m/s, 100 Hz, states one tick old and a declaration taking 10 ticks to
    reach the publisher's side: every neighbour within the interest radius publishes into
    a cell that was declared at least 10 ticks before (so the router knew it)."""
    R, hyst, speed, dt, lag = 3.5, 0.5, 3.0, 0.01, 10
    interest = Interest(R, cell_m, hyst)
    rng = np.random.default_rng(seed)
    me = _walk(start, heading, speed, dt, 300)
    declared_at: dict[tuple[int, int, int], int] = {}
    for k, p in enumerate(me):
        add, drop = interest.update(p.tolist())
        for c in add:
            declared_at[c] = k
        for c in drop:
            declared_at.pop(c)
        # a neighbour anywhere within R of my position, moving at full speed: where was it one tick ago?
        d = rng.normal(size=3)
        q_now = p + d / np.linalg.norm(d) * R * rng.uniform(0, 1) ** (1 / 3)
        v = rng.normal(size=3)
        q_then = q_now - v / np.linalg.norm(v) * speed * dt
        if np.linalg.norm(q_then - p) > R:
            continue
        c = cell_of(q_then.tolist(), cell_m)
        assert c in declared_at, (k, p, q_then)
        assert k - declared_at[c] >= lag or k < lag, "declared too late for the router to know it"


def test_hysteresis_no_redeclaration_for_small_moves_around_a_border():
    interest = Interest(3.5, 1.0, 0.5)
    add, drop = interest.update([0.99, 0.0, 1.0])
    assert add and not drop
    for x in (1.01, 0.99, 1.05, 0.95, 1.1):  # back and forth across x = 1, within a quarter of 0.5
        assert interest.update([x, 0.0, 1.0]) == (set(), set())
    add, drop = interest.update([1.2, 0.0, 1.0])  # 0.21 m > 0.125 m from the anchor
    assert interest.anchor_w == (1.2, 0.0, 1.0)
    assert add or drop
    assert interest.declared == len(cells_meeting_ball([0.99, 0.0, 1.0], 4.0, 1.0)) + len(add)


def test_bad_interest_settings():
    with pytest.raises(ValueError, match="positive"):
        Interest(3.0, 0.0, 0.5)


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(1, 30))
def test_near_lists_are_the_candidates_within_each_radius(seed, n):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-5, 5, (n, 3))
    cand = rng.uniform(size=n) < 0.7
    r = rng.uniform(0.5, 4.0, n)
    got = near_lists(x, cand, r)
    for i in range(n):
        want = [j for j in range(n) if j != i and cand[j] and np.sum((x[j] - x[i]) ** 2) <= r[i] ** 2]
        assert got[i] == want


def test_a_neighbour_that_left_the_cells_is_forgotten_a_lost_one_is_not():
    t = NeighbourTable(timeout_s=0.1, growth_mps=0.5, hard_limit_s=1.0)
    me = np.zeros(3)
    t.update("far", 0.0, 0, np.array([5.0, 0, 0]), np.zeros(3), 0.1)  # last heard outside the radius
    t.update("near", 0.0, 0, np.array([1.0, 0, 0]), np.zeros(3), 0.1)  # last heard inside: lost, not left
    t.update("fresh", 0.95, 95, np.array([5.0, 0, 0]), np.zeros(3), 0.1)  # outside but heard just now
    t.forget_far(me, 4.0, 1.0)
    assert set(t.history) == {"near", "fresh"}
    t.mark_gone("fresh")
    t.forget_far(me, 4.0, 5.0)
    assert set(t.history) == {"near", "fresh"}  # a gone neighbour stays (on_lost decides)
    rows = t.arrays(1.0, names=["near"])
    assert t.row_names == ["near", "fresh"]  # the named ones, then the gone
    assert len(rows) == 2 and not rows.is_neighbour[1]
