"""The neighbour table and the roster rows."""

import numpy as np
import pytest

from swarm.net.neighbours import NeighbourTable, roster_arrays


def test_neighbours_extrapolate_grow_and_stop_when_lost():
    t = NeighbourTable(timeout_s=0.1, growth_mps=0.5, hard_limit_s=1.0, on_lost="keep_stopped")
    t.update("b", 0.0, 0, np.array([1.0, 0, 1]), np.array([-1.0, 0, 0]), 0.07)
    fresh = t.arrays(0.05)
    np.testing.assert_allclose(fresh.c_w[0], [0.95, 0, 1])  # constant-velocity extrapolation
    assert fresh.radius_m[0] == 0.07 and fresh.is_neighbour.all()
    stale = t.arrays(0.5)
    assert stale.radius_m[0] == pytest.approx(0.07 + 0.5 * 0.4)  # grows past the timeout
    lost = t.arrays(2.0)
    np.testing.assert_allclose(lost.c_w[0], [1.0, 0, 1])  # past the hard limit: stopped at last position
    np.testing.assert_array_equal(lost.c_dot_w[0], 0.0)
    t.mark_gone("b")
    np.testing.assert_array_equal(t.arrays(0.05).c_dot_w[0], 0.0)
    dropper = NeighbourTable(0.1, 0.5, 1.0, on_lost="drop")
    dropper.update("b", 0.0, 0, np.zeros(3), np.zeros(3), 0.07)
    dropper.mark_gone("b")
    assert len(dropper.arrays(0.0)) == 0


def test_neighbour_state_at_a_given_tick():
    t = NeighbourTable(0.1, 0.5, 1.0)
    for k in range(12):
        t.update("b", k * 0.01, k, np.array([k * 1.0, 0, 0]), np.zeros(3), 0.07)
    assert t.state("b", 5).k == 5 and t.state("b").k == 11
    assert t.state("b", 2) is None  # older than the kept history


def test_roster_rows_are_the_chosen_drones_centres_velocities_and_radii():
    xvr = np.arange(4 * 7, dtype=float)  # 4 drones: x (3), v (3), r
    rows = np.array([0, 2, 3], dtype=np.intp)
    arr = roster_arrays(xvr, rows, np.ones(3, dtype=bool))
    want = xvr.reshape(4, 7)[rows]
    np.testing.assert_array_equal(arr.c_w, want[:, 0:3])
    np.testing.assert_array_equal(arr.c_dot_w, want[:, 3:6])
    np.testing.assert_array_equal(arr.radius_m, want[:, 6])
    assert arr.is_neighbour.all() and not arr.axis_w.any() and not arr.c_ddot_w.any()
