"""The filter's settings for an agent's situation: its configured ones, with the obstacle
horizon stretched at a low gain on a path planned round walls, and a lane's contact horizon
(docs/design.md, "Reference paths")."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from swarm.rotation import FloatArray
from swarm.route import Route
from swarm.safety.monitor import Action, Breach, MonitorParams

if TYPE_CHECKING:
    from swarm.config import FailureSettings, MonitorSettings
    from swarm.model import QuadParams
    from swarm.realism.settings import RealismSettings
    from swarm.safety.filter import FilterConfig

NOISE_SIGMAS = 3.0
"""The filter's radii keep this many standard deviations of the motion-capture estimates'
position error (own and neighbour's, independent: ``sqrt(2)`` times one) beyond the margin:
``world.realism.sensing`` (:func:`noise_margin_m`)."""


def design_std(realism: RealismSettings | None) -> tuple[float, float]:
    """The estimator's steady-state standard deviations of position [m] and velocity [m/s] when
    it is read (``swarm.realism.sensing.steady_std``, the largest axis, and in quadrature the
    markers' constant offset ``centroid_offset_std_m``; (0, 0) without sensing): what an agent
    without an estimator of its own (a real drone on the world's frames) says its state's
    deviations are, and the envelope the safety monitor holds the live ones to
    (``swarm.safety.monitor``)."""
    if realism is None or not realism.sensing.enabled:
        return 0.0, 0.0
    from swarm.realism.sensing import steady_std

    s = realism.sensing
    pos, vel = steady_std(s.estimator_params(), s.rate_hz, s.drop_fraction, s.latency_s)
    if s.centroid_offset_std_m > 0.0:  # the markers' offset from the centre of mass, which no estimate sees
        pos = math.hypot(pos, s.centroid_offset_std_m)
    return pos, vel


def noise_margin_m(realism: RealismSettings | None) -> float:
    """The steady-state noise margin [m]: :data:`NOISE_SIGMAS` x ``sqrt(2)`` x the
    estimator's steady-state position deviation (:func:`design_std`; 0 without sensing). Two
    estimates of independent frames are each within it of the truth except with the Gaussian
    tail's odds. The filter keeps the live form of it (:func:`live_margin_m`); this is the
    figure the margin is designed for, against which the monitor and the metrics compare."""
    return NOISE_SIGMAS * math.sqrt(2.0) * design_std(realism)[0]


def live_margin_m(own_sd_m: float, row_sd_m: FloatArray) -> FloatArray:
    """The extra radius [m] of each row for the estimates' noise now: :data:`NOISE_SIGMAS` x the
    root sum of squares of the agent's own position deviation ``own_sd_m`` [m] and the one its
    row's state carries ``row_sd_m`` (n,) [m] (0 for a fixed obstacle). Own and neighbour's
    estimates are of independent frames, so the pair's relative error has that deviation; it
    grows through a motion-capture gap of either and shrinks when frames return."""
    return NOISE_SIGMAS * np.sqrt(own_sd_m * own_sd_m + row_sd_m * row_sd_m)


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


def monitor_params(
    settings: MonitorSettings, realism: RealismSettings | None, failure: FailureSettings
) -> MonitorParams:
    """The safety monitor's parameters (``swarm.safety.monitor.MonitorParams``) from the
    scenario's ``monitor`` settings: the deviation envelope, ``std_envelope_factor`` times the
    steady-state deviation the noise margin was designed for (:func:`design_std`, with sensing;
    none without) unless set, the neighbours' age bound
    ``failure.neighbour_timeout_s`` unless set."""
    envelope = settings.std_envelope_m
    if envelope is None:
        sd = design_std(realism)[0]
        envelope = settings.std_envelope_factor * sd if sd > 0.0 else math.inf
    grades = tuple(
        (Breach[name.upper()], Action[action.upper()]) for name, action in settings.grades.model_dump().items()
    )
    return MonitorParams(
        enabled=settings.enabled,
        std_envelope_m=envelope,
        estimate_age_s=settings.estimate_age_s,
        estimate_lost_s=settings.estimate_lost_s,
        neighbour_age_s=settings.neighbour_age_s or failure.neighbour_timeout_s,
        infeasible_s=settings.infeasible_s,
        disturbance_s=settings.disturbance_s,
        world_late_s=settings.world_late_s,
        slow_fraction=settings.slow_fraction,
        land_speed_mps=settings.land_speed_mps,
        settle_s=settings.settle_s,
        grades=grades,
    )


def command_lead_s(realism: RealismSettings | None, control_hz: float) -> float:
    """How far ahead [s] an agent's command acts: the ticks its command link takes to reach the
    drone, ``ceil((delay + jitter / 2) / tick)`` ticks (``world.realism.comms.command``, the
    median of its fates, ``swarm.realism.comms``), 0 in the ideal world. The agent filters the
    state it predicts for then, with its neighbours' rows moved and grown to then, so the delay of
    its command is a prediction, not a lag the filter does not know of."""
    if realism is None or realism.ideal:
        return 0.0
    tick = 1.0 / control_hz
    comms = realism.comms.params()
    link = comms.shared_radio.command_link(comms.command, tick)  # (with the radio's other drones' share)
    return math.ceil((link.delay_s + 0.5 * link.jitter_s) / tick - 1e-9) * tick


HORIZON_SPEED_PER_GAIN_M = 0.4
"""The planner's obstacle horizon ``planner.obstacle_horizon_s`` holds as written for an agent
whose target speed ``u`` [m/s] over its class-K gain ``g`` [1/s] is at most this [m], and is
stretched in proportion beyond it (:func:`obstacle_horizon_s`). Approached at ``u`` from
``|p|``, a pillar's allowance ``s^2 / (2 tau)`` shrinks at up to ``u |p| / tau``, faster than
the gain lets h fall once ``s^2 < 2 u |p| / g``; near a wall many rows then ask at once for more
than the inputs give, by an amount that falls as ``1 / tau`` (the measurements: EXPERIMENTS.md
section 4, "Among walls")."""


class HorizonSpec(NamedTuple):
    """What :func:`obstacle_horizon_s` takes of an agent, as plain values
    (``swarm.build.horizon_spec`` reads them off its config)."""

    filter_s: float | None  # s: its filter's own obstacle horizon (filter.obstacle_horizon_s), or None
    planner_s: float | None  # s: its planner's (planner.obstacle_horizon_s), or None
    speed_mps: float  # m/s: its target speed
    gamma: float  # 1/s: its filter's class-K gain


def obstacle_horizon_s(spec: HorizonSpec, plans_round_walls: bool) -> float | None:
    """The time horizon [s] of the agent's obstacle rows' horizon allowance: its filter's
    (``spec.filter_s``), else, when it ``plans_round_walls`` (``swarm.route.plans_round_walls``),
    its planner's times ``max(1, u / (g`` :data:`HORIZON_SPEED_PER_GAIN_M` ``))`` for target speed
    ``u`` [m/s] and gain ``g`` [1/s] (3 s at 0.8 m/s and gamma 2, 6 s at gamma 1), else None (the
    rows then keep ``filter.horizon_s``). On a planned path the path takes the agent round the
    walls; the far pillars' cones along a corridor or a doorway's line of sight would otherwise
    hold its velocity to a slit between them, where the velocity buffer asks it to speed up
    (docs/design.md, "Reference paths")."""
    if spec.filter_s is not None:
        return spec.filter_s
    if spec.planner_s is None or not plans_round_walls:
        return None
    return spec.planner_s * max(1.0, spec.speed_mps / (HORIZON_SPEED_PER_GAIN_M * spec.gamma))


LANE_CONTACT_S = 0.75
"""The contact horizon [s] (``FilterConfig.contact_s``, at least) of an agent whose path flies a
lane: an agent of the other flow, passing in the next lane, is a few degrees outside its cone
while far; a neighbour more than this from contact relaxes its radius instead of turning it."""


def filter_config_for(base: FilterConfig, obstacle_horizon: float | None, route: Route | None = None) -> FilterConfig:
    """The agent's filter settings: its configured ones ``base`` (at its command level), with its
    obstacle horizon ``obstacle_horizon`` [s] (:func:`obstacle_horizon_s`); with ``route`` (from
    ``swarm.route.path_for``) flying a lane (:func:`swarm.planning.keep_right`), a contact horizon
    of at least :data:`LANE_CONTACT_S` and no velocity buffer: a lane runs a few centimetres beyond
    the safety radius from a wall and from the other flow's lane, on purpose, and the buffer asks
    every row for about 0.1 m/s of velocity margin, which pushes drones off their lanes
    (docs/design.md, "Reference paths"). The estimates' noise is not in the margin: each row grows
    by it live (:func:`live_margin_m`, ``swarm.step``)."""
    cfg = replace(base, obstacle_horizon_s=obstacle_horizon)
    if route is not None and route.lanes:
        cfg = replace(cfg, contact_s=max(cfg.contact_s, LANE_CONTACT_S), buffer_mps=0.0)
    return cfg
