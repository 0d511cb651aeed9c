"""The filter's settings for an agent's situation: its configured ones, with the obstacle
horizon stretched at a low gain on a path planned round walls, and a lane's contact horizon
(docs/design.md, "Reference paths")."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from swarm.model import CommandLevel
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


def design_std(realism: RealismSettings | None, ahead_s: float = 0.0) -> tuple[float, float]:
    """The estimator's steady-state standard deviations of position [m] and velocity [m/s] when
    it is read (``swarm.realism.sensing.steady_std``, the largest axis, and in quadrature the
    markers' constant offset ``centroid_offset_std_m``; (0, 0) without sensing): what an agent
    without an estimator of its own (a real drone on the world's frames) says its state's
    deviations are, and the envelope the safety monitor holds the live ones to
    (``swarm.safety.monitor``). ``ahead_s`` [s]: of the estimate predicted this much further
    (a state published for when its command acts)."""
    if realism is None or not realism.sensing.enabled:
        return 0.0, 0.0
    from swarm.realism.sensing import steady_std

    s = realism.sensing
    pos, vel = steady_std(s.estimator_params(), s.rate_hz, s.drop_fraction, s.latency_s + ahead_s)
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


MIN_AGREED_ACCEL_MPS2 = 1.0
"""The smallest agreed acceleration [m/s^2] (:func:`agreed_accel_mps2`): what a drone at its
cruise speed of about 1 m/s needs to brake within half a metre."""


def agreed_accel_mps2(
    params: QuadParams, realism: RealismSettings | None, control_hz: float | None, growth_m: float | None
) -> float | None:
    """The acceleration [m/s^2] every agent of a swarm keeps its command within, so that a
    neighbour's state extrapolated at constant velocity over the loop's expected age ``A``
    (:func:`expected_ages`) is off by at most ``growth_m`` [m]: ``2 growth_m / A^2``, at least
    :data:`MIN_AGREED_ACCEL_MPS2`; None (the airframe's whole acceleration,
    :func:`max_accel_mps2`) where that is no tighter, in the ideal world, or with ``growth_m``
    None. A neighbour's row grows by ``a A^2 / 2`` over its age (``NeighbourTable``); with the
    airframe's ``a`` (about 15 m/s^2 for a Crazyflie) and the 0.3-0.5 s a loop of 100-150 ms
    links reaches, that is 0.7-1.9 m, and every row of a converging swarm holds its agent."""
    if growth_m is None or realism is None or realism.ideal:
        return None
    age = expected_ages(realism, control_hz).neighbour_s
    a_max = max_accel_mps2(params)
    if age <= 0.0:
        return None
    a = max(MIN_AGREED_ACCEL_MPS2, 2.0 * growth_m / (age * age))
    return a if a < a_max else None


def delay_speed_mps(
    speed_mps: float, accel_mps2: float | None, realism: RealismSettings | None, control_hz: float | None
) -> float:
    """The speed [m/s] an agent of target speed ``speed_mps`` cruises at: that, and where the
    swarm's delay contract binds (its agreed acceleration ``accel_mps2``, :func:`agreed_accel_mps2`;
    None: it does not) at most ``a A``, the velocity a neighbour can gain at the agreed acceleration
    ``a`` over its row's expected age ``A`` (:func:`expected_ages`): no faster than what its
    neighbours may not yet know of, so a neighbour's velocity error is no larger than the agent's
    own speed (``2 delay_growth_m / A``; docs/design.md, "Delay")."""
    limit = agreed_speed_mps(accel_mps2, realism, control_hz)
    return speed_mps if limit is None else min(speed_mps, limit)


def agreed_speed_mps(
    accel_mps2: float | None, realism: RealismSettings | None, control_hz: float | None
) -> float | None:
    """The speed [m/s] every agent keeps within where the swarm's delay contract binds (its
    agreed acceleration ``accel_mps2``; None: it does not, and no limit): ``a A``, what a
    neighbour can gain at the agreed acceleration over its row's expected age ``A``
    (:func:`expected_ages`), kept by the filter's speed row (``FilterConfig.speed_limit_mps``)
    and by the cruise speed (:func:`delay_speed_mps`)."""
    if accel_mps2 is None:
        return None
    return accel_mps2 * expected_ages(realism, control_hz).neighbour_s


class ExpectedAges(NamedTuple):
    """The ages [s] a loop's own delays give its readings, with nothing lost or late beyond
    them (:func:`expected_ages`)."""

    own_s: float  # the own estimate's age where the filter reads it (at the tick plus the lead)
    neighbour_s: float  # a neighbour's row's age there (one tick, and its state's and bundle's links)


def expected_ages(realism: RealismSettings | None, control_hz: float | None) -> ExpectedAges:
    """The ages the configured delays of ``realism`` give an agent ticking at ``control_hz``
    [Hz] (None: no lead) whose filter reads its state at the tick plus the command's lead
    (:func:`command_lead_s`): its own estimate is ``latency_s + lead`` old (the motion
    capture's stamps, which the estimator reads, carry the rest); a neighbour's row is one tick
    (the state of the tick before), the state link and the relay's bundle link (each at its
    delay plus its jitter) and the lead old. (0, 0) in the ideal world. The safety monitor
    bounds what is late or missing BEYOND these (:func:`monitor_params`): a known delay is
    predicted through (the estimator, the neighbour table's growth), not a breach."""
    if realism is None or realism.ideal:
        return ExpectedAges(0.0, 0.0)
    lead = 0.0 if control_hz is None else command_lead_s(realism, control_hz)
    own = (realism.sensing.latency_s if realism.sensing.enabled else 0.0) + lead
    comms = realism.comms.params()
    links = sum(link.delay_s + link.jitter_s for link in (comms.state, comms.bundle))
    tick = 0.0 if control_hz is None else 1.0 / control_hz
    return ExpectedAges(own, tick + links + lead)


def monitor_params(
    settings: MonitorSettings,
    realism: RealismSettings | None,
    failure: FailureSettings,
    control_hz: float | None = None,
    neighbours_ahead_s: float = 0.0,
) -> MonitorParams:
    """The safety monitor's parameters (``swarm.safety.monitor.MonitorParams``) from the
    scenario's ``monitor`` settings: the deviation envelope, ``std_envelope_factor`` times the
    steady-state deviation the noise margin was designed for (:func:`design_std`, with sensing;
    none without) unless set, the neighbours' age bound
    ``failure.neighbour_timeout_s`` unless set. The age bounds are beyond the ages the
    configured delays give (:func:`expected_ages`, with ``control_hz`` the agent's rate).
    Neighbours that publish their states predicted ``neighbours_ahead_s`` [s] ahead (the delay
    contract: ``swarm.step.AgentStep``'s ``publish_ahead``) are held to the envelope of that
    prediction's deviation, and their rows' expected age is that much shorter."""
    ages = expected_ages(realism, control_hz)
    nb_age_s = max(0.0, ages.neighbour_s - neighbours_ahead_s)
    envelope = settings.std_envelope_m
    nb_envelope = None
    if envelope is None:
        sd = design_std(realism)[0]
        envelope = settings.std_envelope_factor * sd if sd > 0.0 else math.inf
        if neighbours_ahead_s > 0.0 and sd > 0.0:
            nb_envelope = settings.std_envelope_factor * design_std(realism, neighbours_ahead_s)[0]
    grades = tuple(
        (Breach[name.upper()], Action[action.upper()]) for name, action in settings.grades.model_dump().items()
    )
    return MonitorParams(
        enabled=settings.enabled,
        std_envelope_m=envelope,
        neighbour_std_envelope_m=nb_envelope,
        estimate_age_s=settings.estimate_age_s + ages.own_s,
        estimate_lost_s=settings.estimate_lost_s + ages.own_s,
        neighbour_age_s=(settings.neighbour_age_s or failure.neighbour_timeout_s) + nb_age_s,
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


def filter_config_for(
    base: FilterConfig,
    obstacle_horizon: float | None,
    route: Route | None = None,
    accel_limit_mps2: float | None = None,
    speed_limit_mps: float | None = None,
) -> FilterConfig:
    """The agent's filter settings: its configured ones ``base`` (at its command level), with its
    obstacle horizon ``obstacle_horizon`` [s] (:func:`obstacle_horizon_s`); with ``route`` (from
    ``swarm.route.path_for``) flying a lane (:func:`swarm.planning.keep_right`), a contact horizon
    of at least :data:`LANE_CONTACT_S` and no velocity buffer: a lane runs a few centimetres beyond
    the safety radius from a wall and from the other flow's lane, on purpose, and the buffer asks
    every row for about 0.1 m/s of velocity margin, which pushes drones off their lanes
    (docs/design.md, "Reference paths"). The estimates' noise is not in the margin: each row grows
    by it live (:func:`live_margin_m`, ``swarm.step``). At the attitude level its command keeps
    within ``accel_limit_mps2`` [m/s^2], the swarm's agreed acceleration in a world with delays
    (:func:`agreed_accel_mps2`, ``filter.delay_growth_m``; None: the airframe's) and its speed
    within ``speed_limit_mps`` [m/s] (:func:`agreed_speed_mps`; None: no limit)."""
    cfg = replace(base, obstacle_horizon_s=obstacle_horizon)
    if cfg.level is CommandLevel.ATTITUDE:
        cfg = replace(cfg, accel_limit_mps2=accel_limit_mps2, speed_limit_mps=speed_limit_mps)
    if route is not None and route.lanes:
        cfg = replace(cfg, contact_s=max(cfg.contact_s, LANE_CONTACT_S), buffer_mps=0.0)
    return cfg
