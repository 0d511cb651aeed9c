"""In-process closed loops. A scenario (:func:`fly_scenario`): the world process's plant and
every agent as ``swarm agent`` builds it (:mod:`swarm.build`), ticked as a lockstep run of the
processes ticks them, without the transport; the benchmarks, experiments and tests fly their
swarms through it. One agent's control step alone (:func:`simulate`): a study of the step
among obstacles moving at constant acceleration, on an ideal RK4 rigid body. No I/O."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from swarm.build import agent_neighbour_table, agent_step
from swarm.config import ScenarioConfig
from swarm.control import AttitudeSetpoint, OnboardController, PathTracker, yaw_of
from swarm.errors import InputError
from swarm.geometry import items_to_arrays, min_pair_distance, obstacle_items, surface_clearance
from swarm.model import CommandLevel, QuadModel, QuadState, body_centre, step_rk4
from swarm.net.cells import near_lists
from swarm.net.neighbours import NearNeighbours
from swarm.planning import StaticObstacles
from swarm.realism.sensing import MocapFrame
from swarm.rotation import E3, FloatArray
from swarm.safety.filter import FilterConfig, FilterResult, FilterStatus
from swarm.safety.monitor import BREACH_NAMES, Action
from swarm.safety.obstacles import NamedObstacles, ObstacleArrays
from swarm.sim.stepper import Stepper
from swarm.step import AgentStep, StepResult
from swarm.tuning import NOISE_SIGMAS


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
    plant = _Plant(model, config.level, state0.copy(), physics_hz, control_hz)
    log = ClosedLoopLog()
    ids = [f"obstacle-{i}" for i in range(len(obstacles))]
    none = NamedObstacles.none()
    for k in range(round(duration_s * control_hz)):
        t = k / control_hz
        obs = obstacles_at(obstacles, t)
        state = plant.state
        res = step(t, state, NamedObstacles(obs, ids), none)
        log.t_s.append(t)
        log.x_w.append(state.x_w.copy())
        log.x_b_w.append(res.x_b_w)
        log.v_w.append(state.v_w.copy())
        log.clearance_m.append(surface_clearance(res.x_b_w[None, :], obs)[0])
        if res.filter is not None:
            log.results.append(res.filter)
        plant.fly(res.command)
    return log


class _Plant:
    """The single-agent study loop's drone (:func:`simulate`): the ideal world's rigid body
    holding its agent's newest command (at the attitude level the firmware's attitude loop
    flies the setpoint, at the rotor level the thrusts, clipped to the rotor limits) over
    ``physics_hz / control_hz`` RK4 substeps a control tick. A swarm, and any world with
    imperfections, flies the world's own plant (:func:`fly_scenario`)."""

    def __init__(
        self, model: QuadModel, level: CommandLevel, state: QuadState, physics_hz: float, control_hz: float
    ) -> None:
        self.model, self.level, self.state = model, level, state
        self.onboard = OnboardController(model, yaw_of(state))
        self.n_sub = max(1, round(physics_hz / control_hz))
        self.dt_s = 1.0 / (control_hz * self.n_sub)
        self.command: FloatArray | None = None

    def fly(self, command: FloatArray) -> None:
        """One control tick flying ``command`` from now."""
        self.command, dt = command, self.dt_s
        for _ in range(self.n_sub):
            if self.level is CommandLevel.ATTITUDE:
                f = self.onboard.rotor_thrusts(self.state, AttitudeSetpoint(*command.tolist()), dt)
            else:
                f = np.clip(command, 0.0, self.model.params.f_max_N)
            self.state = step_rk4(self.model, self.state, f, dt)


@dataclass
class SwarmLog:
    """What :func:`fly_scenario` measured. Distances between body centres."""

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
    fallbacks: list[int] = field(default_factory=list)  # per agent: ticks its filter plugin's command was replaced
    controller_fallbacks: list[int] = field(default_factory=list)  # per agent: its controller plugin's, replaced
    replans: list[int] = field(default_factory=list)  # per agent: the new paths its route planned (0 without one)

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


def fly_scenario(cfg: ScenarioConfig, occlusions: Sequence[tuple[int, float, float]] = ()) -> SwarmLog:
    """Fly the scenario ``cfg`` in one process as a lockstep run of its processes flies it: the
    world's plant (:class:`swarm.sim.stepper.Stepper`: PyBullet, each drone's airframe and yaw,
    ``world.realism``'s plant, motion capture and command link, seeded by ``cfg.seed``), each
    agent's control step and neighbour table built as ``swarm agent`` builds them
    (:mod:`swarm.build`), and each agent hearing, at tick k, the states of tick k-1 of the live
    agents the world names near it (``swarm.net.neighbours.NearNeighbours``, with
    ``world.realism.comms``' delays and losses of states and bundles). Tick by tick as the
    world process: measure (and motion capture) at ``t = k dt``, every agent's step, the
    commands sent through their link, the substeps. Ends at ``cfg.duration_s`` or, with
    ``stop_when_all_reached``, once every agent has been within the goal tolerance of its goal.
    ``occlusions``: scripted motion-capture occlusions, (agent index, from [s], until [s]) each
    (``MocapSensor.hide``; needs sensing). No I/O. Only simulated drones: an agent with
    ``backend: crazyflie`` is refused (its drone is real)."""
    real = [i for i, a in enumerate(cfg.agents) if a.backend != "sim"]
    if real:
        raise InputError(f"agents.{real[0]}.backend: the offline loop flies simulated drones, got a real one")
    world = Stepper(cfg)
    names = world.names
    n = len(names)
    realism = cfg.world.realism
    still = StaticObstacles.of(list(cfg.obstacles))
    steps = [agent_step(cfg, a, still) for a in names]
    comms = None if realism.comms.params().perfect else realism.comms_model(cfg.seed, 1.0 / cfg.time.control_hz)
    heard = [NearNeighbours(set(names) - {a}, agent_neighbour_table(cfg, a), math.inf, a, comms) for a in names]
    if occlusions:
        if world.mocap is None:
            raise InputError("fly_scenario: occlusions need motion capture (world.realism.sensing)")
        for drone, t0, t1 in occlusions:
            world.mocap.hide(drone, t0, t1)
    near_m = np.array([cfg.near_radius_m(a) for a in names])
    radius = world.radius_m.tolist()
    goals = np.array([cfg.agent(a).final_goal for a in names], dtype=float)
    ids = [o.id for o in cfg.obstacles]
    dt = 1.0 / cfg.time.control_hz
    K = round(cfg.duration_s * cfg.time.control_hz)
    everyone = np.ones(n, dtype=bool)
    t_goal: list[float | None] = [None] * n
    log_t, log_x, log_v, log_s, log_com, log_vb, log_err, log_a = [], [], [], [], [], [], [], []
    log_mon, log_sd, log_live = [], [], []
    unguarded = 0
    min_sep, min_clear = math.inf, math.inf
    sensing = world.mocap is not None
    for k in range(K + 1):
        t = k * dt
        ds = world.read()
        l_m = world.l_m[:, None]
        xb = ds.x_w + l_m * ds.R[:, :, 2]
        vb = ds.v_w + l_m * (ds.R[:, :, 0] * ds.Omega_b[:, 1:2] - ds.R[:, :, 1] * ds.Omega_b[:, 0:1])
        frames: list[list[MocapFrame] | None] = [None] * n
        if sensing:
            world.capture(t, ds)
            frames = [world.frames_of(a) for a in names]
        for i in np.flatnonzero(np.linalg.norm(ds.x_w - goals, axis=1) <= cfg.goal_tolerance_m).tolist():
            if t_goal[i] is None:
                t_goal[i] = t
        done = k == K or (cfg.stop_when_all_reached and all(tg is not None for tg in t_goal))
        if done:
            break
        items = obstacle_items(list(cfg.obstacles), t)
        obs = NamedObstacles(items_to_arrays(items), ids)
        if n > 1:
            min_sep = min(min_sep, min_pair_distance(xb))
        if len(obs):
            min_clear = min(min_clear, float(surface_clearance(xb, obs.arrays).min()))
        near = near_lists(xb, everyone, near_m)
        results = []
        for i in range(n):
            heard[i].on_list(k, [names[j] for j in near[i]])
            state = ds.state(i)
            x_b = body_centre(state.x_w, state.v_w, state.q, state.Omega_b, steps[i].model.params.l_m)[0]
            rows = heard[i].rows(t + steps[i].lead_s, k, x_b, lockstep=True)
            results.append(steps[i](t, state, obs, rows, frames=frames[i]))
        for i, res in enumerate(results):  # this tick's states, which the next tick uses
            for j in range(n):
                if j != i:
                    heard[j].take(
                        names[i], t + res.ahead_s, k, res.x_b_w, res.v_b_w, radius[i], res.solo, bundled=True, sd=res.sd
                    )
        for i, res in enumerate(results):
            world.send(names[i], res.command, t, k)
        for j in range(cfg.time.substeps):
            world.deliver(k)
            world.substep(ds if j == 0 else None, j == 0, {}, ds.v_w)
        x_com = ds.x_w
        log_t.append(t)
        log_x.append(xb)
        log_vb.append(vb)
        log_com.append(x_com)
        log_v.append(ds.v_w)
        log_s.append([res.status for res in results])
        log_a.append(
            np.array([_accel_w(s, res, ds.R[i]) for i, (s, res) in enumerate(zip(steps, results, strict=True))])
        )
        log_mon.append([int(res.verdict.action) for res in results])
        log_live.append([res.live_margin_m for res in results])
        if sensing:
            est = np.array([res.est for res in results])
            log_err.append(np.linalg.norm(est[:, :3] - x_com, axis=1))
            log_sd.append(est[:, 6])
            beyond = np.abs(est[:, :3] - x_com).max(axis=1) > NOISE_SIGMAS * est[:, 6]
            unguarded += int((beyond & (np.array(log_mon[-1]) < int(Action.SLOW))).sum())
    world.close()
    return SwarmLog(
        t_s=np.array(log_t),
        x_b_w=np.array(log_x),
        v_w=np.array(log_v),
        status=log_s,
        min_separation_m=min_sep,
        min_clearance_m=min_clear,
        time_to_goal_s=t_goal,
        x_w=np.array(log_com),
        v_b_w=np.array(log_vb),
        estimate_error_m=np.array(log_err) if sensing else None,
        states_lost=sum(h.states_lost for h in heard),
        commands_lost=world.commands_lost,
        frames_dropped=world.mocap.dropped if world.mocap is not None else 0,
        accel_cmd_w=np.array(log_a),
        monitor=np.array(log_mon),
        breach_ticks={
            name: sum(s.monitor.breach_ticks.get(name, 0) for s in steps if s.monitor is not None)
            for name in BREACH_NAMES.values()
        },
        own_sd_m=np.array(log_sd) if sensing else None,
        live_margin_m=np.array(log_live),
        unguarded_ticks=unguarded,
        replans=[0 if s.route is None else s.route.replans for s in steps],
        fallbacks=[0 if s.plugin is None else s.plugin.fallbacks for s in steps],
        controller_fallbacks=[0 if s.controller is None else s.controller.fallbacks for s in steps],
    )


def _accel_w(step: AgentStep, res: StepResult, R: FloatArray) -> FloatArray:
    """The acceleration [m/s^2, world] command ``res`` asks of the agent's nominal airframe,
    ``F / m - g e3`` (at the rotor level ``F = (B f)_0 R e3`` with the drone's attitude ``R``)."""
    p = step.model.params
    F = res.u if res.level is CommandLevel.ATTITUDE else (step.model.B[0] @ res.u) * R[:, 2]
    return F / p.mass_kg - p.g_mps2 * E3


@dataclass(frozen=True)
class SwarmOutcome:
    """How a :func:`fly_scenario` run went, by the runtime's metric definitions."""

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
