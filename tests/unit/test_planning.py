"""Reference paths around static obstacles (swarm.planning, swarm.route, swarm.tuning) by what they promise: a path
keeps the clearance it is asked for, goes where the straight line cannot, says when there
is no way, and replans a stalled agent; and the filter keeps its guarantee whatever path it
is given."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.build import filter_of, obstacle_horizon_of, path_of
from swarm.config import WorldSettings, resolve
from swarm.control import PathTracker, reference_thrust
from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.offline.closed_loop import fly_scenario
from swarm.offline.scenario import corridor, doorway, forest, trap
from swarm.planning import LANE_MARGIN_M, PlannerSettings, StaticObstacles, clear, plan
from swarm.route import Route, corner_cut_m
from swarm.safety.filter import FilterConfig, FilterStatus, SafetyFilter
from swarm.safety.obstacles import ObstacleArrays

from .helpers import planned

pytestmark = pytest.mark.unit

R = 0.09  # an agent's safety radius against a static obstacle [m]
KEEP = R + PlannerSettings().clearance_m


def pillars(xy: list[tuple[float, float]], r: float = 0.15) -> StaticObstacles:
    n = len(xy)
    c = np.array([[x, y, 1.0] for x, y in xy], dtype=float).reshape(n, 3)
    return StaticObstacles(c, np.full(n, r), np.tile([0.0, 0.0, 1.0], (n, 1)))


def of_scene(raw: dict) -> StaticObstacles:
    return StaticObstacles.of(list(resolve(raw).obstacles))


def keeps(waypoints: np.ndarray, obstacles: StaticObstacles, keep: float) -> bool:
    legs = zip(waypoints[:-1], waypoints[1:], strict=True)
    return all(  # sampled every 2 mm (apart from the planner's own exact check)
        obstacles.clearance(np.linspace(a, b, max(2, int(np.linalg.norm(b - a) / 0.002) + 2))).min() >= keep - 1e-9
        for a, b in legs
    )


@settings(max_examples=200, deadline=None)
@given(
    xy=st.lists(st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0)), min_size=1, max_size=6),
    ends=st.tuples(*[st.floats(-3.0, 3.0)] * 4),
    r=st.floats(0.05, 0.4),
    keep=st.floats(0.0, 0.3),
)
def test_a_segment_is_clear_exactly_when_every_point_of_it_is(xy, ends, r, keep):
    obs = pillars(xy, r)
    a, b = np.array([ends[0], ends[1], 1.0]), np.array([ends[2], ends[3], 1.0])
    sampled = obs.clearance(np.linspace(a, b, 4001)).min()
    if abs(sampled - keep) > 1e-3:  # (sampling every 1.5 mm or less overestimates by at most ~1e-3 m)
        assert clear(a, b, obs, keep) == (sampled >= keep)


def test_a_clear_straight_line_is_the_plan():
    p = plan([0, 0, 1.0], [4, 0, 1.0], pillars([(2.0, 1.0)]), R)
    assert p.found and p.reason == "straight" and p.waypoints_w.shape == (2, 3)


@pytest.mark.parametrize("start, goal", [((-3, 1.5), (3, 1.5)), ((-3, -1.5), (3, 2.0))])
def test_a_path_through_the_doorway_keeps_its_clearance(start, goal):
    obs = of_scene(doorway(2))
    a, b = np.array([*start, 1.0]), np.array([*goal, 1.0])
    p = plan(a, b, obs, R)
    assert p.found and p.reason == "planned"
    assert np.array_equal(p.waypoints_w[0], a) and np.array_equal(p.waypoints_w[-1], b)
    assert keeps(p.waypoints_w, obs, KEEP)
    assert abs(p.waypoints_w[:, 0]).min() < 0.5 and abs(p.waypoints_w[np.argmin(abs(p.waypoints_w[:, 0])), 1]) < 0.4
    assert p.length_m < 1.2 * (math.dist(a, [0, 0, 1.0]) + math.dist([0, 0, 1.0], b))  # near the shortest way


def test_the_trap_s_way_out_is_round_the_opening():
    cfg = resolve(trap())
    obs, a = StaticObstacles.of(list(cfg.obstacles)), cfg.agents[0]
    p = plan(np.array(a.start), np.array(a.goal), obs, R)
    assert p.found and keeps(p.waypoints_w, obs, KEEP)
    assert p.waypoints_w[:, 0].max() > 2.0  # out through the opening beyond the arms' ends (x = 2)
    assert p.length_m > 1.5 * math.dist(a.start, a.goal)  # out, round an arm and back


@pytest.mark.parametrize("ring_m, count, why", [(0.6, 10, "no free path"), (0.3, 6, "start or goal walled in")])
def test_a_goal_walled_in_has_no_path_and_says_so(ring_m, count, why):
    """A ring of touching pillars round the goal: free inside it (0.6 m) or not (0.3 m)."""
    ring = [(2 + ring_m * math.cos(t), ring_m * math.sin(t)) for t in np.linspace(0, 2 * math.pi, count + 1)[:-1]]
    p = plan([-2, 0, 1.0], [2, 0, 1.0], pillars(ring, r=0.2), R)
    assert not p.found and p.reason == why
    np.testing.assert_array_equal(p.waypoints_w, [[-2, 0, 1.0], [2, 0, 1.0]])  # the straight line: the filter stops it


def test_an_isolated_pillar_is_left_to_the_filter():
    p = plan([-2, 0, 1.0], [2, 0, 1.0], pillars([(0.0, 0.0)]), R)
    assert p.found and p.reason == "straight"  # its live rows pass it on their own


def test_a_start_inside_the_clearance_still_gets_a_path():
    obs = pillars([(0.0, -0.3), (0.0, 0.0), (0.0, 0.3)])  # a short wall
    p = plan([-0.3, 0.0, 1.0], [2.0, 0.0, 1.0], obs, R)  # 0.15 m from the surface: inside R + clearance
    assert p.found and np.array_equal(p.waypoints_w[0], [-0.3, 0.0, 1.0])
    assert keeps(p.waypoints_w[1:], obs, KEEP)


def test_a_grid_too_large_is_refused_by_name():
    with pytest.raises(Exception, match="max_cells"):
        plan([-3, 1.5, 1.0], [3, 1.5, 1.0], of_scene(doorway(2)), R, PlannerSettings(resolution_m=0.01))


def test_a_stalled_agent_replans_from_where_it_is_and_a_moving_one_does_not():
    obs = of_scene(doorway(2))
    route = Route(obs, R, stall_s=2.0, progress_m=0.3)
    first = route.first(np.array([-3, 1.5, 1.0]), np.array([3, 1.5, 1.0]))
    goal = first.waypoints_w[-1]
    for k in range(40):  # progressing 0.1 m every 0.1 s
        assert route.update(0.1 * k, np.array([-3 + 0.1 * k, 1.5, 1.0]), goal, first.length_m - 0.1 * k) is None
    here = np.array([-0.5, 1.0, 1.0])
    news = [route.update(4.0 + 0.1 * k, here, goal, 2.0) for k in range(30)]  # stuck: no progress for 3 s
    replanned = [p for p in news if p is not None]
    assert len(replanned) == 1 and route.replans == 1
    assert np.array_equal(replanned[0].waypoints_w[0], here) and np.array_equal(replanned[0].waypoints_w[-1], goal)


@settings(max_examples=60, deadline=None)
@given(
    xy=st.lists(st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0)), min_size=1, max_size=12),
    r=st.floats(0.1, 0.4),
    seed=st.integers(0, 1000),
)
def test_every_planned_segment_keeps_its_clearance(xy, r, seed):
    """Walls of two touching pillars each, anywhere: every segment keeps the clearance from
    every wall (isolated pillars are the filter's)."""
    rng = np.random.default_rng(seed)
    obs = pillars([c for x, y in xy for c in ((x, y), (x, y + 2 * r))], r)
    a = np.array([-3.5, rng.uniform(-2, 2), 1.0])
    b = np.array([3.5, rng.uniform(-2, 2), 1.0])
    p = plan(a, b, obs, R, PlannerSettings(resolution_m=0.1))
    assert np.all(np.isfinite(p.waypoints_w))
    assert np.array_equal(p.waypoints_w[0], a) and np.array_equal(p.waypoints_w[-1], b)
    if p.found:
        assert keeps(p.waypoints_w, obs.clustered(2 * KEEP), KEEP)
    else:
        assert p.waypoints_w.shape == (2, 3)


@settings(max_examples=80, deadline=None)
@given(
    way=st.lists(st.tuples(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5)), min_size=1, max_size=5),
    pos=st.tuples(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5)),
    vel=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)),
    cut=st.floats(0.0, 0.3),
)
def test_whatever_path_the_tracker_is_given_the_filter_s_command_keeps_every_row(way, pos, vel, cut):
    """Waypoints anywhere (through the pillar, behind the drone, a single point), corners
    cut by any amount: the reference they make is only a reference; the filter's command
    satisfies every row whenever it reports OK, and is finite always."""
    model = QuadModel()
    filt = SafetyFilter(model, FilterConfig(level=CommandLevel.ATTITUDE, gamma=2.0, floor_z_m=None))
    obs = ObstacleArrays.build(c_w=[[0.0, 0.0, 1.0]], radius_m=[0.3], axis_w=[[0.0, 0.0, 1.0]])
    x = np.array([*pos, 1.0])
    if np.hypot(*pos) < 0.3 + 0.11:
        x[:2] = np.array(pos) / max(np.hypot(*pos), 1e-3) * 0.5  # outside the safety radius
    state = QuadState.hover(x)
    state.v_w = np.array([*vel, 0.0])
    tracker = PathTracker(np.array([x, *[[wx, wy, 1.0] for wx, wy in way]]), 0.8, cut_m=cut)
    F = reference_thrust(model, tracker, state.x_w, state.v_w, state.x_w, np.zeros((0, 3)), None)
    res = filt.filter(state, F, obs)
    assert np.all(np.isfinite(res.u))
    if res.status is FilterStatus.OK:
        assert res.max_violation <= 1e-6 and (res.constraint >= -1e-6).all()


def test_a_path_straight_through_a_pillar_is_flown_without_touching_it():
    """The planner's worst case (a stale path through an obstacle): the filter alone keeps
    the drone outside its safety radius."""
    cfg = resolve(doorway(2))
    wall = [o for o in cfg.obstacles if o.id == "wall_l3"][0]
    horizon_s = planned(cfg)[0].config.obstacle_horizon_s  # the filter's, as on its planned path
    one = cfg.agents[0].model_copy(
        update={
            "start": [-2.0, wall.center[1], 1.0],
            "goal": [2.0, wall.center[1], 1.0],  # straight through the pillar: no path planned
            "speed_mps": 0.8,
            "planner": cfg.agents[0].planner.model_copy(update={"kind": "none"}),
            "filter": cfg.agents[0].filter.model_copy(update={"obstacle_horizon_s": horizon_s}),
        }
    )
    log = fly_scenario(cfg.model_copy(update={"agents": [one], "duration_s": 6.0, "world": WorldSettings()}))
    assert log.min_clearance_m >= R - 0.01  # the safety radius, less the attitude lag's few mm


@pytest.mark.parametrize("make", [lambda: doorway(6), lambda: corridor(4), trap])
def test_a_route_s_tracker_cuts_corners_only_within_the_clearance_its_path_keeps_from_the_walls(make):
    """The tracker may cut a planned path's corners by ``Route.cut_m``: never more than the
    planner's clearance, never negative, and the path keeps the safety radius plus that
    much from every wall it was planned round (so the cut reference keeps the safety
    radius). The trap's path keeps the whole clearance; a lane only its few centimetres."""
    cfg = resolve(make())
    still = StaticObstacles.of(list(cfg.obstacles))
    walls = still.clustered(2 * KEEP)
    agents = planned(cfg)
    for a in agents:
        cut = corner_cut_m(a.route)
        assert 0.0 <= cut <= PlannerSettings().clearance_m
        assert keeps(a.path_w, walls, R + cut - 1e-3)
        if a.route is not None and a.route.lanes:
            assert cut < LANE_MARGIN_M + 0.01
    if make is trap:
        assert corner_cut_m(agents[0].route) == pytest.approx(PlannerSettings().clearance_m)
    assert corner_cut_m(None) == 0.0


@pytest.mark.parametrize("make", [lambda: doorway(6), lambda: corridor(4), trap, lambda: forest(4, 0.6)])
def test_every_scene_among_walls_is_valid_and_planned_round_its_walls(make):
    cfg = resolve(make())
    still = StaticObstacles.of(list(cfg.obstacles))
    agents = planned(cfg)
    for spec, a in zip(cfg.agents, agents, strict=True):
        path = a.path_w
        assert np.array_equal(path[-1], spec.goal)
        lane = a.route is not None and a.route.lanes
        keep = R + LANE_MARGIN_M if lane else KEEP  # a lane keeps its margin, not the clearance
        assert keeps(path[1:-1], still, keep - 0.005) if len(path) > 3 else True


def _corridor_routes() -> tuple[list, list]:
    raw = corridor(1)  # one drone each way, the corridor taken in turn (no lanes)
    raw["defaults"]["planner"] = {"lanes": False}
    cfg = resolve(raw)
    agents = planned(cfg)
    return agents, [a.path_w for a in agents]


@pytest.mark.parametrize("left_m, right_m", [(0.5, 0.8), (0.8, 0.5), (0.6, 0.6)])
def test_of_two_drones_at_the_two_ends_of_a_passage_exactly_one_gives_way(left_m, right_m):
    """Each decides alone from the other's position: the nearer goes, a tie by position."""
    from swarm.route import gives_way

    agents, paths = _corridor_routes()
    at = []
    for a, dist in zip(agents, (left_m, right_m), strict=True):
        p = a.route.passage
        back = (p.entry_w - p.points_w[min(5, len(p.points_w) - 1)]) / np.linalg.norm(
            p.entry_w - p.points_w[min(5, len(p.points_w) - 1)]
        )
        at.append((p.s_in_m - dist, p.entry_w + dist * back))
    flying = []  # each flies at its passage's entry at 0.5 m/s
    for a, (_, x) in zip(agents, at, strict=True):
        to_entry = a.route.passage.entry_w - x
        flying.append(0.5 * to_entry / np.linalg.norm(to_entry))
    waits = [
        gives_way(a.route.passage, s, x, np.array([at[1 - i][1]]), np.array([flying[1 - i]]))
        for i, (a, (s, x)) in enumerate(zip(agents, at, strict=True))
    ]
    parked = [gives_way(a.route.passage, s, x, np.array([at[1 - i][1]]), np.zeros((1, 3))) for i, (a, (s, x)) in
              enumerate(zip(agents, at, strict=True))]  # fmt: skip
    assert not any(parked)  # an agent at rest beyond the passage (parked at its goal) holds no one back
    assert sum(waits) == 1
    if left_m != right_m:
        assert waits == [left_m > right_m, right_m > left_m]  # the farther one waits


def test_drones_going_the_same_way_through_a_passage_follow_each_other():
    from swarm.route import gives_way

    agents, _ = _corridor_routes()
    p = agents[0].route.passage
    ahead = p.points_w[len(p.points_w) // 2]  # in the passage, moving my way
    assert not gives_way(p, p.s_in_m - 0.5, p.entry_w - [0.5, 0, 0], ahead[None], np.array([[0.8, 0.0, 0.0]]))
    assert gives_way(p, p.s_in_m - 0.5, p.entry_w - [0.5, 0, 0], ahead[None], np.array([[-0.8, 0.0, 0.0]]))


@pytest.mark.parametrize("depth", [0.3, 1.0, 1.7])
def test_of_two_drones_that_meet_inside_a_passage_exactly_one_backs_out(depth):
    """Two drones of the opposite flows face each other inside the corridor, ``depth`` [m]
    into it from the left and 0.4 m apart, at rest: each decides from its own direction
    and what it hears, one backs out along its way at the route's back speed, the other
    flies its path; once out, the one that backed out hovers beside the mouth."""
    from swarm.route import keeps_passage

    agents, _ = _corridor_routes()
    left, right = agents
    p_l, p_r = left.route.passage, right.route.passage
    x_l = p_l.entry_w + depth * (p_l.exit_w - p_l.entry_w) / np.linalg.norm(p_l.exit_w - p_l.entry_w)
    x_r = x_l + 0.4 * (p_l.exit_w - p_l.entry_w) / np.linalg.norm(p_l.exit_w - p_l.entry_w)
    rest = np.zeros((1, 3))
    s_l = p_l.s_in_m + depth
    s_r = p_r.s_in_m + float(np.linalg.norm(x_r - p_r.entry_w))
    held_l = left.route.hold(10.0, left.route.length_m - s_l, x_l, x_r[None], rest)
    held_r = right.route.hold(10.0, right.route.length_m - s_r, x_r, x_l[None], rest)
    along_l = (p_l.exit_w - p_l.entry_w) / np.linalg.norm(p_l.exit_w - p_l.entry_w)
    assert keeps_passage(along_l) != keeps_passage(-along_l)
    assert (held_l is None) != (held_r is None)  # exactly one gives way
    backing, route, x, along = (
        (held_r, right.route, x_r, -along_l) if held_l is None else (held_l, left.route, x_l, along_l)
    )
    np.testing.assert_allclose(backing, -route.back_mps * along, atol=1e-9)  # back along its own way
    other = x_l if backing is held_r else x_r
    beside = route.passage.entry_w - 0.7 * along  # out of the passage, 0.7 m before its mouth
    np.testing.assert_allclose(route.hold(11.0, route.length_m, beside, other[None], rest), np.zeros(3))
    assert route.hold(12.0, route.length_m, beside, np.array([[0.0, 5.0, 1.0]]), rest) is None  # the way is clear


def test_a_drone_of_the_same_flow_in_the_passage_is_followed_not_backed_from():
    agents, _ = _corridor_routes()
    route = agents[0].route
    p = route.passage
    along = (p.exit_w - p.entry_w) / np.linalg.norm(p.exit_w - p.entry_w)
    x = p.entry_w + 0.5 * along
    ahead = (x + 0.5 * along)[None]
    assert route.hold(1.0, route.length_m - p.s_in_m - 0.5, x, ahead, 0.8 * along[None]) is None


def test_two_drones_stopped_at_the_two_mouths_do_not_both_wait():
    """Each stopped just before its own mouth, inside the other's passage (a wait that used
    to hold both flows until MAX_WAIT_S): the one nearer its mouth goes."""
    from swarm.route import gives_way

    agents, _ = _corridor_routes()
    at = []
    for a, dist in zip(agents, (0.05, 0.15), strict=True):
        p = a.route.passage
        at.append((p.s_in_m - dist, p.entry_w - dist * p.along_w))
    for a, (_, x) in zip(agents[::-1], at, strict=True):
        assert a.route.passage.holds(x[None])[0]  # each inside the other's passage
    rest = np.zeros((1, 3))
    waits = [
        gives_way(a.route.passage, s, x, at[1 - i][1][None], rest)
        for i, (a, (s, x)) in enumerate(zip(agents, at, strict=True))
    ]
    assert waits == [False, True]


def test_a_drone_follows_its_flow_past_one_stopped_at_the_far_mouth():
    from swarm.route import gives_way

    agents, _ = _corridor_routes()
    p = agents[0].route.passage
    x = p.entry_w - 0.5 * p.along_w
    mate = p.points_w[len(p.points_w) // 2]  # in the passage, flying this way
    far = p.exit_w + 0.05 * p.along_w  # stopped at the far mouth, nearer its end than x is to its own
    others = np.array([mate, far])
    assert gives_way(p, p.s_in_m - 0.5, x, far[None], np.zeros((1, 3)))  # alone it holds this one back
    assert not gives_way(p, p.s_in_m - 0.5, x, others, np.array([0.8 * p.along_w, np.zeros(3)]))
    coming = np.array([0.8 * p.along_w, -0.5 * p.along_w])  # unless it flies in against the flow
    assert gives_way(p, p.s_in_m - 0.5, x, np.array([mate, p.exit_w - 0.3 * p.along_w]), coming)


def test_a_drone_stopped_behind_in_the_passage_does_not_turn_the_flow_back():
    """A drone of the flow that backs out, inside the passage: one stopped ahead of it makes it
    back out; one of its own flow stopped behind it (backing out itself, or slowed) does not,
    so a flow inside a corridor does not turn round behind its last drone."""
    from swarm.route import keeps_passage

    agents, _ = _corridor_routes()
    route = next(a.route for a in agents if not keeps_passage(a.route.passage.along_w))
    p = route.passage
    x = p.entry_w + 1.0 * p.along_w
    remaining = route.length_m - p.s_in_m - 1.0
    rest = np.zeros((1, 3))
    behind, ahead = x - 0.5 * p.along_w, x + 0.5 * p.along_w
    assert route.hold(1.0, remaining, x, behind[None], rest) is None
    assert route.hold(1.0, remaining, x, behind[None], -0.3 * p.along_w[None]) is None
    np.testing.assert_allclose(route.hold(1.0, remaining, x, ahead[None], rest), -route.back_mps * p.along_w)


def test_an_agent_on_a_path_round_walls_relaxes_its_obstacles_cones_and_only_then():
    from swarm.offline.scenario import circle_swap
    from swarm.tuning import HORIZON_SPEED_PER_GAIN_M

    walled = resolve(corridor(1))
    still = StaticObstacles.of(list(walled.obstacles))
    a = walled.agents[0]
    assert obstacle_horizon_of(a, still) == a.planner.obstacle_horizon_s == 3.0
    assert filter_of(a, still, CommandLevel.ATTITUDE).obstacle_horizon_s == 3.0
    for off in ({"obstacle_horizon_s": None}, {"kind": "none"}):
        assert obstacle_horizon_of(a.model_copy(update={"planner": a.planner.model_copy(update=off)}), still) is None
    mine = a.model_copy(update={"filter": a.filter.model_copy(update={"obstacle_horizon_s": 5.0})})
    assert obstacle_horizon_of(mine, still) == 5.0  # the filter's own setting wins
    paper = a.model_copy(update={"filter": a.filter.model_copy(update={"gamma": 1.0})})  # 0.8 m/s at gain 1
    assert a.speed_mps / a.filter.gamma <= HORIZON_SPEED_PER_GAIN_M < paper.speed_mps / paper.filter.gamma
    assert obstacle_horizon_of(paper, still) == pytest.approx(6.0)  # stretched by speed / gain over 0.4 m
    slow = paper.model_copy(update={"speed_mps": 0.3})
    assert obstacle_horizon_of(slow, still) == 3.0  # within 0.4 m: as written, never shortened
    assert obstacle_horizon_of(paper.model_copy(update={"speed_mps": 1.2}), still) == pytest.approx(9.0)
    open_space = resolve(circle_swap(4))
    assert obstacle_horizon_of(open_space.agents[0], StaticObstacles.of(list(open_space.obstacles))) is None
    assert filter_of(open_space.agents[0], StaticObstacles.of([]), CommandLevel.ATTITUDE) == open_space.agents[
        0
    ].filter.filter_config(CommandLevel.ATTITUDE)


def test_a_two_way_corridor_written_at_the_paper_s_gain_brings_every_drone_home():
    """A hand-written config's default gain (gamma 1, the paper's) at 0.8 m/s: two drones each
    way through a corridor too narrow to pass in. With the obstacle horizon stretched to 6 s
    all four are home without contact or a slip into the safety radius; with every pillar's
    whole cone (the horizon off, as it was at this gain) the two that meet mid-way never are.
    The keep-out ellipsoid keeps those two from climbing one over the other (with the sphere,
    ``filter.ellipsoid: false``, they slip into their safety radius; in the ideal world one
    contact: CHANGELOG, Known issues)."""
    from swarm.offline.closed_loop import outcome

    raw = corridor(2)
    del raw["defaults"]["filter"]["gamma"]  # the config's default (swarm scenario writes 2)
    cfg = resolve(raw)
    assert cfg.agents[0].filter.gamma == 1.0
    agents = planned(cfg)
    still = StaticObstacles.of(list(cfg.obstacles))
    assert all(a.config.obstacle_horizon_s == pytest.approx(6.0) for a in agents)
    assert obstacle_horizon_of(cfg.agents[0], still) == pytest.approx(6.0)
    # in the world the config says (swarm scenario writes the lab's), as its margins are sized for
    log = fly_scenario(cfg)
    o = outcome(cfg, log)
    assert log.all_reached, log.time_to_goal_s
    assert o.collisions == 0 and o.margin_violations == 0


def test_an_agent_brakes_before_it_turns_away_from_a_wall_its_velocity_runs_into_and_only_then():
    """Route.turns: by a doorway's wall, a velocity pointed at the junction of two of its
    pillars while the path asks for one towards the doorway brakes; not a velocity along the
    path (within TURN_ANGLE_DEG), not one that runs into no wall within TURN_REACH_M, not an
    agent already at rest."""
    from swarm.route import TURN_ANGLE_DEG, TURN_REACH_M, TURN_REST_MPS

    route = Route(of_scene(doorway(4)), 0.16)
    x = np.array([-0.63, -0.37, 1.0])  # m: by the right-hand wall, 0.3 m before it
    to_junction = np.array([0.185, -0.129, 0.0])  # m/s: at the junction of its first two pillars
    to_doorway = np.array([0.88, 0.48, 0.0])  # m/s: the path's
    assert route.turns(x, to_junction, to_doorway)
    assert not route.turns(x, to_junction, to_junction * 4.0)  # the path flies where it flies
    a = math.radians(0.9 * TURN_ANGLE_DEG)
    c, s = math.cos(a), math.sin(a)
    along = np.array([c * to_junction[0] - s * to_junction[1], s * to_junction[0] + c * to_junction[1], 0.0])
    assert not route.turns(x, to_junction, along)  # within the angle: the rows turn it
    assert not route.turns(x, to_junction * (0.9 * TURN_REST_MPS / np.linalg.norm(to_junction)), to_doorway)
    back = x - TURN_REACH_M * to_junction / np.linalg.norm(to_junction)  # the wall now beyond reach
    assert not route.turns(back, to_junction, to_doorway)
    assert not route.turns(x, -to_junction, to_doorway)  # away from the wall


@pytest.mark.parametrize("start_xy, v_xy", [((-0.73, -0.30), (0.24, -0.165)), ((-0.9, -0.2), (0.3, -0.2))])
def test_a_drone_flying_into_the_junction_of_two_pillars_brakes_turns_and_is_through(start_xy, v_xy):
    """A hand-written config's gain (gamma 1): a drone by a doorway's wall, its velocity at the
    junction of two touching pillars, its path through the doorway. Each pillar's row turns it
    towards the other, so it can only brake; braking first (Route.turns), it is home in under 6
    s without contact and without replanning (it coasted to the wall and replanned after its
    4 s stall before: home at 11.3 and 10.2 s)."""
    from swarm.offline.closed_loop import outcome

    raw = doorway(1)
    del raw["defaults"]["filter"]["gamma"]
    raw["agents"][0].update(start=[*start_xy, 1.0], start_velocity=[*v_xy, 0.0], goal=[2.0, -0.5, 1.0])
    raw["duration_s"] = 8.0
    cfg = resolve(raw)
    assert planned(cfg)[0].route is not None
    log = fly_scenario(cfg)
    o = outcome(cfg, log)
    assert log.all_reached and log.time_to_goal_s[0] < 6.0, log.time_to_goal_s
    assert o.collisions == 0 and o.margin_violations == 0
    assert log.replans == [0]


def _lane_offsets(path: np.ndarray, x_lo: float, x_hi: float) -> np.ndarray:
    """The y [m] of the path ``path`` (k, 3) sampled along x in [x_lo, x_hi] (a path along x there)."""
    from swarm.planning import _sampled

    P = _sampled(path, 0.01)[0]
    keep = (P[:, 0] >= x_lo) & (P[:, 0] <= x_hi)
    return P[keep, 1]


def test_opposite_flows_fly_a_two_lane_corridor_each_in_its_right_hand_lane():
    """The corridor is 0.5 m between pillar surfaces: each flow's lane keeps (w - r) / 3 from
    the wall on its right, so the lanes keep the safety radius plus LANE_MARGIN_M from the
    walls and from each other; neither flow's route gives way there."""
    from swarm.planning import LANE_MARGIN_M, lane_wall_m

    cfg = resolve(corridor(4))
    agents = planned(cfg)
    r = cfg.agents[0].airframe.params().body_radius_m + cfg.agents[0].filter.margin_m
    wall = lane_wall_m(0.5, r)
    assert wall - r >= LANE_MARGIN_M and (0.5 - 2 * wall) - 2 * r >= LANE_MARGIN_M
    for spec, a in zip(cfg.agents, agents, strict=True):
        path = a.path_w
        east = spec.goal[0] > spec.start[0]
        y = _lane_offsets(path, -0.8, 0.8)  # inside the corridor, along its side walls
        assert len(y)
        np.testing.assert_allclose(y, -(0.25 - wall) if east else 0.25 - wall, atol=0.015)  # the right-hand lane
        assert a.route.lanes and a.route.passage is None  # no turn to wait for
        assert keeps(path[1:-1], StaticObstacles.of(list(cfg.obstacles)), r)


def test_lanes_are_for_long_passages_wide_enough_and_can_be_turned_off():
    from swarm.planning import LANE_MARGIN_M, LANE_MIN_LENGTH_M, has_lanes, keep_right, lane_wall_m

    r = 0.09
    wide_enough = 3 * (r + LANE_MARGIN_M) + r  # lane_wall_m(w, r) - r == LANE_MARGIN_M
    assert lane_wall_m(wide_enough, r) - r == pytest.approx(LANE_MARGIN_M)
    assert has_lanes(np.full(5, wide_enough + 1e-6), LANE_MIN_LENGTH_M, r)
    assert not has_lanes(np.array([wide_enough + 0.1, wide_enough - 1e-3]), LANE_MIN_LENGTH_M, r)  # narrowest point
    assert not has_lanes(np.full(5, 1.0), LANE_MIN_LENGTH_M - 0.01, r)  # a doorway: crossed in turn
    door = resolve(doorway(6))  # its gap is a short stretch: paths as planned, the gap taken in turn
    still = StaticObstacles.of(list(door.obstacles))
    for a in planned(door):
        path = a.path_w
        np.testing.assert_array_equal(keep_right(path, still, r), path)
        assert not a.route.lanes and a.route.passage is not None
    agents, _ = _corridor_routes()  # planner.lanes false: the corridor in turn, on its centre line
    for a in agents:
        assert not a.route.lanes and a.route.passage is not None
        assert np.abs(_lane_offsets(a.path_w, -0.8, 0.8)).max() < 0.07


def test_a_lane_flying_agent_gets_the_lane_contact_horizon_and_no_buffer_and_only_it():
    from swarm.route import follows
    from swarm.tuning import LANE_CONTACT_S

    cfg = resolve(corridor(1))
    still = StaticObstacles.of(list(cfg.obstacles))
    a = cfg.agents[0]
    _, route = path_of(a, still)
    assert route is not None and route.lanes and follows(route)
    assert not follows(None)
    lane = filter_of(a, still, CommandLevel.ATTITUDE, route)
    assert lane.contact_s == LANE_CONTACT_S and lane.buffer_mps == 0.0
    plain = filter_of(a, still, CommandLevel.ATTITUDE)
    assert plain.contact_s == a.filter.contact_s == 0.0 and plain.buffer_mps == a.filter.buffer_mps > 0
    longer = a.model_copy(update={"filter": a.filter.model_copy(update={"contact_s": 2.0})})
    assert filter_of(longer, still, CommandLevel.ATTITUDE, route).contact_s == 2.0  # a longer one kept
    raw = corridor(1)
    raw["defaults"]["planner"] = {"lanes": False}
    off = resolve(raw)
    _, in_turn = path_of(off.agents[0], still)
    assert not follows(in_turn)  # the tie-break turns from every agent ahead, as in the open
    turn = filter_of(off.agents[0], still, CommandLevel.ATTITUDE, in_turn)
    assert turn.contact_s == 0.0 and turn.buffer_mps == a.filter.buffer_mps


def _corridor_walls(angle: float, width_m: float, length_m: float) -> StaticObstacles:
    """Two walls of overlapping pillars (radius 0.15 m, 0.2 m apart) along the unit axis at
    ``angle`` [rad] through the origin, ``width_m`` apart at the pillars' tips."""
    axis, side = np.array([math.cos(angle), math.sin(angle), 0.0]), np.array([-math.sin(angle), math.cos(angle), 0.0])
    s = np.arange(-length_m / 2, length_m / 2 + 1e-9, 0.2)
    c = [a * axis + k * (width_m / 2 + 0.15) * side + [0, 0, 1.0] for a in s for k in (1.0, -1.0)]
    return StaticObstacles(np.array(c), np.full(len(c), 0.15), np.tile([0.0, 0.0, 1.0], (len(c), 1)))


@settings(max_examples=60, deadline=None)
@given(angle=st.floats(0.0, 2 * math.pi), width=st.floats(0.3, 0.85), length=st.floats(1.0, 3.0))
def test_lanes_keep_their_margin_from_the_walls_and_each_other_whatever_the_corridor(angle, width, length):
    """Any corridor of pillars, any heading: where it has lanes, each way's path keeps the
    safety radius plus LANE_MARGIN_M from the walls and, abreast, from the other way's lane
    (less the lane's 1 cm tolerance); where it has none, the path comes back unchanged."""
    from swarm.planning import LANE_TOL_M, _sampled, keep_right, narrow_stretches

    walls = _corridor_walls(angle, width, length)
    axis = np.array([math.cos(angle), math.sin(angle), 0.0])
    way = np.array([-(length / 2 + 1.5) * axis, (length / 2 + 1.5) * axis]) + [0.0, 0.0, 1.0]
    ways = [way, way[::-1].copy()]  # along the centre line, each way
    lanes = [keep_right(w, walls, R) for w in ways]
    stretch = narrow_stretches(ways[0], walls, R)
    if not any(p.lanes for p in narrow_stretches(lanes[0], walls, R)):
        for way, lane in zip(ways, lanes, strict=True):
            np.testing.assert_array_equal(lane, way)
        assert not any(p.lanes for p in stretch)
        return
    inner = []
    for lane in lanes:
        P = _sampled(lane, 0.01)[0]
        along = P @ axis
        P = P[np.abs(along) <= length / 2 - 0.2]  # inside the corridor, by its walls
        assert len(P)
        assert walls.clearance(P).min() >= R + LANE_MARGIN_M - LANE_TOL_M - 1e-6
        inner.append(P)
    gap = np.linalg.norm(inner[0][:, None, :] - inner[1][None, :, :], axis=2).min()
    assert gap >= 2 * R + LANE_MARGIN_M - 2 * LANE_TOL_M - 1e-6
