"""Closed loop in process: RK4 rigid body, reference controller, safety filter."""

import numpy as np
import pytest

from swarm.control import PathTracker
from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.offline.closed_loop import simulate
from swarm.safety.barriers import BarrierKind
from swarm.safety.filter import FilterConfig
from swarm.safety.obstacles import ObstacleArrays

MODEL = QuadModel()
BODY = MODEL.params.body_radius_m
MARGIN = FilterConfig().margin_m  # the filter keeps the body centre this much beyond the airframe's radius
# RK4 at the control rate with the command held over each tick: measured within 0.02 mm of BODY + MARGIN
CLEAR_TOL = 1e-3


def fly(level, obstacles, duration=10.0, start=(0, 0, 1.0), goal=(5, 0, 1.0), filter_on=True, **cfg):
    s0 = QuadState.hover(start)
    s0.v_w = np.array([1.0, 0, 0])  # already cruising at 1 m/s toward the goal
    return simulate(
        MODEL,
        FilterConfig(level=level, **cfg),
        PathTracker([start, goal], 1.0),
        obstacles,
        s0,
        duration,
        filter_on=filter_on,
    )


@pytest.mark.parametrize("level", list(CommandLevel))
def test_without_the_filter_the_drone_hits_the_sphere(level):
    log = fly(level, ObstacleArrays.build([2.5, 0.0, 1.0], [0.3]), duration=5.0, filter_on=False)
    assert log.min_clearance_m < 0


@pytest.mark.parametrize("level", list(CommandLevel))
@pytest.mark.parametrize("offset", [0.0, 0.1])
def test_static_sphere_is_never_entered_and_the_goal_is_reached(level, offset):
    log = fly(level, ObstacleArrays.build([2.5, offset, 1.0], [0.3]), duration=12.0)
    assert log.min_clearance_m >= BODY + MARGIN - CLEAR_TOL  # the airframe and its margin stay clear
    assert np.linalg.norm(log.x_w[-1] - np.array([5, 0, 1.0])) < 0.1


@pytest.mark.parametrize("level", list(CommandLevel))
def test_head_on_moving_sphere_is_avoided(level):
    obs = ObstacleArrays.build([4.0, 0.05, 1.0], [0.25], [-1.0, 0.0, 0.0])
    log = fly(level, obs, duration=6.0, goal=(8, 0, 1.0))
    assert log.min_clearance_m >= BODY + MARGIN - CLEAR_TOL


@pytest.mark.parametrize("level", list(CommandLevel))
def test_cylinder_across_the_path_is_avoided(level):
    # a long bar across the path (axis y), 1.0 m up: passed over or under, never hit
    obs = ObstacleArrays.build([2.5, 0.0, 1.05], [0.15], axis_w=[0.0, 1.0, 0.0])
    log = fly(level, obs, duration=10.0)
    assert log.min_clearance_m >= BODY + MARGIN - CLEAR_TOL
    assert log.x_w[-1][0] > 4.0  # it got past the bar


def test_c3bf_slows_and_climbs_over_a_wall_like_sphere_dead_ahead():
    """Dead ahead, 2 m across, at 1 m/s: the drone slows (to 0.59 m/s; 0.40 with the
    velocity loop at kd 3) and climbs over it, never inside the safety radius."""
    obs = ObstacleArrays.build([2.5, 0.0, 1.0], [1.0])
    log = fly(CommandLevel.ATTITUDE, obs, duration=4.0)
    v = log.array("v_w")
    assert log.min_clearance_m >= BODY + MARGIN - CLEAR_TOL
    assert v[:, 0].min() < 0.7  # slowed down from 1 m/s
    assert log.array("x_w")[:, 2].max() > 1.9  # over the top (2 m up) with its safety radius


@pytest.mark.parametrize("level", list(CommandLevel))
def test_hocbf_baseline_also_runs_closed_loop(level):
    log = fly(level, ObstacleArrays.build([2.5, 0.1, 1.0], [0.3]), duration=8.0, kind=BarrierKind.HOCBF)
    assert np.isfinite(log.array("x_w")).all()
    assert np.linalg.norm(log.x_w[-1] - np.array([5, 0, 1.0])) < 0.1  # it got past the sphere
    if level is CommandLevel.ROTORS:  # its own model: the margin holds (measured 0.5 mm short of it)
        assert log.min_clearance_m >= BODY + MARGIN - CLEAR_TOL
    else:  # on the thrust-vector model it ignores the attitude's lag: 4 cm into the margin (measured 0.049 m)
        assert 0.03 < log.min_clearance_m < BODY + MARGIN - 0.02


@pytest.mark.parametrize("level", list(CommandLevel))
def test_the_floor_holds_the_drone_above_it(level):
    """A path that dives into the ground: the floor row stops the descent at floor_z_m."""
    floor = 0.3
    log = fly(level, ObstacleArrays.empty(), duration=6.0, goal=(3, 0, -0.5), floor_z_m=floor)
    z = log.array("x_w")[:, 2]
    assert z.min() >= floor - 0.02  # the HO-CBF holds to within the discretisation
    assert z[-1] < floor + 0.05  # and it does not hover needlessly high: it went down to the floor
    assert all(r.max_violation < 1e-6 for r in log.results if r.status.value == "ok")
    free = fly(level, ObstacleArrays.empty(), duration=6.0, goal=(3, 0, -0.5))
    assert free.array("x_w")[:, 2].min() < 0.0  # without the floor it would have gone through
