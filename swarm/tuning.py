"""The filter's settings for an agent's situation: its configured ones, with the obstacle
horizon stretched at a low gain on a path planned round walls, and a lane's contact horizon
(docs/design.md, "Reference paths")."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

from swarm.planning import StaticObstacles
from swarm.route import Route, plans_round_walls

if TYPE_CHECKING:
    from swarm.config import AgentConfig
    from swarm.model import CommandLevel, QuadParams
    from swarm.realism.settings import RealismSettings
    from swarm.safety.filter import FilterConfig

NOISE_SIGMAS = 3.0
"""The filter's radii keep this many standard deviations of the motion-capture estimates'
position error (own and neighbour's, independent: ``sqrt(2)`` times one) beyond the margin:
``world.realism.sensing`` (:func:`noise_margin_m`)."""


def noise_margin_m(realism: RealismSettings | None) -> float:
    """The extra radius [m] for the estimates' noise: :data:`NOISE_SIGMAS` x ``sqrt(2)`` x the
    estimator's steady-state position standard deviation when it is read
    (``swarm.realism.sensing.steady_std``; 0 without sensing). Two estimates of independent
    frames are each within it of the truth except with the Gaussian tail's odds."""
    if realism is None or not realism.sensing.enabled:
        return 0.0
    from swarm.realism.sensing import steady_std

    s = realism.sensing
    pos_std, _ = steady_std(s.estimator_params(), s.rate_hz, s.drop_fraction, s.latency_s)
    return NOISE_SIGMAS * math.sqrt(2.0) * pos_std


def max_accel_mps2(params: QuadParams) -> float:
    """The largest acceleration [m/s^2] a drone can have at the attitude level's inputs: full
    thrust (``thrust_to_weight``) at the largest tilt, gravity included."""
    g, ttw, tilt = params.g_mps2, params.thrust_to_weight, params.max_tilt_rad
    return math.hypot(ttw * g * math.sin(tilt), ttw * g * math.cos(tilt) - g)


def prediction_bounds(params: QuadParams, realism: RealismSettings | None) -> tuple[float, float]:
    """(acceleration [m/s^2], velocity error [m/s]) bounds for a neighbour's state extrapolated at
    constant velocity over its age (``swarm.net.neighbours.NeighbourTable``'s radius growth):
    the largest acceleration of an airframe like ``params`` (:func:`max_accel_mps2`), and
    :data:`NOISE_SIGMAS` times the estimator's steady-state velocity deviation with sensing.
    (0, 0) in the ideal world, whose states are exact and one tick old."""
    if realism is None or realism.ideal:
        return 0.0, 0.0
    vel = 0.0
    if realism.sensing.enabled:
        from swarm.realism.sensing import steady_std

        s = realism.sensing
        vel = NOISE_SIGMAS * steady_std(s.estimator_params(), s.rate_hz, s.drop_fraction, s.latency_s)[1]
    return max_accel_mps2(params), vel


def command_lead_s(realism: RealismSettings | None, control_hz: float) -> float:
    """How far ahead [s] an agent's command acts: the ticks its command link takes to reach the
    drone, ``ceil((delay + jitter / 2) / tick)`` ticks (``world.realism.comms.command``, the
    median of its fates, ``swarm.realism.comms``), 0 in the ideal world. The agent filters the
    state it predicts for then, with its neighbours' rows moved and grown to then, so the delay of
    its command is a prediction, not a lag the filter does not know of."""
    if realism is None or realism.ideal:
        return 0.0
    link = realism.comms.command
    tick = 1.0 / control_hz
    return math.ceil((link.delay_s + 0.5 * link.jitter_s) / tick - 1e-9) * tick


HORIZON_SPEED_PER_GAIN_M = 0.4
"""The planner's obstacle horizon ``planner.obstacle_horizon_s`` holds as written for an agent
whose target speed ``u`` [m/s] over its class-K gain ``g`` [1/s] is at most this [m], and is
stretched in proportion beyond it (:func:`obstacle_horizon_s`). Approached at ``u`` from
``|p|``, a pillar's allowance ``s^2 / (2 tau)`` shrinks at up to ``u |p| / tau``, faster than
the gain lets h fall once ``s^2 < 2 u |p| / g``; near a wall many rows then ask at once for more
than the inputs give, by an amount that falls as ``1 / tau`` (the measurements: EXPERIMENTS.md
section 4, "Among walls")."""


def obstacle_horizon_s(agent: AgentConfig, obstacles: StaticObstacles) -> float | None:
    """The time horizon [s] of the agent's obstacle rows' horizon allowance: its
    ``filter.obstacle_horizon_s``, else, when it plans round walls, its
    ``planner.obstacle_horizon_s`` times ``max(1, u / (g`` :data:`HORIZON_SPEED_PER_GAIN_M` ``))``
    for target speed ``u`` [m/s] and gain ``g`` [1/s] (3 s at 0.8 m/s and gamma 2, 6 s at
    gamma 1), else None (the rows then keep ``filter.horizon_s``). On a planned path the path
    takes the agent round the walls; the far pillars' cones along a corridor or a doorway's
    line of sight would otherwise hold its velocity to a slit between them, where the velocity
    buffer asks it to speed up (docs/design.md, "Reference paths")."""
    if agent.filter.obstacle_horizon_s is not None:
        return agent.filter.obstacle_horizon_s
    tau = agent.planner.obstacle_horizon_s
    if tau is None or not plans_round_walls(agent, obstacles):
        return None
    return tau * max(1.0, agent.speed_mps / (HORIZON_SPEED_PER_GAIN_M * agent.filter.gamma))


LANE_CONTACT_S = 0.75
"""The contact horizon [s] (``FilterConfig.contact_s``, at least) of an agent whose path flies a
lane: an agent of the other flow, passing in the next lane, is a few degrees outside its cone
while far; a neighbour more than this from contact relaxes its radius instead of turning it."""


def filter_config_for(
    agent: AgentConfig,
    obstacles: StaticObstacles,
    level: CommandLevel,
    route: Route | None = None,
    realism: RealismSettings | None = None,
) -> FilterConfig:
    """The agent's filter settings at command ``level`` among the static ``obstacles``: its
    configured ones, with :func:`obstacle_horizon_s`; with ``route`` (from :func:`path_for`)
    flying a lane (:func:`swarm.planning.keep_right`), a contact horizon of at least :data:`LANE_CONTACT_S`
    and no velocity buffer: a lane runs a few centimetres beyond the safety radius from a wall
    and from the other flow's lane, on purpose, and the buffer asks every row for about 0.1 m/s
    of velocity margin, which pushes drones off their lanes (docs/design.md, "Reference paths"). With
    ``realism.sensing`` the margin grows by :func:`noise_margin_m`."""
    cfg = replace(agent.filter.filter_config(level), obstacle_horizon_s=obstacle_horizon_s(agent, obstacles))
    noise = noise_margin_m(realism)
    if noise > 0.0:  # world.realism.sensing: the estimates' noise (noise_margin_m)
        cfg = replace(cfg, margin_m=cfg.margin_m + noise)
    if route is not None and route.lanes:
        cfg = replace(cfg, contact_s=max(cfg.contact_s, LANE_CONTACT_S), buffer_mps=0.0)
    return cfg
