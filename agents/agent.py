"""The agent process: one quadrotor's reference controller and C3BF-QP safety filter.

    swarm agent CONFIG --id ID [--run RUN] [--port P]

An event loop over one inbox (the world's clock, which carries this agent's measurement
and the obstacles; each neighbour's state; a real drone's motion-capture measurement):
nothing polls. On each measurement it builds one row per obstacle and per neighbour in
range, filters the reference command, and publishes this agent's state (unless the
neighbours come from the world's roster) and then its command with the filter's report.
In lockstep it first waits (with a deadline) for every live neighbour's state of tick
k-1 and uses exactly those, so two runs of one config compute the same commands; in
realtime it uses the newest of everything.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import replace
from typing import Any

import numpy as np

from swarm.agents.crazyflie import CrazyflieLink, FlightPlan, Phase
from swarm.config import ScenarioConfig, TimeMode
from swarm.control import YAW_GAIN_PER_S, AttitudeController, PathTracker, reference_thrust, setpoint_vector
from swarm.errors import DecodeError
from swarm.model import CommandLevel, QuadModel, QuadState, body_centre
from swarm.net import statewire
from swarm.net import transport as tp
from swarm.net.cells import Interest, cell_of
from swarm.net.messages import Message, clock_measurement, encode, warm_up
from swarm.net.neighbours import NeighbourTable, roster_arrays
from swarm.offline.scenario import items_to_arrays
from swarm.planning import StaticObstacles, corner_cut_m, filter_config_for, follows, path_for
from swarm.rotation import FloatArray
from swarm.safety.filter import FilterStatus, SafetyFilter
from swarm.safety.obstacles import ObstacleArrays
from swarm.shutdown import StopFlag


def _keep_newest(by_tick: dict, n: int) -> None:
    """Drop the oldest entries of a dict keyed by tick until ``n`` remain (clocks arrive in
    tick order over one TCP link, so the first inserted is the oldest)."""
    while len(by_tick) > n:
        del by_tick[next(iter(by_tick))]


class Agent:
    """One agent's state between ticks; :meth:`tick` is the control step."""

    def __init__(self, cfg: ScenarioConfig, agent_id: str) -> None:
        self.cfg, self.id = cfg, agent_id
        me = self.me = cfg.agent(agent_id)
        self.model = QuadModel(me.quad_params())
        self.level = me.command_level
        still = StaticObstacles.of(list(cfg.obstacles))
        # the path around the static obstacles (swarm.planning), replanned when it stalls
        path_w, self.route = path_for(me, still)
        fc = filter_config_for(me, still, self.level, self.route)
        self.filt = SafetyFilter(self.model, fc)
        # a real drone lands through its floor: landing filters with the floor off
        self.filt_land = SafetyFilter(self.model, replace(fc, floor_z_m=None)) if me.backend == "crazyflie" else None
        self.tracker = PathTracker(path_w, me.speed_mps, cut_m=corner_cut_m(self.route))
        self.att = AttitudeController(self.model)
        f = cfg.failure
        self.table = NeighbourTable(f.neighbour_timeout_s, f.neighbour_growth_mps, f.neighbour_hard_limit_s, f.on_lost)
        self.table.limits = statewire.Plausible.of(cfg)  # what a neighbour's state may say
        self.goal = np.asarray(me.final_goal)
        self.others = {a.id for a in cfg.agents} - {agent_id}
        self.obstacles = ObstacleArrays.empty()
        self.from_world = cfg.neighbours.source == "world"
        # neighbours by cells (swarm.net.cells): the world's own tick message for a simulated
        # drone (its measurement, the obstacles and the neighbours near it), cell subscriptions
        self.cells = cfg.uses_cells
        self.bundled = cfg.uses_bundles  # the router's bundle of the states near it, once per tick
        self.by_near = cfg.uses_ticks  # lockstep ticks use the neighbours the world names near this agent
        self.ticked = self.by_near and me.backend != "crazyflie"  # measured by tick messages, not the clock
        self.interest = Interest(cfg.interest_radius_m(agent_id), cfg.cell_m, cfg.neighbours.hysteresis_m)
        self.near: dict[int, list[str]] = {}  # tick -> the neighbours the world names near this agent
        self.missed = 0  # near neighbours whose state was not there when used (lockstep: at the deadline)
        self.roster: dict[int, tuple[float, ObstacleArrays]] = {}  # tick -> (t, rows), world source
        self.roster_ids: list[str] = []
        self._roster_key: tuple[str, ...] = ()  # the clock's ids the roster rows were indexed for
        self._roster_rows = np.zeros(0, dtype=np.intp)  # indices of the other drones in the clock's ids
        self._roster_shares = np.zeros(0, dtype=bool)  # each roster drone does its share (a neighbour row)
        self.obstacle_ids: list[str] = []
        self.clock_live: dict[int, list[str]] = {}  # tick -> agents the world expects answers from
        self._newest_k = -1  # newest tick whose clock arrived
        self.infeasible = 0
        self.min_h = math.inf
        self.reached = False
        self.solo = not me.filter.enabled  # this agent is not doing its share of a pair's avoidance now
        self.plan: FlightPlan | None = None  # a real drone's phases (set after the warm-up)
        # The first tick loads numba's compiled code and pays every other first-call cost
        # (about a second): run one now, before the world can see this agent, so that no
        # real tick pays for it.
        hover = {"x": np.asarray(me.start, float), "v": np.zeros(3), "q": np.array([0, 0, 0, 1.0]), "w": np.zeros(3)}
        self.tick(Message("measurement", "", "warm-up", 0, 0.0, 0, hover), lockstep=False)
        encode(
            "command",
            "",
            agent_id,
            0,
            0.0,
            0,
            level=self.level.value,
            u=np.zeros(4),
            intervention=0.0,
            dropped=0,
            **self._report("ok"),
        )
        warm_up()
        roster_arrays(np.zeros(7), np.zeros(1, dtype=np.intp), np.ones(1, dtype=bool))
        if self.bundled:
            self._warm_up_bundles()
        self._warm_up_filter_paths()
        self.infeasible, self.min_h, self.reached = 0, math.inf, False
        self.plan = FlightPlan(me) if me.backend == "crazyflie" else None  # a real drone's phases

    def _warm_up_bundles(self) -> None:
        """Read a bundle of two states into a throwaway table and build its rows (by tick,
        and by the names the world gives): their compiled checks and kernels load now. (Two:
        the fields of one record are contiguous arrays, a type of their own to numba.)"""
        z, names = np.zeros(3), ["warm-up-1", "warm-up-2"]
        records = [statewire.encode_state("", n, 0, 0.0, 0, z, z, 0.1) for n in names]
        b = statewire.read_bundle(statewire.encode_bundle("", self.me.id, 0, 0.0, 0, records), "")
        table = NeighbourTable(self.table.timeout_s, self.table.growth_mps, self.table.hard_limit_s, self.table.on_lost)
        table.update_records(b.states.records, set(names), tp.Counter())
        table.arrays(0.0, 0, names)
        table.arrays(0.0)
        table.state(names[0])

    def _warm_up_filter_paths(self) -> None:
        """Load every compiled path of the filter now (the QP with active rows, the
        least-violation QP, the landing filter): a first use mid-flight stalls that tick
        for up to a second on a busy machine, long enough to look like a lost drone."""
        state = QuadState.hover([0.0, 0.0, 1.0])
        state.v_w = np.array([2.0, 0.0, 0.0])  # m/s, straight at the obstacles below
        u_hover = self.att.from_thrust_vector(state, np.array([0.0, 0.0, self.model.params.weight_N]))
        u = u_hover if self.level is CommandLevel.ROTORS else np.array([0.0, 0.0, self.model.params.weight_N])
        ahead = ObstacleArrays.build([[1.5, 0.0, 1.0]], [0.2])  # active: the QP
        wall = ObstacleArrays.build([[0.4, 0.0, 1.0], [0.4, 0.3, 1.0], [0.4, -0.3, 1.0]], [0.25, 0.25, 0.25])
        for filt in (self.filt, self.filt_land):
            if filt is not None:
                for obstacles in (ahead, wall):  # the wall at 2 m/s is infeasible: the slack QP
                    filt.filter(state, u, obstacles)

    def _report(
        self, status: str, solve_us: float = 0.0, row_ids: list[str] | None = None, h_rows: np.ndarray | None = None
    ) -> dict:
        """The filter's report of this tick, sent with the command."""
        return dict(
            status=status,
            solve_us=solve_us,
            row_ids=row_ids or [],
            h_rows=np.zeros(0) if h_rows is None else h_rows,
            min_h=self.min_h if math.isfinite(self.min_h) else 1e9,
            infeasible=self.infeasible,
            goal_reached=self.reached,
        )

    def _motors_off(self, x_b: np.ndarray, v_b: np.ndarray) -> tuple[dict, dict]:
        off = dict(level=self.level.value, u=np.zeros(4), intervention=0.0, **self._report("ok"))
        return self._state_body(x_b, v_b), off

    def _state_body(self, x_b: np.ndarray, v_b: np.ndarray) -> dict:
        """This agent's state message body: body centre [m], its velocity [m/s], world,
        the bounding radius [m], and whether it is not doing its share now (``solo``)."""
        return dict(x=x_b, v=v_b, r=self.model.params.body_radius_m, solo=self.solo)

    def neighbour_ids(self, neighbours: ObstacleArrays) -> list[str]:
        """Names of the neighbour rows, in the order the neighbour sources build them."""
        if self.from_world:
            return self.roster_ids[: len(neighbours)]  # (the roster rows are the other drones)
        return self.table.row_names[: len(neighbours)]

    def on_clock(self, m: Message) -> list[str]:
        """Tick k's live agents and obstacles, and (world source) the roster. Returns the
        neighbours the world's live list lost since the newest clock before (in a star
        topology agents hear no liveliness but the hubs': this is how they learn a
        neighbour is gone)."""
        before = self.clock_live.get(self._newest_k) if m.k > self._newest_k else None
        left = [] if before is None or m["live"] == before else [n for n in before if n not in m["live"]]
        self.clock_live[m.k] = m["live"]
        if m.k >= self._newest_k:
            self._newest_k = m.k
            self.obstacles = items_to_arrays(m["items"])
            self.obstacle_ids = [i["id"] for i in m["items"]]
        if self.from_world:
            # the world's roster: every other drone's body centre, velocity and radius at tick k
            ids = tuple(m["ids"])
            if ids != self._roster_key:  # the roster's drones changed (rarely): index them again
                self._roster_key = ids
                self._roster_rows = np.array([i for i, name in enumerate(ids) if name in self.others], dtype=np.intp)
                self.roster_ids = [ids[i] for i in self._roster_rows.tolist()]
                self._roster_shares = np.ones(len(self._roster_rows), dtype=bool)
            shares = self._roster_shares
            if m["solo"]:  # drones not doing their share: this agent takes all of each of those pairs
                shares = np.array([name not in m["solo"] for name in self.roster_ids], dtype=bool)
            self.roster[m.k] = (m.t, roster_arrays(m["xvr"], self._roster_rows, shares))
            _keep_newest(self.roster, 5)
        _keep_newest(self.clock_live, 5)
        return [n for n in left if n in self.others]

    def on_tick(self, m: Message) -> tuple[Message | None, list[str]]:
        """This agent's own tick message (neighbours by bundles or cells): keep the
        obstacles and the near neighbours of tick k, and mark gone the neighbours the world
        has seen go (in a star no agent hears another's liveliness). Returns its measurement
        (None once the run is over) and the neighbours newly marked gone."""
        self.near[m.k] = m["near"]
        left = [n for n in m["gone"] if n in self.others and n not in self.table.gone]
        for name in left:
            self.table.mark_gone(name)
        _keep_newest(self.near, 5)
        if m.k >= self._newest_k:
            self._newest_k = m.k
            self.obstacles = items_to_arrays(m["items"])
            self.obstacle_ids = [i["id"] for i in m["items"]]
        if m["done"]:
            return None, left
        return Message("measurement", m.run, m.src, m.seq, m.t, m.k, {f: m[f] for f in ("x", "v", "q", "w")}), left

    def roster_rows(self, t: float, k: int | None) -> ObstacleArrays:
        """Neighbour rows from the newest roster of tick <= k, extrapolated to ``t`` [s]."""
        if k is None:  # the newest (inserted last: clocks come in tick order)
            if not self.roster:
                return ObstacleArrays.empty()
            t_r, arr = self.roster[next(reversed(self.roster))]
        else:
            ks = [kk for kk in self.roster if kk <= k]
            if not ks:
                return ObstacleArrays.empty()
            t_r, arr = self.roster[max(ks)]
        return arr.at(t - t_r)  # the roster's drones at constant velocity (it gives no acceleration)

    def missing(self, k: int) -> int:
        """Lockstep: how many messages tick k still waits for: its clock, then (agents
        source) each live neighbour's state of tick k-1."""
        live = self.near.get(k) if self.ticked else self.clock_live.get(k)
        if live is None:
            return 1
        if self.from_world or k == 0:
            return 0  # the clock of tick k carried every neighbour's tick-k state
        table = self.table
        return sum(1 for n in live if n in self.others and n not in table.gone and table.waits_for(n, k - 1))

    def _neighbour_rows(self, t: float, k: int, x_b: np.ndarray, lockstep: bool) -> ObstacleArrays:
        """Rows of the other agents at ``t`` [s]: the world's roster, or their states
        (lockstep: of tick k-1, and with cells those of the neighbours the world named)."""
        if self.from_world:
            return self.roster_rows(t, k if lockstep else None)
        if not self.by_near:
            return self.table.arrays(t, k - 1 if lockstep else None)
        near = self.near.get(k, [])
        if lockstep:
            return self.table.arrays(t, k - 1, sorted(near))
        self.table.forget_far(x_b, self.interest.radius_m + self.interest.hysteresis_m, t)
        if t > self.table.timeout_s:  # (before that, no neighbour can have been heard for long)
            timeout_s = self.table.timeout_s
            self.missed += sum(1 for n in near if (s := self.table.state(n)) is None or t - s.t_s > timeout_s)
        return self.table.arrays(t)

    def _route(self, t_s: float, state: QuadState, neighbours: ObstacleArrays) -> FloatArray | None:
        """The route at this tick (swarm.planning.Route): a new path from where the agent is
        if it has made no progress along its own for a while; then the velocity it holds in
        place of its path to give way at a narrow passage to the neighbours it hears, or to
        brake before it turns away from a wall, or None."""
        if self.route is None:
            return None
        remaining = self.tracker.reference(state.x_w)[2]
        new = self.route.update(t_s, state.x_w, self.goal, remaining)
        if new is not None:
            self.tracker = PathTracker(new.waypoints_w, self.me.speed_mps, cut_m=self.route.cut_m)
            remaining = self.tracker.reference(state.x_w)[2]
        v_path = self.tracker.command(state.x_w)[0]
        return self.route.hold(t_s, remaining, state.x_w, neighbours.c_w, neighbours.c_dot_w, state.v_w, v_path)

    def ready(self, k: int) -> bool:
        """Lockstep: has everything of tick k arrived (clock, neighbours k-1)?"""
        return self.missing(k) == 0

    def tick(self, msg: Message, lockstep: bool) -> tuple[dict, dict]:
        """One control step on a measurement: (state message body, command message body)."""
        me, model, level = self.me, self.model, self.level
        k, t = msg.k, msg.t
        state = QuadState(msg["x"], msg["v"], msg["q"], msg["w"])
        x_b, v_b, yaw = body_centre(state.x_w, state.v_w, state.q, state.Omega_b, model.params.l_m)
        neighbours = self._neighbour_rows(t, k, x_b, lockstep)
        tracker: PathTracker | None = self.tracker
        filt = self.filt
        if self.plan is not None:
            tracker = self.plan.tracker(state.x_w)
            if self.plan.phase is Phase.LAND and self.filt_land is not None:
                filt = self.filt_land
        if tracker is None:  # a real drone that has landed or been stopped: motors off
            return self._motors_off(x_b, v_b)
        held = None
        if tracker is self.tracker:  # the mission's path (not a real drone's take-off or landing)
            held = self._route(t, state, neighbours)  # gives way at a narrow passage
            tracker = self.tracker  # (replanned)
        if held is not None:
            F_ref = tracker.thrust_vector(model, state.x_w, state.v_w, held)  # hover, or back out of the passage
        else:
            others_v = neighbours.c_dot_w if follows(self.route) else None  # a lane's queue is followed
            F_ref = reference_thrust(
                model, tracker, state.x_w, state.v_w, x_b, neighbours.c_w, me.tiebreak.pair, others_v
            )
        u_ref = self.att.from_thrust_vector(state, F_ref, me.yaw_rad) if level is CommandLevel.ROTORS else F_ref
        rows = ObstacleArrays.concat([self.obstacles, neighbours]) if len(self.obstacles) else neighbours
        row_ids: list[str] = []
        h_rows = np.zeros(0)
        if me.filter.enabled:
            res = filt.filter(state, u_ref, rows)
            names = self.obstacle_ids + self.neighbour_ids(neighbours)
            row_ids = [names[i] for i in res.row_index.tolist()]
            h_rows = res.h
            u, status = res.u, res.status
            if status is not FilterStatus.OK:
                self.infeasible += 1
            self.solo = status is not FilterStatus.OK
            self.min_h = min(self.min_h, res.min_cone_h)
            intervention, solve_us = res.intervention, res.solve_time_s * 1e6
        else:
            u, status, intervention, solve_us = u_ref, FilterStatus.OK, 0.0, 0.0
        if not self.reached:
            self.reached = math.dist(state.x_w.tolist(), self.goal.tolist()) <= self.cfg.goal_tolerance_m
        report = self._report(status.value, solve_us, row_ids, h_rows)
        if level is CommandLevel.ATTITUDE:
            cmd = setpoint_vector(u, yaw, me.yaw_rad, YAW_GAIN_PER_S)
        else:
            cmd = u
        return self._state_body(x_b, v_b), dict(level=level.value, u=cmd, intervention=intervention, **report)


def follow_cells(interest: Interest, subs: tp.Channels, keys: tp.Keys, x_b_w: np.ndarray) -> None:
    """Subscribe to the cells near the body centre ``x_b_w`` [m, world] and drop the ones
    left behind (``swarm.net.cells.Interest``: nothing while within the hysteresis)."""
    add, drop = interest.update(x_b_w.tolist())
    for c in sorted(add):
        subs.add(keys.cell(c))
    for c in drop:
        subs.remove(keys.cell(c))


class RealDrone:
    """The supervisor of a real Crazyflie, apart from the control step: its radio link
    (``swarm.agents.crazyflie.CrazyflieLink``), its flight phases, and the rules that stop it
    (link lost, body lost to motion capture, geofence, filter fault, the run's end)."""

    def __init__(self, agent_id: str, plan: FlightPlan, link: CrazyflieLink, mocap_timeout_s: float) -> None:
        self.id, self.plan, self.link, self.mocap_timeout_s = agent_id, plan, link, mocap_timeout_s
        self.flying = False  # it has been sent a setpoint
        self.last_meas = time.monotonic()  # arrival of its last measurement
        self.last_tick_end = 0.0  # our own tick can stall; the silence of the stream counts from its end

    def safety_stop(self, reason: str) -> None:
        if not self.link.stopped:
            self.link.emergency_stop(reason)
            self.plan.phase = Phase.STOPPED

    def measured(self) -> None:
        self.last_meas = time.monotonic()  # arrival time: a slow tick of ours is not a lost body

    def run_over(self) -> bool:
        """The world says the run is over: a flying drone lands on its measurements (True:
        the agent stops now)."""
        if self.flying and self.plan.phase in (Phase.TAKEOFF, Phase.MISSION):
            self.plan.land()
        return not self.flying

    def keeps_going(self) -> bool:
        """Between ticks: False once the link is lost, the body has not been measured for
        the motion-capture timeout (it is then stopped), or the drone has landed or stopped."""
        if self.link.lost.is_set():
            print(
                f"agent {self.id}: Crazyflie link lost ({self.link.lost_reason}); the guard stopped it", file=sys.stderr
            )
            self.link.stopped = True
            return False
        silent_s = time.monotonic() - max(self.last_meas, self.last_tick_end)  # while we listened
        if self.flying and not self.link.stopped and silent_s > self.mocap_timeout_s:
            self.safety_stop(f"no motion-capture measurement for {silent_s:.2f} s (body lost)")
            return False
        return self.plan.phase not in (Phase.LANDED, Phase.STOPPED)

    def inside_geofence(self, x_w: np.ndarray) -> bool:
        if self.plan.outside_geofence(x_w):
            self.safety_stop(f"outside the geofence at {np.round(x_w, 3).tolist()}")
            return False
        return True

    def fly(self, msg: Message, cmd_body: dict) -> bool:
        """Send the tick's command to the drone (False: a filter fault stopped it)."""
        if cmd_body["status"] == FilterStatus.FAILED.value:
            self.safety_stop("filter fault (no usable command)")
            return False
        if self.plan.phase is Phase.LANDED:
            self.link.motors_off()
            print(f"agent {self.id}: landed, motors off", file=sys.stderr)
        else:
            self.link.pose(msg["x"], msg["q"])
            self.link.setpoint(*map(float, cmd_body["u"]))
            self.flying = True
        self.last_tick_end = time.monotonic()
        return True

    def close(self, stopped_by_signal: bool) -> None:
        if stopped_by_signal and self.flying and self.plan.phase is not Phase.LANDED:
            self.safety_stop("stopped by a signal (Ctrl-C or the launcher) while flying")
        self.link.close()


class AgentProcess:
    """The agent process: wires one :class:`Agent` to its Zenoh session (and a real drone
    to its :class:`RealDrone` supervisor). Phases: :meth:`listen` (what arrived),
    :meth:`next_message` (the tick to act on), :meth:`act` and :meth:`publish`."""

    def __init__(self, cfg: ScenarioConfig, agent_id: str, run: str, conf: Any) -> None:
        self.agent = agent = Agent(cfg, agent_id)
        self.cfg, self.id, self.run_id, self.keys = cfg, agent_id, run, tp.Keys(run)
        self.lockstep = cfg.time.mode is TimeMode.LOCKSTEP
        self.stop = StopFlag()
        keys = self.keys
        self.session = session = tp.open_session(conf)
        self.counter = tp.Counter()
        self.meas_key, self.tick_key = keys.measurement(agent_id), keys.tick(agent_id)
        if agent.bundled:
            neighbour_keys = [keys.bundle(agent_id)]
        else:
            neighbour_keys = [] if agent.from_world or agent.cells else [keys.state(n) for n in sorted(agent.others)]
        self.bundle_key = keys.bundle(agent_id)
        self.real = agent.plan is not None  # measured by motion capture on its own key, not in the clock
        self.inbox = tp.Inbox(
            session,
            [self.tick_key if agent.ticked else keys.clock, *neighbour_keys, *([self.meas_key] if self.real else [])],
        )
        self.live_sub = tp.liveliness_subscriber(session, keys.all_alive)
        # with neighbours from the world's roster nobody needs this agent's own state message
        self.pub_state = None if agent.from_world or agent.cells else session.declare_publisher(keys.state(agent_id))
        self.cell_pubs: dict[tuple[int, int, int], Any] = {}  # cell -> publisher of this agent's state there
        self.cell_subs = tp.Channels(session)  # the neighbours' states, drained when the tick has woken us
        if agent.cells:  # listen to the cells near the start before anyone can see this agent
            start_b = body_centre(
                np.asarray(agent.me.start, float),
                np.zeros(3),
                np.array([0, 0, 0, 1.0]),
                np.zeros(3),
                agent.model.params.l_m,
            )[0]
            follow_cells(agent.interest, self.cell_subs, keys, start_b)
        self.pub_cmd = session.declare_publisher(keys.command(agent_id))
        self.token = tp.declare_liveliness(session, keys.alive(agent_id))
        self.startup_cpu_s = time.process_time()
        self.drone: RealDrone | None = None
        self.alive: set[str] = set()
        self.world_seen = False
        self.world_deadline = time.monotonic() + cfg.time.start_timeout_s  # the world must show up by then
        self.pending: list[Message] = []  # measurements not yet acted on
        self.seq = 0
        self.tick_s: list[float] = []  # wall time from measurement taken up to command sent
        self.waited_s = 0.0  # lockstep: wall time spent waiting for neighbours / clock
        self.msg_seen: dict[int, float] = {}  # lockstep: wall time each tick's measurement arrived
        self.reported_gone: set[str] = set()
        self.acted_k = -1  # lockstep: the newest tick acted on
        self.bundle_k = -1  # the newest tick whose bundle arrived

    def connect_drone(self) -> bool:
        """A real drone: its link up (False: not reached in 15 s)."""
        settings = self.cfg.agent(self.id).crazyflie
        if self.agent.plan is None or settings is None:
            return True
        link = CrazyflieLink(settings, self.id)
        if not link.wait_ready(15.0):
            print(f"agent {self.id}: Crazyflie at {settings.uri} not reached: {link.lost_reason}", file=sys.stderr)
            return False
        self.drone = RealDrone(self.id, self.agent.plan, link, settings.mocap_timeout_s)
        return True

    def safety_stop(self, reason: str) -> None:
        if self.drone is not None:
            self.drone.safety_stop(reason)

    def neighbour_gone(self, name: str, how: str) -> None:
        if name not in self.reported_gone:
            self.reported_gone.add(name)
            print(f"agent {self.id}: neighbour {name} gone ({how}) at wall {time.time():.4f}", file=sys.stderr)

    def _state_key(self, m: Message) -> str:
        """The key a neighbour's state ``m`` must come on."""
        agent, keys = self.agent, self.keys
        return keys.cell_state(cell_of(m["x"], agent.interest.cell_m), m.src) if agent.cells else keys.state(m.src)

    def _measurement(self, m: Message) -> None:
        self.pending.append(m)
        self.msg_seen.setdefault(m.k, time.monotonic())
        self.agent.table.at(m.t)  # how far the run is: no neighbour's state is much newer

    def handle(self, sample: Any) -> None:
        """One sample: a measurement, a neighbour's state or their bundle, this agent's tick
        or the clock."""
        agent, key = self.agent, str(sample.key_expr)
        if key == self.bundle_key:
            self._bundle(tp.payload(sample))
            return
        m = tp.decode_sample(sample, self.run_id, self.counter)
        if m is None:
            return
        if key == self.meas_key and m.kind == "measurement":
            self._measurement(m)
            if self.drone is not None:
                self.drone.measured()
        elif m.kind == "state" and m.src == self.id and agent.cells:
            pass  # its own state, heard in its own cell
        elif m.kind == "state" and m.src in agent.others and key == self._state_key(m):
            agent.table.update(m.src, m.t, m.k, m["x"], m["v"], m["r"], m["solo"])
        elif m.kind == "tick" and key == self.tick_key:
            mine, left = agent.on_tick(m)
            for name in left:
                self.neighbour_gone(name, "the world's live list")
            if mine is not None:
                self._measurement(mine)
            else:
                self.stop.set()
        elif m.kind == "clock" and key == self.keys.clock:
            self._on_clock(m)
        else:
            self.counter.drop(f"unexpected {m.kind} on {key}")

    def _bundle(self, data: bytes) -> None:
        """The router's bundle of the states near this agent: checked as one array, each
        bad record (or one from an agent it does not know, or from itself) dropped and
        counted."""
        counter = self.counter
        counter.rx_bytes += len(data)
        counter.rx_messages += 1
        try:
            b = statewire.read_bundle(data, self.run_id)
        except DecodeError as exc:
            counter.drop(str(exc))
            return
        if b.dst != self.id:
            counter.drop("bundle: for another agent")
            return
        self.bundle_k = max(self.bundle_k, b.k)
        for reason, n in b.states.dropped.items():
            counter.dropped += n
            counter.reasons[reason] = counter.reasons.get(reason, 0) + n
        self.agent.table.update_records(b.states.records, self.agent.others, counter)

    def _on_clock(self, m: Message) -> None:
        for name in self.agent.on_clock(m):
            self.neighbour_gone(name, "the world's live list")
        mine = None if self.real or m["done"] else clock_measurement(m, self.id)
        if mine is not None:
            self._measurement(mine)
        if m["done"] and (self.drone is None or self.drone.run_over()):
            self.stop.set()

    def listen(self, wake_s: float) -> bool:
        """Wait for what the oldest pending tick still needs (or ``wake_s``), take what
        arrived and the liveliness changes; False once the world is gone."""
        agent, pending = self.agent, self.pending
        # wake when what the oldest pending tick still needs can all be here (one wake for a
        # neighbour mesh's states, not one per state), or after wake_s
        need = max(1, agent.missing(min(m.k for m in pending))) if self.lockstep and pending else 1
        if agent.bundled:  # one bundle brings every neighbour's state
            self.inbox.wait_for(self._bundled_need(), time.monotonic() + wake_s)
        elif agent.cells and pending:  # the tick is here, states are still coming: look again in 1 ms
            self.inbox.wait_for(1, time.monotonic() + 0.001)
        else:
            self.inbox.wait_for(need, time.monotonic() + wake_s)
        for s in self.inbox.drain():
            self.handle(s)
        for s in self.cell_subs.drain():
            self.handle(s)
        for name, up in tp.liveliness_events(self.live_sub):
            if up:
                self.alive.add(name)
                self.world_seen |= name == "world"
            else:
                self.alive.discard(name)
                if name in agent.others:
                    if not agent.from_world:  # the world keeps measuring a dead agent's body
                        agent.table.mark_gone(name)
                    self.neighbour_gone(name, "liveliness")
        if not self.world_seen and time.monotonic() > self.world_deadline:  # its launcher died before the world
            print(f"agent {self.id}: no world within time.start_timeout_s, stopping", file=sys.stderr)
            return False
        if self.world_seen and "world" not in self.alive:
            print(f"agent {self.id}: the world is gone, stopping", file=sys.stderr)
            if self.drone is not None and self.drone.flying:
                self.drone.safety_stop("the world's liveliness is gone")
            return False
        return True

    def _bundled_need(self) -> int:
        """How many messages to wake for with bundles: in lockstep, the next tick and the
        bundle of the tick before (the router sends each agent one bundle per tick, so the
        two wake it once); in realtime, whichever comes (it acts on the newest)."""
        if not self.lockstep or self.pending:
            return 1
        k_next = self.acted_k + 1
        return 1 if k_next == 0 or self.bundle_k >= k_next - 1 else 2

    def next_message(self) -> Message | None:
        """The measurement to act on now: lockstep, the oldest once its tick is complete
        (or at the deadline); realtime, the newest."""
        pending, agent = self.pending, self.agent
        if not pending:
            return None
        if not self.lockstep:
            msg = max(pending, key=lambda m: m.k)  # realtime: only the newest matters
            pending.clear()
            return msg
        msg = min(pending, key=lambda m: m.k)
        if not agent.ready(msg.k):
            if time.monotonic() - self.msg_seen[msg.k] < self.cfg.time.lockstep_timeout_s:
                return None  # wait for the rest of tick k (the inbox wakes us)
            agent.missed += agent.missing(msg.k) if agent.ticked and msg.k in agent.near else 0
            self.counter.drop("lockstep: tick incomplete at the deadline")
        pending.remove(msg)
        self.acted_k = max(self.acted_k, msg.k)
        self.waited_s += time.monotonic() - self.msg_seen.pop(msg.k, time.monotonic())
        return msg

    def act(self, msg: Message) -> tuple[dict, dict] | None:
        """The control step on ``msg``, flown by a real drone; None when a rule stopped it."""
        drone = self.drone
        if drone is not None and not drone.inside_geofence(msg["x"]):
            return None
        try:
            state_body, cmd_body = self.agent.tick(msg, self.lockstep)
        except Exception:
            self.safety_stop("the control step raised")
            raise
        if drone is not None and not drone.fly(msg, cmd_body):
            return None
        return state_body, cmd_body

    def publish(self, msg: Message, state_body: dict, cmd_body: dict) -> None:
        """This agent's state (by cell, or on its own key) and then its command."""
        agent, keys, run = self.agent, self.keys, self.run_id
        if agent.cells:
            self.seq += 1
            cell = cell_of(state_body["x"], agent.interest.cell_m)
            pub = self.cell_pubs.get(cell)
            if pub is None:
                pub = self.cell_pubs[cell] = self.session.declare_publisher(keys.cell_state(cell, self.id))
            pub.put(encode("state", run, self.id, self.seq, msg.t, msg.k, **state_body))
            follow_cells(agent.interest, self.cell_subs, keys, state_body["x"])
        elif self.pub_state is not None:
            self.seq += 1
            self.pub_state.put(encode("state", run, self.id, self.seq, msg.t, msg.k, **state_body))
        self.seq += 1
        self.pub_cmd.put(
            encode("command", run, self.id, self.seq, msg.t, msg.k, dropped=self.counter.dropped, **cmd_body)
        )

    def loop(self) -> None:
        wake_s = 0.02 if self.drone is not None else 0.1
        while not self.stop:
            if not self.listen(wake_s):
                break
            if self.drone is not None and not self.drone.keeps_going():
                break
            msg = self.next_message()
            if msg is None:
                continue
            t0 = time.perf_counter()
            bodies = self.act(msg)
            if bodies is None:
                break
            self.publish(msg, *bodies)
            self.tick_s.append(time.perf_counter() - t0)

    def summary(self) -> dict[str, Any]:
        ts = np.array(self.tick_s or [0.0]) * 1e3
        agent, counter = self.agent, self.counter
        return {
            "id": self.id,
            "ticks": len(self.tick_s),
            "compute_median_ms": float(np.median(ts)),
            "compute_p99_ms": float(np.percentile(ts, 99)),
            "waited_s": self.waited_s,
            "cpu_s": time.process_time(),
            "startup_cpu_s": self.startup_cpu_s,
            "dropped": counter.dropped,
            "rx_bytes": counter.rx_bytes,
            "rx_messages": counter.rx_messages,
            "missed_neighbours": agent.missed,
            "cells_declared": agent.interest.declared,
            "rejected": tp.rejected(agent.table.rejected, counter.by_sender),  # per sender and reason
        }

    def run(self) -> int:
        """Connect a real drone, fly until the run ends or a rule stops it, report; 2 when
        the drone was not reached."""
        if not self.connect_drone():
            self.token.undeclare()
            return 2
        try:
            self.loop()
        finally:
            if self.drone is not None:
                self.drone.close(stopped_by_signal=bool(self.stop))
            self.token.undeclare()
        print("AGENT_SUMMARY " + json.dumps(self.summary()), file=sys.stderr)
        if self.counter.dropped:
            print(f"agent {self.id}: dropped {self.counter.dropped} messages {self.counter.reasons}", file=sys.stderr)
        return 0


def main(cfg: ScenarioConfig, agent_id: str, run: str, conf: Any) -> int:
    """The agent process: ``swarm agent``."""
    return AgentProcess(cfg, agent_id, run, conf).run()
