"""Delay-aware C3BF (docs/design.md, "Delay"): the swarm's agreed acceleration, the ages the
configured delays give, the state published for when the command acts, and the imperfection
sweep's circle flown at 100 ms on every link without contact."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.config import resolve
from swarm.model import QuadModel, QuadParams, thrust_vector_input_set
from swarm.offline.closed_loop import fly_scenario, outcome
from swarm.realism.settings import RealismSettings
from swarm.tuning import MIN_AGREED_ACCEL_MPS2, agreed_accel_mps2, expected_ages, max_accel_mps2
from tools.bench_imperfections import realism, scene

from .helpers import planned

HZ = 100.0


def _late(delay_s: float) -> RealismSettings:
    return RealismSettings.model_validate(realism("latency", delay_s))


def test_the_agreed_acceleration_keeps_a_rows_growth_over_its_expected_age_and_binds_only_where_it_is_tighter():
    params = QuadParams()
    assert agreed_accel_mps2(params, None, HZ, 0.15) is None  # the ideal world: no contract
    assert agreed_accel_mps2(params, RealismSettings(), HZ, 0.15) is None
    assert agreed_accel_mps2(params, _late(0.1), HZ, None) is None  # filter.delay_growth_m null: the airframe's
    assert agreed_accel_mps2(params, _late(0.01), HZ, 0.15) is None  # short delays: the airframe's is tighter
    for delay in (0.1, 0.15, 0.2):
        a = agreed_accel_mps2(params, _late(delay), HZ, 0.15)
        age = expected_ages(_late(delay), HZ).neighbour_s
        assert a is not None and MIN_AGREED_ACCEL_MPS2 <= a < max_accel_mps2(params)
        assert a == pytest.approx(max(MIN_AGREED_ACCEL_MPS2, 2 * 0.15 / age**2))
        assert 0.5 * a * age**2 <= 0.15 + 1e-12 or a == MIN_AGREED_ACCEL_MPS2


@pytest.mark.parametrize("a", [1.0, 3.0, 8.0])
def test_the_input_set_with_an_acceleration_limit_holds_every_command_within_it(a: float):
    """Every vertex-ish point of the set (the QP's corners, sampled) asks at most ``a`` beyond gravity."""
    params = QuadParams()
    ins = thrust_vector_input_set(params, accel_limit_mps2=a)
    rng = np.random.default_rng(0)
    F = rng.uniform(ins.lb, ins.ub, size=(20000, 3))
    inside = F[[ins.contains(f) for f in F]]
    assert len(inside) > 100
    accel = inside / params.mass_kg - np.array([0.0, 0.0, params.g_mps2])
    assert np.linalg.norm(accel, axis=1).max() <= a + 1e-9
    hover = np.array([0.0, 0.0, params.weight_N])
    assert ins.contains(hover)  # hovering is always allowed


def test_the_sweeps_circle_at_100_ms_on_every_link_touches_nothing_and_every_drone_gets_home():
    """The imperfections sweep's ``circle_8`` (8 drones across a 2 m circle, exact symmetry) with the
    motion capture and every state, bundle and command 100 ms late, flown offline: the filter of a
    fixed airframe bound touched 28 times here; the delay-aware one touches nothing."""
    cfg = resolve(scene("circle_8", "c3bf", "latency", 0.1))
    agents = planned(cfg)
    assert all(a.config.accel_limit_mps2 is not None for a in agents)  # the contract binds at this delay
    log = fly_scenario(cfg)
    o = outcome(cfg, log)
    assert o.collisions == 0, o
    assert o.reached == len(agents), o
    assert log.min_separation_m > 2 * QuadModel().params.body_radius_m


def test_a_late_state_is_used_at_its_true_age_and_an_older_one_arriving_after_a_newer_is_not_taken():
    """Jitter delivers states late and out of order: a row is the newest state's, moved along its velocity
    by its true age (now less its stamp), and grown by what the agreed acceleration allows over that age."""
    from swarm.net.neighbours import NeighbourTable

    a = 3.0
    table = NeighbourTable(0.5, 0.5, 1.0, accel_bound_mps2=a)
    v = np.array([1.0, 0.0, 0.0])
    table.update("cf2", 1.00, 100, np.array([0.0, 0.0, 1.0]), v, 0.05)
    table.update("cf2", 0.95, 95, np.array([-9.0, 0.0, 1.0]), v, 0.05)  # older, arriving after: not taken
    rows = table.arrays(1.3)
    assert table.row_age_s == pytest.approx([0.3])
    assert rows.c_w[0] == pytest.approx([0.3, 0.0, 1.0])  # moved by its true age
    assert rows.radius_m[0] == pytest.approx(0.05 + 0.5 * a * 0.3**2)


@pytest.mark.parametrize("speed", [0.2, 0.6, 0.9, 1.5])
def test_the_speed_row_is_the_speed_cbf_by_its_definition(speed: float):
    """The filtered command keeps ``h_v' + k h_v >= 0`` for ``h_v = V^2 - |v|^2`` (``h_v' = -2 <v, a>``, the
    acceleration the thrust vector gives), or, where that asks for more braking than half the axes'
    limit, brakes at least that hard; a reference that speeds up is cut back, one that slows is left."""
    from swarm.model import CommandLevel, QuadState
    from swarm.safety.filter import SPEED_GAIN_PER_S, FilterConfig, SafetyFilter
    from swarm.safety.obstacles import ObstacleArrays

    model = QuadModel()
    p = model.params
    V, a_lim = 0.65, 1.4
    filt = SafetyFilter(model, FilterConfig(level=CommandLevel.ATTITUDE, accel_limit_mps2=a_lim, speed_limit_mps=V))
    direction = np.array([0.6, 0.8, 0.0])
    state = QuadState.hover([0.0, 0.0, 1.0])
    state.v_w = speed * direction
    g = np.array([0.0, 0.0, p.g_mps2])
    for push in (1.0, -1.0):  # accelerate along v, or brake
        u_ref = p.mass_kg * (g + push * 0.9 * direction)
        res = filt.filter(state, u_ref, ObstacleArrays.build(np.zeros((0, 3)), np.zeros(0)))
        accel = res.u / p.mass_kg - g
        h_v = V**2 - speed**2
        h_dot = -2.0 * float(state.v_w @ accel)
        brake = -float(state.v_w @ accel) / speed  # m/s^2 along -v
        assert h_dot + SPEED_GAIN_PER_S * h_v >= -1e-6 or brake >= 0.25 * a_lim - 1e-6
        if push < 0:
            assert res.u == pytest.approx(u_ref, abs=1e-6)  # braking is never cut
        assert np.linalg.norm(accel) <= a_lim + 1e-6
