"""h' = Lf h + Lg h u, checked against a central difference of h along simulated motion
of the agent and of the obstacle (static, constant velocity and accelerating obstacles;
spheres, cylinders and other drones' keep-out ellipsoids; both command levels). Dropping the
obstacle's velocity term or the body-centre offset makes this fail."""

import zlib

import numpy as np
import pytest

from swarm.model import CommandLevel, QuadModel, QuadState, step_rk4, thrust_vector_accel
from swarm.offline.closed_loop import obstacles_at
from swarm.safety.barriers import BarrierKind
from swarm.safety.filter import FilterConfig, SafetyFilter
from swarm.safety.obstacles import ObstacleArrays

from .helpers import random_state

MOTIONS = {
    "static": (np.zeros(3), np.zeros(3)),
    "moving": (np.array([-1.0, 0.4, 0.2]), np.zeros(3)),
    "accelerating": (np.array([-1.0, 0.4, 0.2]), np.array([0.5, -2.0, 1.0])),
}


def _advance(level, model, state, u, dt):
    if level is CommandLevel.ROTORS:
        return step_rk4(model, state, u, dt)
    a = thrust_vector_accel(model.params, u)
    return QuadState(state.x_w + state.v_w * dt + 0.5 * a * dt * dt, state.v_w + a * dt, state.q, state.Omega_b)


def _richardson(h_of_t, d=2e-5):
    """dh/dt at 0 from central differences at d and 2d (error O(d^4); at d = 1e-4 a
    drone spinning at 3 rad/s near the cone boundary left about 2e-6 of truncation)."""
    c1 = (h_of_t(d) - h_of_t(-d)) / (2 * d)
    c2 = (h_of_t(2 * d) - h_of_t(-2 * d)) / (4 * d)
    return (4 * c1 - c2) / 3


@pytest.mark.parametrize("level", list(CommandLevel))
@pytest.mark.parametrize("kind", list(BarrierKind))
@pytest.mark.parametrize("shape", ["sphere", "cylinder", "drone"])
@pytest.mark.parametrize("motion", list(MOTIONS))
def test_hdot_matches_finite_difference_along_motion(level, kind, shape, motion):
    """A drone (a neighbour, moving with the obstacle's motion) keeps the keep-out ellipsoid:
    its row is taken in the frame that makes it a ball, its gradients mapped back."""
    rng = np.random.default_rng(zlib.crc32(f"{level}{kind}{shape}{motion}".encode()))  # stable across runs
    model = QuadModel()
    filt = SafetyFilter(model, FilterConfig(level=level, kind=kind, gamma_ho=0.8))
    checked = 0
    for _ in range(40):
        state = random_state(rng)
        c_dot, c_ddot = MOTIONS[motion]
        axis = rng.normal(size=3) if shape == "cylinder" else None
        c = state.x_w + rng.uniform(-2.5, 2.5, 3)
        radius = [0.2 if shape != "drone" else 0.07]
        obs = ObstacleArrays.build(c, radius, c_dot, c_ddot, axis, is_neighbour=[shape == "drone"])
        rows = filt.rows(state, obs)
        if rows.inside.any():
            continue
        u = (
            rng.uniform(0, model.params.f_max_N, 4)
            if level is CommandLevel.ROTORS
            else np.array([*rng.uniform(-0.1, 0.1, 2), rng.uniform(0.1, 0.5)])
        )
        predicted = rows.Lf_h[0] + rows.Lg_h[0] @ u
        fd = _richardson(
            lambda t, s=state, u=u, o=obs: filt.rows(_advance(level, model, s, u, t), obstacles_at(o, t)).h[0]
        )
        assert abs(predicted - fd) <= 1e-6 * max(1.0, abs(predicted)), (predicted, fd)
        if shape == "drone":
            assert rows.barrier.sz is not None and rows.barrier.sz[0] < 1.0  # the ellipsoid's frame
        checked += 1
    assert checked >= 20


def test_dropping_the_obstacle_velocity_would_be_caught():
    """The same check, with the obstacle velocity left out of the rows, must fail."""
    model = QuadModel()
    filt = SafetyFilter(model, FilterConfig(level=CommandLevel.ATTITUDE))
    state = QuadState.hover()
    state.v_w = np.array([0.3, 0.2, 0.0])
    obs = ObstacleArrays.build([2.0, 0.6, 1.0], [0.2], [-1.0, 0.3, 0.0])
    frozen = ObstacleArrays.build([2.0, 0.6, 1.0], [0.2])
    u = np.array([0.0, 0.0, model.params.weight_N])
    r = filt.rows(state, frozen)
    wrong = r.Lf_h[0] + r.Lg_h[0] @ u
    fd = _richardson(
        lambda t: filt.rows(_advance(CommandLevel.ATTITUDE, model, state, u, t), obstacles_at(obs, t)).h[0]
    )
    right = filt.rows(state, obs)
    assert abs(right.Lf_h[0] + right.Lg_h[0] @ u - fd) < 1e-6
    assert abs(wrong - fd) > 1e-2
