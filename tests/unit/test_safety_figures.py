"""The safety figures measure what they say: the exact C3BF barrier by its definition (the
straight relative motion's closest approach), contacts apart from margin violations, one
count of bad ticks, one deadlock rule, and the sensing radius checked against the speeds."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from swarm.config import resolve
from swarm.errors import ConfigError
from swarm.geometry import items_to_arrays, obstacle_items
from swarm.offline.metrics import compute, deadlock_at
from swarm.safety.barriers import cone_h

vec = st.lists(st.floats(-3, 3, allow_nan=False), min_size=3, max_size=3).map(np.array)


def closest_approach(p, w):
    """Smallest |p + w t| over t >= 0 (the gap's straight-line future)."""
    ww = float(w @ w)
    t = max(0.0, -float(p @ w) / ww) if ww > 0 else 0.0
    return float(np.linalg.norm(p + w * t))


@settings(max_examples=300, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 1.0))
def test_exact_h_is_negative_exactly_on_a_collision_course(p, w, r):
    assume(np.linalg.norm(p) > r * 1.01 and np.linalg.norm(w) > 1e-3)
    miss = closest_approach(p, w)
    assume(abs(miss - r) > 1e-3)  # (not grazing: the sign there is rounding)
    h, inside = cone_h(p[None], w[None], np.array([r]))
    assert not inside[0]
    assert (h[0] < 0) == (miss < r)


@settings(max_examples=200, deadline=None)
@given(p=vec, w=vec, r=st.floats(0.05, 1.0), axis=vec)
def test_a_cylinder_is_the_disc_across_its_axis(p, w, r, axis):
    assume(np.linalg.norm(axis) > 0.1)
    a = axis / np.linalg.norm(axis)
    P = np.eye(3) - np.outer(a, a)
    pp, pw = P @ p, P @ w
    assume(np.linalg.norm(pp) > r * 1.01 and np.linalg.norm(pw) > 1e-3)
    assume(abs(closest_approach(pp, pw) - r) > 1e-3)
    h, _ = cone_h(p[None], w[None], np.array([r]), a[None])
    assert (h[0] < 0) == (closest_approach(pp, pw) < r)


def test_inside_the_radius_is_flagged_and_finite():
    h, inside = cone_h(np.array([[0.1, 0, 0], [0, 0, 0]]), np.array([[1.0, 0, 0], [0, 0, 0]]), np.array([0.2, 0.2]))
    assert inside.tolist() == [True, True] and np.isfinite(h).all()
    assert h[0] == pytest.approx(0.1)  # <p, w>: opening


def _cfg(sensing_m=3.0, margin_m=0.02, ellipsoid=True):
    flt = {"sensing_radius_m": sensing_m, "margin_m": margin_m, "ellipsoid": ellipsoid}
    return resolve(
        {
            "version": 1,
            "name": "h",
            "duration_s": 1.0,
            "goal_tolerance_m": 0.1,
            "agents": [
                {
                    "id": "a",
                    "start": [0, 0, 1],
                    "goal": [4, 0, 1],
                    "speed_mps": 0.5,
                    "filter": flt,
                    "airframe": {"l_m": 0.0},
                },
                {
                    "id": "b",
                    "start": [4, 0, 1],
                    "goal": [0, 0, 1],
                    "speed_mps": 0.5,
                    "filter": flt,
                    "airframe": {"l_m": 0.0},
                },
            ],
        },
        "h.yaml",
    )


def _head_on(gaps_m, speed_mps=0.5, min_h=0.3, statuses=None):
    """Records of a and b head on along x, their gap at each tick ``gaps_m`` (0.1 s ticks)."""
    recs = []
    for k, gap in enumerate(gaps_m):
        for aid, x, v in (("a", 2 - gap / 2, speed_mps), ("b", 2 + gap / 2, -speed_mps)):
            recs.append(
                {"kind": "measurement", "topic": f"/swarm/r/world/{aid}/measurement", "k": k, "t": 0.1 * k,
                 "x": [x, 0, 1], "q": [0, 0, 0, 1], "v": [v, 0, 0], "w": [0, 0, 0]}
            )  # fmt: skip
            status = (statuses or {}).get(k, 0)
            recs.append(
                {"kind": "command", "src": aid, "k": k, "t": 0.1 * k, "min_h": min_h, "solve_us": 10.0,
                 "infeasible": status, "dropped": 0}
            )  # fmt: skip
    recs.append({"kind": "status", "t": 0.1 * len(gaps_m), "k": len(gaps_m), "live": ["a", "b"], "done": True})
    return recs


def test_min_h_is_the_exact_barrier_from_the_measured_states_not_the_rows():
    gaps = [3.5, 2.5, 1.0]
    m = compute(_cfg(), _head_on(gaps))
    r = 0.07 * 2 + 0.02
    want = min(-gap * 1.0 + 1.0 * math.sqrt(gap**2 - r**2) for gap in gaps if gap <= 3.0)  # w = 1 m/s closing
    a = m["agents"]["a"]
    assert a["min_h"] == pytest.approx(want) and m["min_h"] == pytest.approx(want)
    assert a["min_row_h"] == pytest.approx(0.3)  # what the rows said, kept apart
    assert a["negative_h_ticks"] == 2  # the two ticks within the 3 m sensing radius
    assert a["unseen_negative_h_ticks"] == 1  # at 3.5 m: on course, no row yet
    assert m["negative_h_ticks"] == 4 and m["unseen_negative_h_ticks"] == 2  # summed over the agents


def test_margin_violations_are_counted_apart_from_contacts_with_their_depth():
    r = 0.07 * 2 + 0.02  # body radii + margin
    m = compute(_cfg(), _head_on([1.0, 0.155, 0.15, 0.5]))
    assert m["collisions"] == 0  # no contact message: bodies never touched (0.14 m)
    assert m["margin_violations"] == 1 and m["margin_violation_pairs"] == ["a|b"]
    assert m["margin_violation_ticks"] == 2
    assert m["max_margin_depth_m"] == pytest.approx(r - 0.15)


def test_every_status_but_ok_is_a_bad_tick_and_the_agent_count_is_reported():
    m = compute(_cfg(), _head_on([3.0, 2.0, 1.0], statuses={2: 2}))
    assert m["agents"]["a"]["infeasible_ticks"] == 2  # the agent's own count (every non-OK status)


def test_one_deadlock_rule_a_yield_is_not_a_deadlock():
    t = np.arange(0, 6, 0.1)
    goal = np.array([1.0, 0, 1])
    stall = np.where(t < 3, 0.0, np.minimum(1.0, (t - 3) * 0.5))  # still for 3 s, then on to the goal
    x = np.stack([stall, np.zeros_like(t), np.ones_like(t)], axis=1)
    v = np.gradient(x, t, axis=0)
    assert deadlock_at(t, x, v, goal, 0.1) is None  # it got out to its goal
    x_stuck = x.copy()
    x_stuck[:, 0] = 0.0
    assert deadlock_at(t, x_stuck, np.zeros_like(v), goal, 0.1) == pytest.approx(0.0)


def test_a_sensing_radius_that_cannot_see_in_time_is_refused_with_the_field():
    with pytest.raises(ConfigError, match=r"h\.yaml: agents\.0\.filter\.sensing_radius_m: 0\.2 m cannot see b"):
        _cfg(sensing_m=0.2, ellipsoid=False)
    _cfg(sensing_m=0.3, ellipsoid=False)  # 1 m/s closing: 0.073 m to brake, 0.008 m per tick, plus 0.16 m
    # the keep-out ellipsoid's radius up and down (0.30 m and the margin) in place of 0.16 m
    with pytest.raises(ConfigError, match=r"sensing_radius_m: 0\.3 m cannot see b.*safety radius 0\.320 m"):
        _cfg(sensing_m=0.3)
    _cfg(sensing_m=0.41)


def test_fly_scenario_counts_bad_ticks_as_the_agents_do():
    from swarm.offline.closed_loop import SwarmLog
    from swarm.safety.filter import FilterStatus as S

    status = [[S.OK, S.COLLISION], [S.INFEASIBLE, S.OK], [S.FAILED, S.OK]]
    log = SwarmLog(np.zeros(3), np.zeros((3, 2, 3)), np.zeros((3, 2, 3)), status, 1.0, math.inf, [None, None])
    assert log.infeasible_ticks == 3  # escape rows (COLLISION) count: the guarantee did not hold there either


def test_fly_scenario_reports_the_exact_barrier_of_its_log():
    from swarm.config import WorldSettings
    from swarm.offline.closed_loop import fly_scenario, outcome
    from swarm.offline.scenario import SwapSettings, circle_swap

    cfg = resolve(circle_swap(2, 1.0, SwapSettings(duration_s=3.0)))
    log = fly_scenario(cfg.model_copy(update={"world": WorldSettings()}))
    o = outcome(cfg, log)
    r = 2 * 0.07 + cfg.agents[0].filter.margin_m
    p = log.x_b_w[:, 1] - log.x_b_w[:, 0]
    h, _ = cone_h(p, log.v_b_w[:, 1] - log.v_b_w[:, 0], np.full(len(p), r))
    assert o.min_h == pytest.approx(float(h.min()))  # both in sensing range throughout (2 m apart at most)
    assert o.negative_h_ticks == 2 * int((h < 0).sum())  # each agent's tick counts
    assert o.margin_violations == int(bool((np.linalg.norm(p, axis=1) < r).any()))


def test_fly_scenario_s_deadlock_is_judged_at_the_centre_of_mass_as_its_arrival():
    """An agent that hovers 0.14 m from its goal (tolerance 0.15) with its body centre 0.16 m
    away arrived: it is neither late nor deadlocked (the runtime's metrics use the centre of
    mass too); nor is one whose arrival ended the run before a tick logged it."""
    from swarm.offline.closed_loop import SwarmLog, outcome
    from swarm.safety.filter import FilterStatus as S

    cfg = resolve(
        {"version": 1, "name": "d", "duration_s": 5.0, "goal_tolerance_m": 0.15,
         "agents": [{"id": "a", "start": [0, 0, 1], "goal": [1, 0, 1]}]}, "d.yaml"
    )  # fmt: skip
    t = np.arange(0.0, 5.0, 0.1)
    com = np.tile([[0.86, 0.0, 1.0]], (len(t), 1))[:, None, :]
    body = com + np.array([-0.02, 0.0, 0.0])  # 0.16 m from the goal
    still = np.zeros_like(com)
    log = SwarmLog(t, body, still, [[S.OK]] * len(t), math.inf, math.inf, [0.0], x_w=com, v_b_w=still)
    o = outcome(cfg, log)
    assert o.reached == 1 and o.deadlocked == 0
    # stalled short of it in every logged tick, arrived in the step that ended the run: a yield
    far = com + np.array([-0.5, 0.0, 0.0])
    log = SwarmLog(t, far, still, [[S.OK]] * len(t), math.inf, math.inf, [5.0], x_w=far, v_b_w=still)
    assert outcome(cfg, log).deadlocked == 0
    log = SwarmLog(t, far, still, [[S.OK]] * len(t), math.inf, math.inf, [None], x_w=far, v_b_w=still)
    assert outcome(cfg, log).deadlocked == 1  # never arrived: deadlocked


def test_an_agent_on_a_path_round_walls_is_judged_by_the_barrier_its_obstacle_rows_keep():
    """In a corridor the agents' obstacle rows keep ``h_tau`` (the obstacle horizon): the
    figures add its allowance to the exact cone h of every agent-obstacle, and to nothing
    else; without walls or with the horizon off they are the cone's."""
    from swarm.offline.metrics import SafetyFigures
    from swarm.offline.scenario import corridor

    cfg = resolve(corridor(1))
    tau = cfg.agents[0].planner.obstacle_horizon_s
    fig = SafetyFigures(cfg)
    np.testing.assert_allclose(fig.inv_tau_obs, 1.0 / tau)
    np.testing.assert_allclose(fig.inv_tau_nb, 0.0)
    raw = corridor(1)
    raw["defaults"]["planner"] = {"obstacle_horizon_s": None}
    np.testing.assert_allclose(SafetyFigures(resolve(raw)).inv_tau_obs, 0.0)
    np.testing.assert_allclose(SafetyFigures(_cfg()).inv_tau_obs, 0.0)  # open space
    # one agent flying straight at a pillar 2 m off: the cone's h plus (|p|^2 - r^2) / (2 tau)
    o = cfg.obstacles[0]
    x = np.array([[o.center[0] - 2.0, o.center[1], 1.0]])
    fig.add([0], x, x, np.array([[1.0, 0.0, 0.0]]), items_to_arrays(obstacle_items([o], 0.0)), [o.id])
    r = o.radius_m + 0.07 + cfg.agents[0].filter.margin_m
    s2 = 4.0 - r * r
    assert fig.min_h[0] == pytest.approx(-2.0 + math.sqrt(s2) + s2 / (2 * tau))
    assert fig.negative[0] == 0  # on the cone's collision course, within the row's allowance
