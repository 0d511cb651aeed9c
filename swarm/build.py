"""One agent of a scenario, built the same way for every shell: the agent process
(``swarm agent``), the offline loop (``swarm.offline.closed_loop.fly_scenario``), the ROS 2
goals and the benchmarks. The config is read here, once: the planner, the route, the tuning and
the control step get plain values (``swarm.route.PathSpec``, ``swarm.tuning.HorizonSpec``, a
``FilterConfig``, a :class:`swarm.step.Sensing`), never an ``AgentConfig``.

    step = agent_step(cfg, "cf1")                # its control step (swarm.step.AgentStep)
    table = agent_neighbour_table(cfg, "cf1")    # its neighbour table, with the run's limits
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from swarm.config import AgentConfig, FailureSettings, MonitorSettings, ScenarioConfig, TimeMode
from swarm.control import PathTracker
from swarm.model import CommandLevel, QuadModel, QuadParams, rotor_input_set, thrust_vector_input_set
from swarm.net.neighbours import NeighbourTable
from swarm.net.statewire import Plausible
from swarm.planner import planned_path
from swarm.planning import StaticObstacles
from swarm.plugins import CONTROLLERS, filter_class, filter_options, plugin_class, plugin_options
from swarm.realism.sensing import EstimatorParams
from swarm.realism.settings import RealismSettings
from swarm.reference import ContainedController, ControllerSpec, is_builtin
from swarm.rotation import FloatArray
from swarm.route import PathSpec, Route, corner_cut_m, path_for, plans_round_walls
from swarm.safety.external import ContainedFilter, FilterSpec, barrier_of, budget_s
from swarm.safety.filter import FilterConfig
from swarm.step import AgentStep, Sensing
from swarm.tuning import (
    NOISE_SIGMAS,
    HorizonSpec,
    agreed_accel_mps2,
    agreed_speed_mps,
    command_lead_s,
    delay_speed_mps,
    design_std,
    expected_ages,
    filter_config_for,
    monitor_params,
    obstacle_horizon_s,
    prediction_bounds,
)


def agent_step(cfg: ScenarioConfig, agent_id: str, still: StaticObstacles | None = None) -> AgentStep:
    """The control step of agent ``agent_id`` of ``cfg`` (:func:`step_of`), among the static
    obstacles ``still`` (default: the scenario's), in the scenario's world, at its control rate,
    with its monitor and failure settings."""
    still = StaticObstacles.of(list(cfg.obstacles)) if still is None else still
    return step_of(
        cfg.agent(agent_id),
        still,
        cfg.goal_tolerance_m,
        realism=cfg.world.realism,
        control_hz=cfg.time.control_hz,
        monitor=cfg.monitor,
        failure=cfg.failure,
        realtime=cfg.time.mode is TimeMode.REALTIME,
    )


def step_of(
    agent: AgentConfig,
    still: StaticObstacles,
    goal_tolerance_m: float,
    level: CommandLevel | None = None,
    realism: RealismSettings | None = None,
    control_hz: float | None = None,
    monitor: MonitorSettings | None = None,
    failure: FailureSettings | None = None,
    realtime: bool = False,
) -> AgentStep:
    """The step of a configured agent among the static obstacles ``still``: its airframe, its
    path planned round the walls (:func:`path_of`), its filter tuned for that path
    (:func:`filter_of`), at its command level (or ``level``), holding its yaw; with
    ``realism.sensing`` a simulated drone's estimator, starting at its start with its yaw and start
    velocity (a real drone acts on the states the world relays from the real motion capture, whose
    deviations are taken as the design's, ``swarm.tuning.design_std``), and a real drone's
    disturbance observer where it asks for one; with ``control_hz`` its command's lead in that
    world, and where the swarm's delay contract binds there (``swarm.tuning.agreed_accel_mps2``) its
    command within the agreed acceleration, its cruise speed within what its neighbours may not
    yet know of (:func:`cruise_speed_mps`) and its published state the one predicted for when its
    command acts; with ``monitor`` (and the scenario's ``failure`` settings) its safety monitor; its
    safety filter and reference controller plugins contained (:func:`contained_plugin`,
    :func:`contained_controller`; ``realtime``: the run is on the wall clock)."""
    level = agent.command_level if level is None else level
    lead_s = 0.0 if control_hz is None else command_lead_s(realism, control_hz)
    path_w, route = path_of(agent, still)
    observer = None
    if agent.crazyflie is not None and agent.crazyflie.disturbance_estimate:
        observer = real_drone_estimator()
    estimator = None
    if realism is not None and realism.sensing.enabled and agent.backend == "sim":  # (a real drone: real frames)
        half = 0.5 * agent.yaw_rad
        estimator = realism.estimator(
            np.asarray(agent.start, float),
            np.array([0.0, 0.0, math.sin(half), math.cos(half)]),
            v0_w=np.asarray(agent.start_velocity, float),
        )
    fixed_sd = design_std(realism) if estimator is None else (0.0, 0.0)
    offset_sd = realism.sensing.centroid_offset_std_m if realism is not None and realism.sensing.enabled else 0.0
    fc = filter_of(agent, still, level, route, realism, control_hz)
    ahead = lead_s if fc.accel_limit_mps2 is not None else 0.0  # (the swarm's delay contract binds)
    mon = None
    if monitor is not None:
        mon = monitor_params(monitor, realism, failure or FailureSettings(), control_hz, neighbours_ahead_s=ahead)
    return AgentStep(
        QuadModel(agent.quad_params()),
        fc,
        PathTracker(path_w, cruise_speed_mps(agent, realism, control_hz), cut_m=corner_cut_m(route)),
        goal_w=np.asarray(agent.final_goal, dtype=float),
        route=route,
        tiebreak=agent.tiebreak.pair,
        filtered=agent.filter.enabled,
        yaw_rad=agent.yaw_rad,
        goal_tolerance_m=goal_tolerance_m,
        landing=agent.backend == "crazyflie",
        sensing=Sensing(estimator, lead_s, observer, fixed_sd, offset_sd, publish_ahead=ahead > 0.0),
        monitor=mon,
        plugin=contained_plugin(agent, fc, control_hz, realtime),
        controller=contained_controller(agent, control_hz, realtime, cruise_speed_mps(agent, realism, control_hz)),
    )


def real_drone_estimator() -> EstimatorParams:
    """What a real Crazyflie's agent estimates its disturbance with (the acceleration its drone has
    beyond its command: a thrust map off the drone's motors, a sagging battery, a mass off the
    model): the ``crazyflie_lab`` preset's estimator (its sources are cited there) on the states
    the world relays from the real motion capture, taken as measured at the tick's time (latency 0)."""
    lab = RealismSettings.model_validate("crazyflie_lab").sensing.estimator_params()
    return replace(lab, latency_s=0.0)


def path_spec(agent: AgentConfig) -> PathSpec:
    """What the planner takes of ``agent``: its configured path from its start, its safety radius
    (its airframe's body radius plus its filter's margin), its planner's settings (None with
    ``planner.kind: none``) and its stall time."""
    return PathSpec(
        np.asarray(agent.path(), dtype=float),
        agent.airframe.params().body_radius_m + agent.filter.margin_m,
        None if agent.planner.kind == "none" else agent.planner.settings(),
        agent.planner.stall_s,
    )


def path_of(agent: AgentConfig, still: StaticObstacles) -> tuple[FloatArray, Route | None]:
    """The waypoints (k, 3) [m, world] ``agent`` flies from its start among ``still``, and its
    route (``swarm.route.path_for``); a plugin planner's path (``swarm.planner``), flown as it
    is, without a route."""
    custom = planned_path(agent.plan_request(), still)
    if custom is not None:
        return custom, None
    return path_for(path_spec(agent), still)


def obstacle_horizon_of(agent: AgentConfig, still: StaticObstacles) -> float | None:
    """The time horizon [s] of ``agent``'s obstacle rows' horizon allowance among ``still``
    (``swarm.tuning.obstacle_horizon_s``)."""
    spec = HorizonSpec(
        agent.filter.obstacle_horizon_s, agent.planner.obstacle_horizon_s, agent.speed_mps, agent.filter.gamma
    )
    return obstacle_horizon_s(spec, plans_round_walls(path_spec(agent), still))


def filter_of(
    agent: AgentConfig,
    still: StaticObstacles,
    level: CommandLevel,
    route: Route | None = None,
    realism: RealismSettings | None = None,
    control_hz: float | None = None,
) -> FilterConfig:
    """``agent``'s filter settings at command ``level`` among ``still`` on ``route``, in the world
    ``realism`` ticking at ``control_hz`` (``swarm.tuning.filter_config_for``, with its agreed
    acceleration, :func:`agent_accel_mps2`, and speed, ``swarm.tuning.agreed_speed_mps``)."""
    base = agent.filter.filter_config(level)
    a = agent_accel_mps2(agent, realism, control_hz)
    v = agreed_speed_mps(a, realism, control_hz)
    return filter_config_for(base, obstacle_horizon_of(agent, still), route, a, v)


def agent_accel_mps2(agent: AgentConfig, realism: RealismSettings | None, control_hz: float | None) -> float | None:
    """The agreed acceleration (``swarm.tuning.agreed_accel_mps2``) of ``agent``'s airframe and
    filter settings."""
    return agreed_accel_mps2(agent.quad_params(), realism, control_hz, agent.filter.delay_growth_m)


def cruise_speed_mps(agent: AgentConfig, realism: RealismSettings | None, control_hz: float | None) -> float:
    """The speed [m/s] ``agent`` cruises at (``swarm.tuning.delay_speed_mps``): its ``speed_mps``,
    held within what its neighbours may not yet know of where the swarm's delay contract binds
    (an attitude-level agent with an agreed acceleration)."""
    a = agent_accel_mps2(agent, realism, control_hz) if agent.command_level is CommandLevel.ATTITUDE else None
    return delay_speed_mps(agent.speed_mps, a, realism, control_hz)


def swarm_accel_mps2(
    agents: Sequence[AgentConfig], realism: RealismSettings | None, control_hz: float | None
) -> float | None:
    """The acceleration [m/s^2] an agent's neighbour rows may assume of every other agent of
    ``agents``: the largest of their agreed bounds (:func:`agent_accel_mps2`), or None (the
    airframe's) where any one of them keeps none (it flies the rotor level, or has
    ``filter.delay_growth_m`` null)."""
    bounds = [
        agent_accel_mps2(a, realism, control_hz) if a.command_level is CommandLevel.ATTITUDE else None for a in agents
    ]
    return None if not bounds or any(b is None for b in bounds) else max(b for b in bounds if b is not None)


def agent_neighbour_table(cfg: ScenarioConfig, agent_id: str) -> NeighbourTable:
    """The neighbour table of agent ``agent_id`` of ``cfg``: the scenario's failure settings,
    the prediction bounds of its airframe in ``world.realism`` (:func:`neighbour_table`) and the
    run's plausibility limits on what a neighbour's state may say (``swarm.net.statewire.Plausible``)."""
    realism, hz = cfg.world.realism, cfg.time.control_hz
    accel = swarm_accel_mps2(cfg.agents, realism, hz)
    table = neighbour_table(cfg.failure, cfg.agent(agent_id).quad_params(), realism, hz, accel)
    table.limits = Plausible.of(cfg)
    return table


def neighbour_table(
    failure: FailureSettings,
    params: QuadParams,
    realism: RealismSettings | None,
    control_hz: float | None = None,
    accel_mps2: float | None = None,
) -> NeighbourTable:
    """The neighbour table of an agent flying an airframe like ``params`` at ``control_hz``
    [Hz]: its ``failure`` settings, with the timeout counted beyond the rows' expected age
    (``swarm.tuning.expected_ages``: a known delay is predicted through, not a loss); the
    prediction bounds of ``realism`` (``swarm.tuning.prediction_bounds``), the acceleration the
    swarm agreed (``accel_mps2``, :func:`swarm_accel_mps2`) in place of the airframe's where given;
    and with ``realism.sensing`` each row's velocity error ``NOISE_SIGMAS`` times the deviation its
    state carries where that exceeds the bound (:func:`agent_neighbour_table` adds the run's limits)."""
    accel, vel_err = prediction_bounds(params, realism)
    if accel_mps2 is not None:
        accel = min(accel, accel_mps2)
    sigmas = NOISE_SIGMAS if realism is not None and realism.sensing.enabled else 0.0
    f = failure
    timeout = f.neighbour_timeout_s + expected_ages(realism, control_hz).neighbour_s
    return NeighbourTable(timeout, f.neighbour_growth_mps, f.neighbour_hard_limit_s, f.on_lost, accel, vel_err, sigmas)


def contained_plugin(
    agent: AgentConfig, config: FilterConfig, control_hz: float | None, realtime: bool = False
) -> ContainedFilter | None:
    """The agent's safety filter plugin (``filter.kind``, ``swarm.plugins``) built and contained,
    or None when its filter is a built-in barrier (its own QP) or it flies unfiltered. ``config``:
    its tuned C3BF-QP settings (the fallback's), whose level, margin, sensing radius and input set
    the plugin is given; ``control_hz`` (None: 100 Hz) sets its tick. Its budget is
    ``filter.budget_ms``, or without it one tick where the run is on the wall clock (``realtime``, or
    a real drone) and none otherwise (``swarm.safety.external.budget_s``)."""
    cls = filter_class(agent.filter.kind)
    if barrier_of(cls) is not None or not agent.filter.enabled:
        return None
    period_s = 1.0 / (100.0 if control_hz is None else control_hz)
    params = agent.quad_params()
    limits = (
        rotor_input_set(params)
        if config.level is CommandLevel.ROTORS
        else thrust_vector_input_set(params, accel_limit_mps2=config.accel_limit_mps2)
    )
    spec = FilterSpec(
        agent.id, params, config.level, limits, config.margin_m,
        config.sensing_radius_m, period_s, filter_options(cls, dict(agent.filter.options)),
    )  # fmt: skip
    wall = realtime or agent.backend == "crazyflie"
    return ContainedFilter(cls(spec), spec, budget_s=budget_s(agent.filter.budget_ms, period_s, wall))


def contained_controller(
    agent: AgentConfig, control_hz: float | None, realtime: bool = False, speed_mps: float | None = None
) -> ContainedController | None:
    """The agent's reference controller plugin (``controller.kind``, ``swarm.plugins``) built and
    contained, or None for the built-in path tracker. ``control_hz`` (None: 100 Hz) sets its tick;
    its budget is ``controller.budget_ms``, or as a filter plugin's (:func:`contained_plugin`);
    ``speed_mps``: the cruise speed its tracker flies (None: the agent's ``speed_mps``)."""
    cls = plugin_class(CONTROLLERS, agent.controller.kind)
    if is_builtin(cls):
        return None
    period_s = 1.0 / (100.0 if control_hz is None else control_hz)
    params = agent.quad_params()
    spec = ControllerSpec(
        agent.id, params, thrust_vector_input_set(params),
        agent.speed_mps if speed_mps is None else speed_mps, period_s,
        plugin_options(cls, dict(agent.controller.options)),
    )  # fmt: skip
    wall = realtime or agent.backend == "crazyflie"
    return ContainedController(cls(spec), spec, budget_s=budget_s(agent.controller.budget_ms, period_s, wall))
