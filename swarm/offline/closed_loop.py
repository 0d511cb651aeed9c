"""In-process closed loops: one agent (:func:`simulate`) or a swarm (:func:`simulate_swarm`),
each agent's control step the one the agent process runs (:class:`swarm.step.AgentStep`), its
command flown as the world process flies it, with RK4 rigid-body physics and obstacles moving
at constant acceleration. No I/O; the runtime's world process does the same with PyBullet.
Used by tests, the liveness benchmark and quick studies."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from swarm.config import FailureSettings, MonitorSettings, NeighbourSettings, ScenarioConfig
from swarm.control import AttitudeSetpoint, OnboardController, PathTracker, yaw_of
from swarm.errors import InputError
from swarm.geometry import items_to_arrays, min_pair_distance, obstacle_items, surface_clearance
from swarm.model import CommandLevel, QuadModel, QuadState, body_centre, step_rk4
from swarm.net.cells import near_lists
from swarm.net.neighbours import NearNeighbours
from swarm.planning import StaticObstacles
from swarm.realism.comms import CommsModel, DelayLine, MessageKind
from swarm.realism.plant import Plant
from swarm.realism.sensing import MocapFrame, MocapSensor
from swarm.realism.settings import RealismSettings
from swarm.reference import ContainedController
from swarm.rotation import E3, FloatArray, quat_to_R
from swarm.route import Route, corner_cut_m, path_for
from swarm.safety.external import ContainedFilter
from swarm.safety.filter import FilterConfig, FilterResult, FilterStatus
from swarm.safety.monitor import BREACH_NAMES, Action
from swarm.safety.obstacles import NamedObstacles, ObstacleArrays
from swarm.step import AgentStep, contained_controller, contained_plugin
from swarm.tuning import (
    NOISE_SIGMAS,
    command_lead_s,
    delay_speed_mps,
    filter_config_for,
    monitor_params,
    neighbour_table,
)


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
    """Fly one agent's control step (:class:`swarm.step.AgentStep`) for ``duration_s``
    seconds among ``obstacles`` moving with their constant acceleration; the command is held
    between control ticks (at the attitude level flown by the firmware's attitude loop)."""
    step = AgentStep(model, config, tracker, filtered=filter_on)
    plant = _Plant(model, config.level, [state0.copy()], [yaw_of(state0)], physics_hz, control_hz)
    log = ClosedLoopLog()
    ids = [f"obstacle-{i}" for i in range(len(obstacles))]
    none = NamedObstacles.none()
    for k in range(round(duration_s * control_hz)):
        t = k / control_hz
        obs = obstacles_at(obstacles, t)
        state = plant.states[0]
        res = step(t, state, NamedObstacles(obs, ids), none)
        log.t_s.append(t)
        log.x_w.append(state.x_w.copy())
        log.x_b_w.append(res.x_b_w)
        log.v_w.append(state.v_w.copy())
        log.clearance_m.append(surface_clearance(res.x_b_w[None, :], obs)[0])
        if res.filter is not None:
            log.results.append(res.filter)
        plant.send(0, res.command, k)
        plant.fly(k)
    return log


class _Plant:
    """The offline world's drones, as the world process flies them: each holds its agent's
    newest command (at the attitude level the firmware's attitude loop flies the setpoint,
    integrating its yaw rate; at the rotor level the thrusts, clipped to the rotor limits) over
    ``physics_hz / control_hz`` RK4 substeps a control tick. With ``realism``
    (``world.realism``; ``swarm.realism``) the drones are the plant's airframes, their rotors make
    the plant's thrusts and its downwash, drag, ground effect and wind act on them; motion
    capture sees them every substep (:meth:`frames`); a command reaches its drone after its
    seeded delay, or never."""

    def __init__(
        self,
        model: QuadModel,
        level: CommandLevel,
        states: list[QuadState],
        yaw0_rad: list[float],
        physics_hz: float,
        control_hz: float,
        realism: RealismSettings | None = None,
        seed: int = 0,
        ids: list[str] | None = None,
    ) -> None:
        self.model, self.level, self.states = model, level, states
        n = len(states)
        self.onboard = [OnboardController(model, y) for y in yaw0_rad]
        self.n_sub = max(1, round(physics_hz / control_hz))
        self.dt_s = 1.0 / (control_hz * self.n_sub)
        self.ids = ids or [f"agent-{i}" for i in range(n)]
        self.commands: list[FloatArray | None] = [None] * n
        self.plant: Plant | None = None
        self.bodies = [model] * n  # the rigid bodies (the plant's airframes)
        self.mocap: MocapSensor | None = None
        self.comms: CommsModel | None = None
        self.in_flight: DelayLine[tuple[int, FloatArray]] = DelayLine()
        self.commands_lost = 0
        self.seen: list[list[MocapFrame]] = [[] for _ in range(n)]
        self.t_s = 0.0
        if realism is not None:
            plant = realism.plant([model.params] * n, self.dt_s, seed)
            if not plant.p.ideal:
                self.plant = plant
                self.bodies = [QuadModel(a) for a in plant.airframes]
            if realism.sensing.enabled:
                self.mocap = realism.mocap(n, seed)
            if not realism.comms.params().perfect:
                self.comms = realism.comms_model(seed, 1.0 / control_hz)

    def send(self, i: int, command: FloatArray, k: int) -> None:
        """Drone ``i``'s command answering tick ``k``: flown from this tick, or after its fate's delay."""
        if self.comms is None:
            self.commands[i] = command
        elif not self.in_flight.put(k, self.comms.fate(self.ids[i], "world", MessageKind.COMMAND, k), (i, command)):
            self.commands_lost += 1

    def _capture(self) -> None:
        if self.mocap is not None:
            x = np.array([s.x_w for s in self.states])
            q = np.array([s.q for s in self.states])
            for f in self.mocap.step(self.t_s, x, q):
                self.seen[f.drone].append(f)

    def frames(self, i: int) -> list[MocapFrame]:
        """Drone ``i``'s motion-capture frames that arrived since the last call (none without sensing)."""
        self._capture()
        out, self.seen[i] = self.seen[i], []
        return out

    def fly(self, k: int) -> None:
        """Control tick ``k``: the commands due by now, then the substeps of every drone."""
        for i, command in self.in_flight.due(k):
            self.commands[i] = command
        n, dt = len(self.states), self.dt_s
        for j in range(self.n_sub):
            if j:
                self._capture()
            f = np.zeros((n, 4))
            for i, cmd in enumerate(self.commands):
                if cmd is None:
                    sp = AttitudeSetpoint(0.0, 0.0, 0.0, self.model.params.weight_N)
                    f[i] = self.onboard[i].rotor_thrusts(self.states[i], sp, dt)
                elif self.level is CommandLevel.ATTITUDE:
                    f[i] = self.onboard[i].rotor_thrusts(self.states[i], AttitudeSetpoint(*cmd.tolist()), dt)
                else:
                    f[i] = np.clip(cmd, 0.0, self.model.params.f_max_N)
            if self.plant is None:
                for i in range(n):
                    self.states[i] = step_rk4(self.bodies[i], self.states[i], f[i], dt)
            else:
                x = np.array([s.x_w for s in self.states])
                v = np.array([s.v_w for s in self.states])
                R = np.array([quat_to_R(s.q) for s in self.states])
                out = self.plant.step(x, v, R, f)
                for i in range(n):
                    self.states[i] = step_rk4(
                        self.bodies[i], self.states[i], out.f_N[i], dt, out.force_w[i], out.torque_b[i]
                    )
            self.t_s += dt


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
    id: str = ""  # its name (the seeded imperfections of world.realism depend on it); "" : agent-<index>
    # its safety filter plugin (swarm.safety.external), built per run from the control rate [Hz]; None: config's QP
    plugin: Callable[[float], ContainedFilter | None] | None = None
    # its reference controller plugin (swarm.reference), built per run from the control rate; None: the tracker
    controller: Callable[[float], ContainedController | None] | None = None

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
    estimate_error_m: FloatArray | None = None  # (T, N) m: |estimated - true centre of mass| (None: no estimator)
    states_lost: int = 0  # world.realism.comms: neighbour states that never arrived
    commands_lost: int = 0  # world.realism.comms: commands that never reached their drone
    frames_dropped: int = 0  # world.realism.sensing: motion-capture frames dropped
    accel_cmd_w: FloatArray | None = None  # (T, N, 3) m/s^2, world: what each command asks, F / m_nominal - g e3
    monitor: FloatArray | None = None  # (T, N) the safety monitor's action (swarm.safety.monitor.Action)
    breach_ticks: dict[str, int] = field(default_factory=dict)  # per check: agent ticks it breached
    own_sd_m: FloatArray | None = None  # (T, N) m: each estimate's largest axis position deviation
    live_margin_m: FloatArray | None = None  # (T, N) m: the largest live noise margin of a row
    unguarded_ticks: int = 0  # agent ticks an estimate's error exceeded its live bound with the monitor not acting
    fallbacks: list[int] = field(default_factory=list)  # per agent: ticks its plugin's command was replaced
    controller_fallbacks: list[int] = field(default_factory=list)  # per agent: its controller plugin's, replaced

    def action_ticks(self, action: Action) -> int:
        """Agent ticks the monitor took ``action`` (0 without a log)."""
        return 0 if self.monitor is None else int((self.monitor == int(action)).sum())

    @property
    def landed_by_monitor(self) -> list[bool]:
        """Per agent: the monitor landed it."""
        return (
            [False] * self.x_b_w.shape[1]
            if self.monitor is None
            else (self.monitor == int(Action.LAND)).any(0).tolist()
        )

    @property
    def infeasible_ticks(self) -> int:
        """Agent ticks whose filter call was not a clean solve (every status but OK: slack,
        escape rows, a failed solve), as the agents and ``swarm.offline.metrics`` count them."""
        return sum(s is not FilterStatus.OK for row in self.status for s in row)

    @property
    def all_reached(self) -> bool:
        return all(t is not None for t in self.time_to_goal_s)


def _body_rows(states: list[QuadState], l_m: float) -> tuple[FloatArray, FloatArray]:
    xb = np.empty((len(states), 3))
    vb = np.empty((len(states), 3))
    for i, s in enumerate(states):
        xb[i], vb[i], _ = body_centre(s.x_w, s.v_w, s.q, s.Omega_b, l_m)
    return xb, vb


_FAILURE = FailureSettings()
_NEAR_MARGIN_M = NeighbourSettings().margin_m / 2


def simulate_swarm(
    model: QuadModel,
    agents: list[SwarmAgent],
    obstacles: ObstacleArrays,
    duration_s: float,
    *,
    control_hz: float = 100.0,
    physics_hz: float = 300.0,
    goal_tolerance_m: float = 0.15,
    realism: RealismSettings | None = None,
    seed: int = 0,
    monitor: MonitorSettings | None = None,
    occlusions: Sequence[tuple[int, float, float]] = (),
) -> SwarmLog:
    """Fly a swarm in one process, as a lockstep run of the agent processes with neighbours by
    bundles does: at every tick each agent's control step (:class:`swarm.step.AgentStep`, the
    attitude level) filters against the obstacles and the states its neighbours published at
    tick k-1 (body centre, velocity, whether they did their share), extrapolated to the tick by
    the same neighbour view the agents keep (``swarm.net.neighbours.NearNeighbours``), of the
    agents the world names near it (within its sensing radius and half the default margin);
    then the firmware's attitude loop and RK4 physics run ``physics_hz / control_hz`` steps.
    Ends early once every agent has been within ``goal_tolerance_m`` of its goal. With
    ``realism`` (``world.realism``, seeded by ``seed``) the world is as imperfect as the world
    process makes it (the plant, motion capture and each agent's estimator, the delay and loss of
    states and commands: :class:`_Plant`, ``swarm.net.neighbours.HeardNeighbours``). No I/O; the
    benchmark and tests use it. ``monitor``: each agent's safety monitor (None: the default
    settings, as the agent processes run it). ``occlusions``: scripted motion-capture occlusions,
    (agent index, from [s], until [s]) each (``MocapSensor.hide``; needs sensing)."""
    for i, a in enumerate(agents):
        if a.config.level is not CommandLevel.ATTITUDE:
            raise InputError(f"agents[{i}].config.level: simulate_swarm flies the attitude level, got {a.config.level}")
    n = len(agents)
    names = [a.id or f"agent-{i}" for i, a in enumerate(agents)]
    r = realism if realism is not None and not realism.ideal else None
    sensing = r is not None and r.sensing.enabled
    comms = None if r is None or r.comms.params().perfect else r.comms_model(seed, 1.0 / control_hz)
    lead = command_lead_s(r, control_hz)
    limits = [a.config.accel_limit_mps2 for a in agents]  # the swarm's agreed acceleration (swarm.tuning)
    accel = None if r is None or any(x is None for x in limits) else max(x for x in limits if x is not None)
    mon = monitor_params(monitor or MonitorSettings(), r, _FAILURE, control_hz, lead if accel is not None else 0.0)
    steps = [
        AgentStep(
            model,
            a.config,
            PathTracker(np.vstack([a.start_w, a.path_w]), a.speed_mps, cut_m=corner_cut_m(a.route)),
            goal_w=a.goal_w,
            route=a.route,
            tiebreak=a.tiebreak,
            filtered=a.filtered,
            goal_tolerance_m=goal_tolerance_m,
            estimator=(
                r.estimator(a.start_w, np.array([0.0, 0.0, 0.0, 1.0]), v0_w=a.start_velocity_w)
                if r is not None and sensing
                else None
            ),
            lead_s=lead,
            monitor=mon,
            offset_sd_m=r.sensing.centroid_offset_std_m if r is not None and sensing else 0.0,
            publish_ahead=a.config.accel_limit_mps2 is not None,  # (the swarm's delay contract binds)
            plugin=None if a.plugin is None else a.plugin(control_hz),
            controller=None if a.controller is None else a.controller(control_hz),
        )
        for a in agents
    ]
    table = neighbour_table(_FAILURE, model.params, r, control_hz, accel)
    heard = [NearNeighbours(set(names) - {names[i]}, table.blank(), math.inf, names[i], comms) for i in range(n)]
    near_m = np.array([a.config.sensing_radius_m + _NEAR_MARGIN_M for a in agents])
    states = [QuadState.hover(a.start_w) for a in agents]
    for s, a in zip(states, agents, strict=True):
        if a.start_velocity_w is not None:
            s.v_w = np.asarray(a.start_velocity_w, dtype=float).copy()
    plant = _Plant(model, CommandLevel.ATTITUDE, states, [0.0] * n, physics_hz, control_hz, r, seed, names)
    if occlusions:
        if plant.mocap is None:
            raise InputError("simulate_swarm: occlusions need motion capture (world.realism.sensing)")
        for drone, t0, t1 in occlusions:
            plant.mocap.hide(drone, t0, t1)
    p = model.params
    everyone = np.ones(n, dtype=bool)
    goals = np.array([a.goal_w for a in agents])
    t_goal: list[float | None] = [None] * n
    log_t, log_x, log_v, log_s, log_com, log_vb, log_err, log_a = [], [], [], [], [], [], [], []
    log_mon, log_sd, log_live = [], [], []
    unguarded = 0
    min_sep, min_clear = math.inf, math.inf
    for k in range(round(duration_s * control_hz)):
        t = k / control_hz
        obs = NamedObstacles(obstacles_at(obstacles, t), [f"obstacle-{j}" for j in range(len(obstacles))])
        xb, vb = _body_rows(states, p.l_m)
        x_com = np.array([s.x_w for s in states])
        if n > 1:
            min_sep = min(min_sep, min_pair_distance(xb))
        if len(obs):
            min_clear = min(min_clear, float(surface_clearance(xb, obs.arrays).min()))
        near = near_lists(xb, everyone, near_m)
        results = []
        for i in range(n):
            heard[i].on_list(k, [names[j] for j in near[i]])
            frames = plant.frames(i) if sensing else None
            results.append(steps[i](t, states[i], obs, heard[i].rows(t + lead, k, xb[i], lockstep=True), frames=frames))
        for i, res in enumerate(results):  # this tick's states, which the next tick uses
            for j in range(n):
                if j != i:
                    heard[j].take(
                        names[i], t + res.ahead_s, k, res.x_b_w, res.v_b_w, p.body_radius_m, res.solo, True, sd=res.sd
                    )
        for i, res in enumerate(results):
            plant.send(i, res.command, k)
        plant.fly(k)
        x_now = np.array([s.x_w for s in states])
        for i in np.flatnonzero(np.linalg.norm(x_now - goals, axis=1) <= goal_tolerance_m).tolist():
            if t_goal[i] is None:
                t_goal[i] = t + 1.0 / control_hz
        log_t.append(t)
        log_x.append(xb)
        log_vb.append(vb)
        log_com.append(x_com)
        log_v.append(np.array([s.v_w for s in states]))
        log_s.append([res.status for res in results])
        log_a.append(np.array([res.u for res in results]) / p.mass_kg - p.g_mps2 * E3)
        log_mon.append([int(res.verdict.action) for res in results])
        log_live.append([res.live_margin_m for res in results])
        if sensing:
            est = np.array([res.est for res in results])
            log_err.append(np.linalg.norm(est[:, :3] - x_com, axis=1))
            log_sd.append(est[:, 6])
            beyond = np.abs(est[:, :3] - x_com).max(axis=1) > NOISE_SIGMAS * est[:, 6]
            unguarded += int((beyond & (log_mon[-1] < np.array(int(Action.SLOW)))).sum())
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
        np.array(log_err) if sensing else None,
        sum(h.states_lost for h in heard),
        plant.commands_lost,
        plant.mocap.dropped if plant.mocap is not None else 0,
        np.array(log_a),
        np.array(log_mon),
        {
            name: sum(s.monitor.breach_ticks.get(name, 0) for s in steps if s.monitor is not None)
            for name in BREACH_NAMES.values()
        },
        np.array(log_sd) if sensing else None,
        np.array(log_live),
        unguarded,
        [0 if s.plugin is None else s.plugin.fallbacks for s in steps],
        [0 if s.controller is None else s.controller.fallbacks for s in steps],
    )


def scenario_swarm(cfg: ScenarioConfig) -> tuple[list[SwarmAgent], ObstacleArrays]:
    """A validated scenario's agents and obstacles (at t = 0) as :func:`simulate_swarm`
    takes them, every filter at the attitude level (a safety filter plugin with its own)."""
    still = StaticObstacles.of(list(cfg.obstacles))
    agents = []
    for a in cfg.agents:
        path_w, route = path_for(a, still)  # around the static obstacles, as the agents fly it
        config = filter_config_for(a, still, CommandLevel.ATTITUDE, route, cfg.world.realism, cfg.time.control_hz)
        agents.append(
            SwarmAgent(
                np.asarray(a.start, dtype=float),
                path_w[1:] if len(path_w) > 1 else path_w,
                delay_speed_mps(a, cfg.world.realism, cfg.time.control_hz),
                config,
                np.asarray(a.start_velocity, dtype=float),
                a.tiebreak.pair,
                a.filter.enabled,
                route,
                a.id,
                partial(contained_plugin, a, config),
                partial(contained_controller, a, speed_mps=delay_speed_mps(a, cfg.world.realism, cfg.time.control_hz)),
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
