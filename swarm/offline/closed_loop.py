"""In-process closed loop: one quadrotor, the reference controller, the safety filter
and RK4 rigid-body physics, with obstacles moving at constant acceleration. No I/O; the
runtime's world process does the same with PyBullet. Used by tests and quick studies."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from swarm.config import ScenarioConfig
from swarm.control import (
    AttitudeController,
    OnboardController,
    PathTracker,
    reference_thrust,
    setpoint_from_thrust_vector,
    yaw_of,
)
from swarm.errors import InputError
from swarm.model import CommandLevel, QuadModel, QuadState, step_rk4
from swarm.offline.scenario import items_to_arrays, min_pair_distance, obstacle_items, surface_clearance
from swarm.planning import Route, StaticObstacles, corner_cut_m, filter_config_for, follows, path_for
from swarm.rotation import FloatArray, quat_to_R
from swarm.safety.filter import FilterConfig, FilterResult, FilterStatus, SafetyFilter
from swarm.safety.obstacles import ObstacleArrays


def obstacles_at(obs0: ObstacleArrays, t_s: float) -> ObstacleArrays:
    """Obstacles at time ``t_s`` [s] moving with their constant acceleration."""
    return obs0.at(t_s)


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


@dataclass
class SwarmAgent:
    """One agent of :func:`simulate_swarm`: where it starts, its path and its filter."""

    start_w: FloatArray  # (3,) m, world: centre of mass at rest
    path_w: FloatArray  # (k, 3) m, world: waypoints after the start (the last is the goal)
    speed_mps: float = 0.8
    config: FilterConfig = field(default_factory=FilterConfig)
    start_velocity_w: FloatArray | None = None  # (3,) m/s, world (default: at rest)
    tiebreak: tuple[float, float] | None = None  # right-hand tie-break (trigger [m], speed [m/s]), or None
    filtered: bool = True  # False: flies its reference unfiltered (and so takes no share of any pair)
    route: Route | None = None  # replans path_w when the agent stalls (swarm.planning), or None

    @property
    def goal_w(self) -> FloatArray:
        return self.path_w[-1]


@dataclass
class SwarmLog:
    """What :func:`simulate_swarm` measured. Distances between body centres."""

    t_s: FloatArray  # (T,) s
    x_b_w: FloatArray  # (T, N, 3) m, world: body centres
    v_w: FloatArray  # (T, N, 3) m/s, world: centre-of-mass velocities
    status: list[list[FilterStatus]]  # (T, N)
    min_separation_m: float  # closest pair of body centres over the run
    min_clearance_m: float  # closest body centre to an obstacle surface (inf: no obstacles)
    time_to_goal_s: list[float | None]  # per agent: first time within the tolerance of the goal
    x_w: FloatArray | None = None  # (T, N, 3) m, world: centres of mass, at the tick (None: not logged)
    v_b_w: FloatArray | None = None  # (T, N, 3) m/s, world: body-centre velocities, at the tick

    @property
    def infeasible_ticks(self) -> int:
        """Agent ticks whose filter call was not a clean solve (every status but OK: slack,
        escape rows, a failed solve), as the agents and ``swarm.offline.metrics`` count them."""
        return sum(s is not FilterStatus.OK for row in self.status for s in row)

    @property
    def all_reached(self) -> bool:
        return all(t is not None for t in self.time_to_goal_s)


def _body_rows(states: list[QuadState], l_m: float) -> tuple[FloatArray, FloatArray]:
    from swarm.model import body_centre

    xb = np.empty((len(states), 3))
    vb = np.empty((len(states), 3))
    for i, s in enumerate(states):
        xb[i], vb[i], _ = body_centre(s.x_w, s.v_w, s.q, s.Omega_b, l_m)
    return xb, vb


def _gives_way(
    agent: SwarmAgent,
    trackers: list[PathTracker],
    i: int,
    t_s: float,
    state: QuadState,
    goal_w: FloatArray,
    others_x_w: FloatArray,
    others_v_w: FloatArray,
) -> FloatArray | None:
    """The agent's route at this tick, as the agent process runs it: a new path if it has
    stalled (``trackers[i]`` replaced), then the velocity it holds in place of its path
    to give way at a narrow passage (swarm.planning.Route.hold) or to brake before it turns
    away from a wall (Route.turns), or None."""
    route = agent.route
    if route is None:
        return None
    remaining = trackers[i].reference(state.x_w)[2]
    new = route.update(t_s, state.x_w, goal_w, remaining)
    if new is not None:
        trackers[i] = PathTracker(new.waypoints_w, agent.speed_mps, cut_m=route.cut_m)
        remaining = trackers[i].reference(state.x_w)[2]
    v_path = trackers[i].command(state.x_w)[0]
    return route.hold(t_s, remaining, state.x_w, others_x_w, others_v_w, state.v_w, v_path)


def simulate_swarm(
    model: QuadModel,
    agents: list[SwarmAgent],
    obstacles: ObstacleArrays,
    duration_s: float,
    *,
    control_hz: float = 100.0,
    physics_hz: float = 300.0,
    goal_tolerance_m: float = 0.15,
) -> SwarmLog:
    """Fly a swarm in one process, as a lockstep run with the world's roster does: at
    every tick each agent filters its tracker's thrust vector (attitude level) against
    the obstacles and every other agent's body centre and velocity of that tick (no
    acceleration, as a roster gives; an agent whose last filter call was not a clean
    solve is an obstacle row, as the roster's ``solo`` makes it), then the firmware's attitude loop and RK4 physics
    run ``physics_hz / control_hz`` steps. Ends early once every agent has been within
    ``goal_tolerance_m`` of its goal. No I/O; the benchmark and tests use it."""
    for i, a in enumerate(agents):
        if a.config.level is not CommandLevel.ATTITUDE:
            raise InputError(f"agents[{i}].config.level: simulate_swarm flies the attitude level, got {a.config.level}")
    n = len(agents)
    trackers = [PathTracker(np.vstack([a.start_w, a.path_w]), a.speed_mps, cut_m=corner_cut_m(a.route)) for a in agents]
    filters = [SafetyFilter(model, a.config) for a in agents]
    states = [QuadState.hover(a.start_w) for a in agents]
    for s, a in zip(states, agents, strict=True):
        if a.start_velocity_w is not None:
            s.v_w = np.asarray(a.start_velocity_w, dtype=float).copy()
    onboard = [OnboardController(model, 0.0) for _ in agents]
    n_sub = max(1, round(physics_hz / control_hz))
    dt = 1.0 / (control_hz * n_sub)
    p = model.params
    r_nb = np.full(n, p.body_radius_m)
    others = [np.array([j for j in range(n) if j != i], dtype=np.intp) for i in range(n)]
    zeros = np.zeros((max(n - 1, 0), 3))
    ok = np.ones(n, dtype=bool)  # each agent's last filter call was a clean solve (it does its share)
    goals = np.array([a.goal_w for a in agents])
    t_goal: list[float | None] = [None] * n
    log_t, log_x, log_v, log_s, log_com, log_vb = [], [], [], [], [], []
    min_sep, min_clear = math.inf, math.inf
    for k in range(round(duration_s * control_hz)):
        t = k / control_hz
        obs = obstacles_at(obstacles, t)
        xb, vb = _body_rows(states, p.l_m)
        x_com = np.array([s.x_w for s in states])
        if n > 1:
            min_sep = min(min_sep, min_pair_distance(xb))
        if len(obs):
            min_clear = min(min_clear, float(surface_clearance(xb, obs).min()))
        statuses = []
        setpoints = []
        for i in range(n):
            nb = ObstacleArrays(xb[others[i]], vb[others[i]], zeros, r_nb[others[i]], zeros, ok[others[i]], True)
            held = _gives_way(agents[i], trackers, i, t, states[i], goals[i], xb[others[i]], vb[others[i]])
            if held is not None:  # giving way: hover, or back out of a passage
                F_ref = trackers[i].thrust_vector(model, states[i].x_w, states[i].v_w, held)
            else:
                F_ref = reference_thrust(
                    model,
                    trackers[i],
                    states[i].x_w,
                    states[i].v_w,
                    xb[i],
                    xb[others[i]],
                    agents[i].tiebreak,
                    vb[others[i]] if follows(agents[i].route) else None,
                )
            if agents[i].filtered:
                res = filters[i].filter(states[i], F_ref, ObstacleArrays.concat([obs, nb]))
                u, status = res.u, res.status
            else:
                u, status = F_ref, FilterStatus.OK
            statuses.append(status)
            setpoints.append(setpoint_from_thrust_vector(u, yaw_of(states[i])))
        ok = np.array(
            [st is FilterStatus.OK and a.filtered for st, a in zip(statuses, agents, strict=True)]
        )  # the next tick's shares, as the roster gives them
        for i in range(n):
            for _ in range(n_sub):
                states[i] = step_rk4(model, states[i], onboard[i].rotor_thrusts(states[i], setpoints[i], dt), dt)
        x_now = np.array([s.x_w for s in states])
        for i in np.flatnonzero(np.linalg.norm(x_now - goals, axis=1) <= goal_tolerance_m).tolist():
            if t_goal[i] is None:
                t_goal[i] = t + 1.0 / control_hz
        log_t.append(t)
        log_x.append(xb)
        log_vb.append(vb)
        log_com.append(x_com)
        log_v.append(np.array([s.v_w for s in states]))
        log_s.append(statuses)
        if all(tg is not None for tg in t_goal):
            break
    return SwarmLog(
        np.array(log_t),
        np.array(log_x),
        np.array(log_v),
        log_s,
        min_sep,
        min_clear,
        t_goal,
        np.array(log_com),
        np.array(log_vb),
    )


def scenario_swarm(cfg: ScenarioConfig) -> tuple[list[SwarmAgent], ObstacleArrays]:
    """A validated scenario's agents and obstacles (at t = 0) as :func:`simulate_swarm`
    takes them, every filter at the attitude level."""
    still = StaticObstacles.of(list(cfg.obstacles))
    agents = []
    for a in cfg.agents:
        path_w, route = path_for(a, still)  # around the static obstacles, as the agents fly it
        agents.append(
            SwarmAgent(
                np.asarray(a.start, dtype=float),
                path_w[1:] if len(path_w) > 1 else path_w,
                a.speed_mps,
                filter_config_for(a, still, CommandLevel.ATTITUDE, route),
                np.asarray(a.start_velocity, dtype=float),
                a.tiebreak.pair,
                a.filter.enabled,
                route,
            )
        )
    return agents, items_to_arrays(obstacle_items(list(cfg.obstacles), 0.0))


@dataclass(frozen=True)
class SwarmOutcome:
    """How a :func:`simulate_swarm` run went, by the runtime's metric definitions."""

    collisions: int  # contacts: agent pairs whose airframes touched, plus agent-obstacle contacts
    margin_violations: int  # pairs and agent-obstacles ever closer than the safety radius (body radii + margin)
    deadlocked: int  # agents that never reached the goal and stalled short of it (swarm.offline.metrics.deadlock_at)
    reached: int  # agents that reached their goal
    agents: int
    infeasible_ticks: int
    time_ratios: list[float]  # per agent that arrived: time to goal / (straight line / target speed)
    min_h: float | None = None  # m^2/s: the smallest exact C3BF h of a row an agent had (swarm.offline.metrics)
    negative_h_ticks: int = 0  # agent ticks with such an h below 0
    downwash_pairs: int = 0  # pairs ever inside their downwash keep-out ellipsoid (swarm.offline.metrics)
    downwash_pair_ticks: int = 0  # pair-ticks they were
    min_downwash_distance: float | None = None  # smallest scaled distance of a pair [unit-free] (below 1: inside)

    @property
    def success(self) -> bool:
        return self.reached == self.agents and self.collisions == 0


def outcome(cfg: ScenarioConfig, log: SwarmLog) -> SwarmOutcome:
    """Contacts, the safety figures of ``swarm.offline.metrics`` (margin violations, the exact
    barrier), deadlocks, arrivals and time ratios of a run of ``cfg``."""
    from swarm.offline.metrics import SafetyFigures, deadlock_at

    body = np.array([a.airframe.params().body_radius_m for a in cfg.agents])
    x = log.x_b_w  # (T, N, 3)
    n = x.shape[1]
    contacts = 0
    for i in range(n):
        for j in range(i + 1, n):
            contacts += bool((np.linalg.norm(x[:, i] - x[:, j], axis=1) < body[i] + body[j]).any())
    obs = items_to_arrays(obstacle_items(list(cfg.obstacles), 0.0))
    for i in range(n) if len(obs) else ():
        clear = np.array([surface_clearance(x[k, i][None], obstacles_at(obs, t))[0] for k, t in enumerate(log.t_s)])
        contacts += int(((clear < body[i]).sum(axis=0) > 0).sum())
    figures = SafetyFigures(cfg)
    com = log.x_w if log.x_w is not None else x
    v_b = log.v_b_w if log.v_b_w is not None else log.v_w
    obstacle_ids = [o.id for o in cfg.obstacles]
    for k, t in enumerate(log.t_s):
        figures.add(list(range(n)), com[k], x[k], v_b[k], obstacles_at(obs, t), obstacle_ids)
    min_h = float(figures.min_h.min()) if n else math.inf
    dl = cfg.deadlock
    deadlocked = 0
    ratios = []
    for i, a in enumerate(cfg.agents):
        goal = np.asarray(a.final_goal, dtype=float)
        t_goal = log.time_to_goal_s[i]
        if t_goal is None and (  # arrived (its last step can end the run before it is logged): no deadlock
            deadlock_at(  # from the centre of mass, as the arrival and the runtime's metrics
                log.t_s, com[:, i], log.v_w[:, i], goal, cfg.goal_tolerance_m, speed_mps=dl.speed_mps, hold_s=dl.hold_s
            )
            is not None
        ):
            deadlocked += 1
        straight = float(np.linalg.norm(goal - np.asarray(a.start))) / a.speed_mps
        if t_goal is not None and straight > 0:
            ratios.append(t_goal / straight)
    reached = sum(t is not None for t in log.time_to_goal_s)
    return SwarmOutcome(
        contacts,
        len(figures.violations),
        deadlocked,
        reached,
        n,
        log.infeasible_ticks,
        ratios,
        min_h if math.isfinite(min_h) else None,
        int(figures.negative.sum()),
        len(figures.downwash),
        figures.downwash_ticks,
        figures.min_downwash if math.isfinite(figures.min_downwash) else None,
    )
