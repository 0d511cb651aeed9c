"""The reference controller alone: hover and track, both command levels, 100-500 Hz."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.control import PathTracker, TrackingGains
from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.offline.closed_loop import simulate
from swarm.rotation import euler_to_quat
from swarm.safety.filter import FilterConfig
from swarm.safety.obstacles import ObstacleArrays

MODEL = QuadModel()


@pytest.mark.parametrize("level", list(CommandLevel))
@pytest.mark.parametrize("rate_hz", [100.0, 250.0, 500.0])
def test_hover_recovers_from_a_disturbed_start(level, rate_hz):
    s0 = QuadState.hover([0.3, -0.2, 0.8])
    s0.q = euler_to_quat(0.3, -0.2, 0.5)
    s0.Omega_b = np.array([2.0, -1.0, 0.5])
    log = simulate(
        MODEL,
        FilterConfig(level=level),
        PathTracker([[0, 0, 1.0]], 1.0),
        ObstacleArrays.empty(),
        s0,
        6.0,
        control_hz=rate_hz,
        physics_hz=1000.0,
        filter_on=False,
    )
    x = log.array("x_w")
    assert np.linalg.norm(x[-1] - [0, 0, 1.0]) < 0.01
    assert np.abs(log.array("v_w")[-50:]).max() < 0.02


@pytest.mark.parametrize("level", list(CommandLevel))
@pytest.mark.parametrize("rate_hz", [100.0, 500.0])
def test_tracks_a_path_at_the_target_speed(level, rate_hz):
    waypoints = [[0, 0, 1.0], [3, 0, 1.0], [3, 3, 1.5]]
    log = simulate(
        MODEL,
        FilterConfig(level=level),
        PathTracker(waypoints, 1.0),
        ObstacleArrays.empty(),
        QuadState.hover(waypoints[0]),
        10.0,
        control_hz=rate_hz,
        physics_hz=1000.0,
        filter_on=False,
    )
    x, v = log.array("x_w"), log.array("v_w")
    speed = np.linalg.norm(v, axis=1)
    t = np.array(log.t_s)
    cruise = (t > 1.5) & (t < 2.5)
    assert np.abs(speed[cruise] - 1.0).max() < 0.05
    assert np.abs(x[t < 2.8, 1]).max() < 0.05  # stays on the first segment
    assert np.linalg.norm(x[-1] - waypoints[-1]) < 0.05


def test_the_tie_break_turns_the_commanded_velocity_and_never_speeds_it_up():
    from swarm.control import right_hand_bias, turned

    x, heading = np.zeros(3), np.array([0.8, 0.0, 0.0])  # m/s: cruising along +x
    crowd = np.array([[0.2, 0.1, 0.0], [0.3, -0.1, 0.0], [0.2, 0.0, 0.1]])
    bias = right_hand_bias(x, heading, crowd, 2.0, 0.5, cruise_mps=0.8)
    v = turned(heading, bias)
    assert np.linalg.norm(v) == pytest.approx(0.8)  # the target speed, not sqrt(0.8^2 + 0.5^2)
    assert math.degrees(math.atan2(-v[1], v[0])) == pytest.approx(math.degrees(math.atan2(0.5, 0.8)))  # to the right
    assert (turned(heading, np.zeros(3)) == heading).all()
    slower = np.array([-0.3, 0.0, 0.0])  # a bias against the heading slows it, and stays so
    assert (turned(heading, slower) == heading + slower).all()
    assert not turned(np.zeros(3), np.zeros(3)).any()  # at rest (the bias is then zero too)


def test_right_hand_bias_turns_right_of_the_heading_for_agents_ahead_only():
    from swarm.control import right_hand_bias

    x, heading = np.zeros(3), np.array([1.0, 0.0, 0.0])
    ahead = np.array([[1.0, 0.0, 0.0]])
    b = right_hand_bias(x, heading, ahead, 2.0, 0.3)
    assert b[1] < 0 and b[0] == 0 and b[2] == 0  # facing +x with z up, right is -y
    assert np.linalg.norm(b) == pytest.approx(0.3 * 0.5)  # weight 1 - d / trigger
    assert not right_hand_bias(x, heading, -ahead, 2.0, 0.3).any()  # behind: nothing
    assert not right_hand_bias(x, heading, 3 * ahead, 2.0, 0.3).any()  # beyond the trigger: nothing
    crowd = np.array([[0.2, 0.1, 0.0], [0.3, -0.1, 0.0], [0.2, 0.0, 0.1]])
    assert np.linalg.norm(right_hand_bias(x, heading, crowd, 2.0, 0.3)) == pytest.approx(0.3)  # capped
    arriving = 0.1 * heading  # the tracker slows to 0.1 m/s near the goal, cruising at 1 m/s
    assert np.linalg.norm(right_hand_bias(x, arriving, crowd, 2.0, 0.3, cruise_mps=1.0)) == pytest.approx(0.03)


def test_with_their_velocities_the_tie_break_follows_agents_ahead_flying_its_way():
    """A lane's queue: the agent ahead flying this one's way (at least FOLLOW_FRACTION of its
    commanded speed along it) is followed; one stopped, crossing or coming against it still
    turns it right; without velocities every agent ahead counts, as before."""
    from swarm.control import FOLLOW_FRACTION, right_hand_bias

    x, heading = np.zeros(3), np.array([0.8, 0.0, 0.0])
    ahead = np.array([[0.5, 0.0, 0.0]])
    turning = right_hand_bias(x, heading, ahead, 1.2, 0.5)
    assert turning[1] < 0
    same_way = np.array([[0.8 * FOLLOW_FRACTION + 1e-6, 0.0, 0.0]])
    assert not right_hand_bias(x, heading, ahead, 1.2, 0.5, others_v_w=same_way).any()
    for v in ([0.8 * FOLLOW_FRACTION - 1e-3, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.8, 0.0], [-0.8, 0.0, 0.0]):
        np.testing.assert_allclose(right_hand_bias(x, heading, ahead, 1.2, 0.5, others_v_w=np.array([v])), turning)


def _bias_by_definition(x, heading, others, trigger_m, speed_mps, cruise_mps, others_v):
    """right_hand_bias's docstring in numpy: each agent in front within the trigger (less those
    flying this way) weighs 1 - d / trigger, the sum capped at 1, faded with the heading's speed."""
    n = math.hypot(heading[0], heading[1])
    if n < 1e-9 or len(others) == 0:
        return np.zeros(3)
    d = others - x
    dist = np.linalg.norm(d, axis=1)
    ahead = (d[:, 0] * heading[0] + d[:, 1] * heading[1] > 0) & (dist < trigger_m)
    if others_v is not None:
        from swarm.control import FOLLOW_FRACTION

        ahead &= others_v[:, 0] * heading[0] + others_v[:, 1] * heading[1] < FOLLOW_FRACTION * n * n
    weight = min(float(np.sum(1.0 - dist[ahead] / trigger_m)), 1.0) * min(1.0, n / cruise_mps)
    return np.array([heading[1] / n, -heading[0] / n, 0.0]) * speed_mps * weight


_coord = st.floats(-3.0, 3.0, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(
    others=st.lists(st.tuples(_coord, _coord, _coord), min_size=0, max_size=20),
    velocities=st.booleans(),
    heading=st.tuples(_coord, _coord, _coord),
    trigger_m=st.floats(0.1, 3.0),
    data=st.data(),
)
def test_the_tie_break_is_its_definition(others, velocities, heading, trigger_m, data):
    """The compiled sum over the agents ahead gives the bias of the docstring, on the rows as a
    neighbour table gives them (strided views of one record array)."""
    from swarm.control import right_hand_bias

    rows = ObstacleArrays.build(others or np.zeros((0, 3)), [0.1] * len(others))
    v = data.draw(st.lists(st.tuples(_coord, _coord, _coord), min_size=len(others), max_size=len(others)))
    rows.rec["cd"] = v or np.zeros((0, 3))
    x, h = np.array([0.1, -0.2, 1.0]), np.array(heading)
    others_v = rows.c_dot_w if velocities else None
    got = right_hand_bias(x, h, rows.c_w, trigger_m, 0.4, 0.8, others_v)
    want = _bias_by_definition(x, h, rows.c_w, trigger_m, 0.4, 0.8, others_v)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)


def test_a_tracker_moves_on_past_short_legs_it_was_pushed_beyond_but_not_through_a_wall():
    """A replanned path's first legs can be short steps from where the agent was to the
    grid; an agent carried past them tracks the leg it is at (within SKIP_AHEAD_M of path),
    not the start. A later leg that is nearer only across a wall (a U-turn, more path than
    that ahead) is not taken."""
    from swarm.control import SKIP_AHEAD_M

    W = np.array([[0.0, 0.0, 1.0], [-0.1, 0.05, 1.0], [-0.1, -0.2, 1.0], [0.2, -0.3, 1.0], [3.0, -0.3, 1.0]])
    tr = PathTracker(W, 0.8)
    c, tangent, remaining = tr.reference(np.array([0.6, -0.25, 1.0]))
    np.testing.assert_allclose(c, [0.6, -0.3, 1.0], atol=1e-12)
    np.testing.assert_allclose(tangent, [1.0, 0.0, 0.0], atol=1e-12)
    assert remaining == pytest.approx(2.4)
    assert tr.segment == 3
    U = np.array([[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [2.0, 1.0, 1.0], [0.0, 1.0, 1.0]])
    assert np.linalg.norm(np.diff(U, axis=0), axis=1)[:2].sum() - 0.1 > SKIP_AHEAD_M
    tr = PathTracker(U, 0.8)
    c, tangent, _ = tr.reference(np.array([0.1, 0.6, 1.0]))  # nearer the last leg, across the U
    np.testing.assert_allclose(c, [0.1, 0.0, 1.0], atol=1e-12)
    assert tr.segment == 0


def test_an_agent_carried_back_behind_a_leg_it_reached_is_not_sped_up_to_catch_it():
    """Backed out of a corridor 1.2 m behind the leg it was on: the tracker asks the target
    speed along the leg and corrects across it, not kp times the 1.2 m on top."""
    W = np.array([[3.0, 0.3, 1.0], [1.0, 0.0, 1.0], [-2.4, 0.0, 1.0]])
    tr = PathTracker(W, 0.8)
    tr.desired_velocity(np.array([0.9, 0.0, 1.0]))  # it reached the corridor's leg
    assert tr.segment == 1
    v = tr.desired_velocity(np.array([2.2, 0.1, 1.0]))  # backed out behind its start
    np.testing.assert_allclose(v, [-0.8, -1.5 * 0.1, 0.0], atol=1e-12)
    fresh = PathTracker(W, 0.8)  # never reached it: the first leg, as ever
    assert np.linalg.norm(fresh.desired_velocity(np.array([2.2, 0.1, 1.0]))) < 1.0


def _fly_alone(waypoints, speed, duration, cut_m=0.0):
    log = simulate(
        MODEL,
        FilterConfig(level=CommandLevel.ATTITUDE),
        PathTracker(waypoints, speed, cut_m=cut_m),
        ObstacleArrays.empty(),
        QuadState.hover(waypoints[0]),
        duration,
        control_hz=100.0,
        physics_hz=500.0,
        filter_on=False,
    )
    return np.array(log.t_s), log.array("x_w")


def test_from_rest_the_tracker_arrives_within_a_few_tenths_of_a_second_of_the_path_at_full_speed():
    """4 m from rest at 0.8 m/s: within the goal tolerance (0.15 m) no more than 0.35 s
    after a point flying the whole path at 0.8 m/s would be (the velocity loop's lag at
    the start and the braking at the end; a taper of kp times the distance left and kd 3
    lost 0.7 s), then it stops at the goal without overshooting it."""
    goal = np.array([4.0, 0.0, 1.0])
    t, x = _fly_alone([[0.0, 0.0, 1.0], goal], 0.8, 8.0)
    d = np.linalg.norm(x - goal, axis=1)
    arrival = t[np.flatnonzero(d <= 0.15)[0]]
    assert arrival <= (4.0 - 0.15) / 0.8 + 0.35
    assert x[:, 0].max() <= goal[0] + 0.02
    assert d[-1] < 0.01


@pytest.mark.parametrize("d", [3.0, 0.4, 0.25, 0.1, 0.02])
def test_the_commanded_speed_is_the_braking_profile_and_its_slope_the_feedforward(d):
    """By the profile's definition: the least of the target speed and
    ``sqrt(2 a (d - a / (2 kp^2)))`` (``kp d`` within ``a / kp^2`` of the goal); the
    braking rate ``command`` returns is its derivative along the path (finite differences),
    and ``desired_accel`` takes that much times the speed off (feedforward)."""
    g = TrackingGains()
    tr = PathTracker([[0.0, 0.0, 1.0], [5.0, 0.0, 1.0]], 0.8, g)
    a, kp = g.brake_mps2, g.kp_per_s

    def profile(r):
        return min(0.8, kp * r if r <= a / kp**2 else math.sqrt(2 * a * (r - 0.5 * a / kp**2)))

    x = np.array([5.0 - d, 0.0, 1.0])
    v, brake = tr.command(x)
    np.testing.assert_allclose(v, [profile(d), 0.0, 0.0], atol=1e-12)
    eps = 1e-6
    assert brake == pytest.approx((profile(d + eps) - profile(d - eps)) / (2 * eps), rel=1e-5, abs=1e-9)
    moving = np.array([profile(d), 0.0, 0.0])  # flying at the commanded velocity
    np.testing.assert_allclose(tr.desired_accel(x, moving), [-brake * profile(d), 0.0, 0.0], atol=1e-9)


def test_near_the_goal_the_tracker_points_straight_at_it_from_off_the_path():
    """By definition: on the last leg within ``speed / kc`` of the goal the commanded
    velocity points from the agent straight at the goal, its size the braking profile of
    the distance; further back it is the tangent plus ``kc`` times the error across it."""
    g = TrackingGains()
    tr = PathTracker([[0.0, 0.0, 1.0], [4.0, 0.0, 1.0]], 0.8, g)
    x = np.array([3.7, 0.25, 1.0])  # 0.3 m of path left, 0.25 m beside it
    v, _ = tr.command(x)
    to_goal = np.array([4.0, 0.0, 1.0]) - x
    d = float(np.linalg.norm(to_goal))
    a, kp = g.brake_mps2, g.kp_per_s
    np.testing.assert_allclose(v, to_goal / d * min(0.8, math.sqrt(2 * a * (d - 0.5 * a / kp**2))), atol=1e-12)
    nearer = np.array([3.9, 0.1, 1.0])  # braking: 0.14 m from the goal
    v, _ = tr.command(nearer)
    d = math.hypot(0.1, 0.1)
    np.testing.assert_allclose(v, (np.array([4.0, 0.0, 1.0]) - nearer) / d * kp * d, atol=1e-12)
    far, _ = tr.command(np.array([3.0, 0.25, 1.0]))  # 1 m left: along the path, back across it
    np.testing.assert_allclose(far, [0.8, -g.kc_per_s * 0.25, 0.0], atol=1e-12)


def test_a_drone_near_its_goal_but_beside_its_path_flies_to_the_goal_not_past_it():
    """Flying along the path at 0.8 m/s, 0.3 m beside it and 0.3 m before the goal (as a
    neighbour alongside leaves a drone in a crowd): within the goal tolerance no later than
    0.2 s after flying straight at it at 0.8 m/s would be, not carried past the goal along
    the path (measured: 0.48 s against 0.34 s, 1 cm; along the path's direction with the
    cross-track term, 0.73 s and 11 cm past it)."""
    W = np.array([[0.0, 0.0, 1.0], [4.0, 0.0, 1.0]])
    start = QuadState.hover(np.array([3.7, 0.3, 1.0]))
    start.v_w = np.array([0.8, 0.0, 0.0])
    log = simulate(
        MODEL,
        FilterConfig(level=CommandLevel.ATTITUDE),
        PathTracker(W, 0.8),
        ObstacleArrays.empty(),
        start,
        3.0,
        control_hz=100.0,
        physics_hz=500.0,
        filter_on=False,
    )
    t, x = np.array(log.t_s), log.array("x_w")
    d = np.linalg.norm(x - W[-1], axis=1)
    assert t[np.flatnonzero(d <= 0.15)[0]] <= (math.hypot(0.3, 0.3) - 0.15) / 0.8 + 0.2
    assert x[:, 0].max() <= W[-1, 0] + 0.03
    assert d[-1] < 0.01


@settings(max_examples=150, deadline=None)
@given(
    way=st.lists(st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0)), min_size=2, max_size=6),
    at=st.floats(0.0, 1.0),
    cut=st.floats(0.0, 0.2),
)
def test_the_aim_cuts_no_corner_by_more_than_the_cut(way, at, cut):
    """Whatever the path and wherever along it the agent is: the chord from its closest
    path point to the point it aims at passes every corner between within ``cut_m`` (so a
    path that keeps ``cut_m`` beyond the safety radius from the walls is flown outside
    it), and the aim point is on the path, no further than ``speed / kc`` of path ahead."""
    W = np.array([[x, y, 1.0] for x, y in way])
    tr = PathTracker(W, 0.8, cut_m=cut)
    seg = np.linalg.norm(np.diff(W, axis=0), axis=1)
    s_at = at * seg.sum()
    head = np.concatenate([[0.0], np.cumsum(seg)])
    i = min(int(np.searchsorted(head, s_at, side="right")) - 1, len(seg) - 1)
    x = W[i] + (W[i + 1] - W[i]) * ((s_at - head[i]) / seg[i] if seg[i] > 1e-9 else 0.0)
    for _ in range(len(W)):  # the segment moves on at most a metre of path per call
        c, _, remaining = tr.reference(x)
    p = tr.aim(x)
    s_c = seg.sum() - remaining

    on_path = []  # where along the path p lies, at or after the closest point (a path may cross itself)
    for k in range(len(seg)):
        t = 0.0 if seg[k] < 1e-9 else float(np.clip((p - W[k]) @ (W[k + 1] - W[k]) / seg[k] ** 2, 0, 1))
        if np.linalg.norm(W[k] + t * (W[k + 1] - W[k]) - p) < 1e-9 and head[k] + t * seg[k] >= s_c - 1e-9:
            on_path.append(head[k] + t * seg[k])
    assert on_path
    s_p = min(on_path)
    assert s_p <= s_c + 0.8 / TrackingGains().kc_per_s + 1e-9
    between = [k for k in range(1, len(W) - 1) if s_c < head[k] < s_p - 1e-9]
    for k in between:
        d = p - c
        t = float(np.clip((W[k] - c) @ d / max(d @ d, 1e-18), 0, 1))
        assert np.linalg.norm(c + t * d - W[k]) <= cut + 1e-6


def test_cutting_corners_by_the_cut_shortens_the_flight_and_keeps_near_the_path():
    """A zigzag of right-angle corners flown from rest with a 0.1 m cut: sooner at the goal
    than corner by corner, and never further from the path than the cut plus the
    tracking's few centimetres."""
    W = np.array([[0, 0, 1.0], [1.5, 0, 1.0], [1.5, 1.0, 1.0], [3.0, 1.0, 1.0], [3.0, 2.0, 1.0]])
    times = {}
    for cut in (0.0, 0.1):
        t, x = _fly_alone(W, 0.8, 12.0, cut_m=cut)
        times[cut] = t[np.flatnonzero(np.linalg.norm(x - W[-1], axis=1) <= 0.15)[0]]
        legs = [(W[k], W[k + 1] - W[k]) for k in range(len(W) - 1)]
        off = max(min(np.linalg.norm(a + np.clip((p - a) @ d / (d @ d), 0, 1) * d - p) for a, d in legs) for p in x)
        assert off <= cut + 0.07  # (measured: 0.064 m past the corners at 0, 0.074 m inside them at 0.1)
    assert times[0.1] < times[0.0] - 0.5  # (measured: 6.18 s against 7.07 s)
