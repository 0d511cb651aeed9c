"""In-process closed loop: one quadrotor, the reference controller, the safety filter
and RK4 rigid-body physics, with obstacles moving at constant acceleration. No I/O; the
runtime's world process does the same with PyBullet. Used by tests and quick studies."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from swarm.control import (
    AttitudeController,
    OnboardController,
    PathTracker,
    setpoint_from_thrust_vector,
    yaw_of,
)
from swarm.filter import FilterConfig, FilterResult, FilterStatus, SafetyFilter
from swarm.model import CommandLevel, QuadModel, QuadState, step_rk4
from swarm.obstacles import ObstacleArrays
from swarm.rotation import FloatArray, quat_to_R
from swarm.scenario import surface_clearance


def obstacles_at(obs0: ObstacleArrays, t_s: float) -> ObstacleArrays:
    """Obstacles at time ``t_s`` [s] moving with their constant acceleration."""
    if not (obs0.c_dot_w.any() or obs0.c_ddot_w.any()):
        return obs0
    return ObstacleArrays(
        obs0.c_w + obs0.c_dot_w * t_s + 0.5 * obs0.c_ddot_w * t_s**2,
        obs0.c_dot_w + obs0.c_ddot_w * t_s,
        obs0.c_ddot_w, obs0.radius_m, obs0.axis_w, obs0.is_neighbour,
    )  # fmt: skip


@dataclass
class ClosedLoopLog:
    t_s: list[float] = field(default_factory=list)
    x_w: list[FloatArray] = field(default_factory=list)  # (3,) m: centre of mass
    x_b_w: list[FloatArray] = field(default_factory=list)  # (3,) m: body centre x + l R e3
    v_w: list[FloatArray] = field(default_factory=list)
    clearance_m: list[FloatArray] = field(default_factory=list)  # surface distance per obstacle
    results: list[FilterResult] = field(default_factory=list)

    def array(self, name: str) -> FloatArray:
        return np.array(getattr(self, name))

    @property
    def min_clearance_m(self) -> float:
        return float(np.min(self.clearance_m)) if self.clearance_m else float("inf")

    @property
    def infeasible_ticks(self) -> int:
        return sum(r.status is not FilterStatus.OK for r in self.results)


def simulate(
    model: QuadModel,
    config: FilterConfig,
    tracker: PathTracker,
    obstacles: ObstacleArrays,
    state0: QuadState,
    duration_s: float,
    *,
    control_hz: float = 100.0,
    physics_hz: float = 500.0,
    filter_on: bool = True,
) -> ClosedLoopLog:
    """Fly ``duration_s`` seconds; the command is held between control ticks."""
    filt = SafetyFilter(model, config)
    att = AttitudeController(model)
    onboard = OnboardController(model, yaw_of(state0))
    n_sub = max(1, round(physics_hz / control_hz))
    dt = 1.0 / (control_hz * n_sub)
    state = state0.copy()
    log = ClosedLoopLog()
    l_m = model.params.l_m
    for k in range(round(duration_s * control_hz)):
        t = k / control_hz
        obs = obstacles_at(obstacles, t)
        F_ref = tracker.thrust_vector(model, state.x_w, state.v_w)
        if config.level is CommandLevel.ROTORS:
            u_ref = att.from_thrust_vector(state, F_ref)
        else:
            u_ref = F_ref
        res = filt.filter(state, u_ref, obs) if filter_on else None
        u = res.u if res is not None else u_ref
        x_b = state.x_w + l_m * quat_to_R(state.q)[:, 2]
        log.t_s.append(t)
        log.x_w.append(state.x_w.copy())
        log.x_b_w.append(x_b)
        log.v_w.append(state.v_w.copy())
        log.clearance_m.append(surface_clearance(x_b[None, :], obs)[0])
        if res is not None:
            log.results.append(res)
        sp = setpoint_from_thrust_vector(u, yaw_of(state)) if config.level is CommandLevel.ATTITUDE else None
        for _ in range(n_sub):
            f = onboard.rotor_thrusts(state, sp, dt) if sp is not None else u
            state = step_rk4(model, state, f, dt)
    return log
