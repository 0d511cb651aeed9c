"""The agent process: one quadrotor's control step (``swarm.step``) wired to Zenoh.

    swarm agent CONFIG --id ID [--run RUN] [--port P]

An event loop over one inbox (the world's clock or this agent's own tick, which carry its
measurement and the obstacles; its neighbours' traffic, as its neighbour source takes it
(``swarm.net.sources``); a real drone's motion-capture measurement): nothing polls. On each
measurement it takes its neighbours' rows from the source, runs the control step, and
publishes its state (unless the neighbours come from the world's roster) and then its
command with the filter's report. In lockstep it first waits (with a deadline) for every
live neighbour's state of tick k-1 and uses exactly those, so two runs of one config compute
the same commands; in realtime it uses the newest of everything.
"""

from __future__ import annotations

import json
import math
import sys
import time
from typing import Any

import numpy as np

from swarm.agents.crazyflie import CrazyflieLink, FlightPlan, Phase
from swarm.agents.orders import OrderInbox
from swarm.build import agent_neighbour_table, agent_step
from swarm.config import ScenarioConfig, TimeMode
from swarm.geometry import items_to_arrays
from swarm.ledger import timing_sketch
from swarm.model import QuadState, body_centre
from swarm.net import transport as tp
from swarm.net.access import LAUNCHER
from swarm.net.messages import (
    CommandBody,
    Message,
    StateBody,
    clock_measurement,
    encode_command,
    encode_state,
    frames_of,
    warm_up,
)
from swarm.net.neighbours import roster_arrays
from swarm.net.sources import NeighbourSource, pick
from swarm.planning import StaticObstacles
from swarm.ros2.goals import GoalInbox, course, landing_goal
from swarm.rotation import FloatArray
from swarm.safety.filter import FilterStatus
from swarm.safety.monitor import BREACH_NAMES, Action
from swarm.safety.obstacles import NamedObstacles
from swarm.shutdown import StopFlag
from swarm.step import AgentStep, StepResult

HELD_TICKS = 5
"""Ticks of the clock's live lists kept (lockstep may act on tick k while later ones came)."""


def command_body(result: StepResult) -> CommandBody:
    """The command message body of a step's result, with the agent's running tallies."""
    return CommandBody(
        result.level.value,
        result.command,
        result.status.value,
        result.intervention,
        result.solve_us,
        tuple(result.row_ids),
        result.h_rows,
        result.min_h if math.isfinite(result.min_h) else 1e9,
        result.infeasible_ticks,
        result.arrived,
        result.est,
        int(result.verdict.action),
        int(result.verdict.breaches),
        result.live_margin_m,
        result.fallback,
        result.fallbacks,
        result.controller_fallback,
        result.controller_fallbacks,
    )


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

    def fly(self, msg: Message, result: StepResult) -> bool:
        """Send the tick's command to the drone (False: a filter fault stopped it)."""
        if result.status is FilterStatus.FAILED:
            self.safety_stop("filter fault (no usable command)")
            return False
        if self.plan.phase is Phase.LANDED:
            self.link.motors_off()
            print(f"agent {self.id}: landed, motors off", file=sys.stderr)
        else:
            self.link.pose(msg["x"], msg["q"])
            self.link.setpoint(*map(float, result.command))
            self.flying = True
        self.last_tick_end = time.monotonic()
        return True

    def close(self, stopped_by_signal: bool) -> None:
        if stopped_by_signal and self.flying and self.plan.phase is not Phase.LANDED:
            self.safety_stop("stopped by a signal (Ctrl-C or the launcher) while flying")
        self.link.close()


def _warm_up(step: AgentStep, source: NeighbourSource, agent_id: str, start_w: FloatArray) -> None:
    """The first tick loads numba's compiled code and pays every other first-call cost
    (about a second): pay it now, before the world can see this agent, so that no real
    tick does."""
    step.warm_up(start_w)
    encode_command("", agent_id, 0, 0.0, 0, CommandBody.zero(step.level.value))
    warm_up()
    roster_arrays(np.zeros(7), np.zeros(1, dtype=np.intp), np.ones(1, dtype=bool))
    source.warm_up()


def warm_kernels(cfg: ScenarioConfig) -> None:
    """An agent's warm-up for the first simulated agent of ``cfg``, in this process and with
    no session: the fork server (swarm.runs.forkserver) does it once, so that the agents it
    forks find every compiled kernel loaded (or compiled, on a cold cache)."""
    sim = next((a.id for a in cfg.agents if a.backend == "sim"), None)
    if sim is not None:
        step = agent_step(cfg, sim)
        _warm_up(
            step,
            pick(cfg, sim, "warm-up", tp.Counter(), agent_neighbour_table(cfg, sim)),
            sim,
            np.asarray(cfg.agent(sim).start),
        )


class AgentProcess:
    """The agent process: one :class:`swarm.step.AgentStep` and its neighbour source
    (:func:`swarm.net.sources.pick`, chosen once) wired to a Zenoh session, and a real drone's
    :class:`RealDrone` supervisor. Built without a session (and warmed up); :meth:`open`
    opens it. Phases: :meth:`listen` (what arrived), :meth:`next_message` (the tick to act
    on), :meth:`act` and :meth:`publish`."""

    def __init__(self, cfg: ScenarioConfig, agent_id: str, run: str) -> None:
        me = cfg.agent(agent_id)
        self.cfg, self.id, self.run_id, self.keys = cfg, agent_id, run, tp.Keys(run)
        self.lockstep = cfg.time.mode is TimeMode.LOCKSTEP
        self.me, self.still = me, StaticObstacles.of(list(cfg.obstacles))
        self.step = agent_step(cfg, agent_id, self.still)
        self.radius_m = self.step.model.params.body_radius_m
        self.counter = tp.Counter()
        self.source = pick(cfg, agent_id, run, self.counter, agent_neighbour_table(cfg, agent_id))
        self.others = {a.id for a in cfg.agents} - {agent_id}
        self.real = me.backend == "crazyflie"  # measured by motion capture on its own key, not in the clock
        self.ticked = cfg.uses_ticks and not self.real  # measured by its own tick message, not the clock
        self.obstacles = NamedObstacles.none()  # at the newest tick
        self.clock_live: dict[int, list[str]] = {}  # tick -> agents the world expects answers (clock)
        self._newest_k = -1  # newest tick whose clock or tick arrived
        self.stop = StopFlag()
        self.drone: RealDrone | None = None
        self.alive: set[str] = set()
        self.world_seen = False
        self.pending: list[Message] = []  # measurements not yet acted on
        self.seq = 0
        self.tick_s = timing_sketch()  # wall time [s] from measurement taken up to command sent
        self.waited_s = 0.0  # lockstep: wall time spent waiting for neighbours / clock
        self.msg_seen: dict[int, float] = {}  # lockstep: wall time each tick's measurement arrived
        self.reported_gone: set[str] = set()
        self.acted_k = -1  # lockstep: the newest tick acted on
        self.pace_s: float | None = None  # realtime: the smallest (wall clock - sim time) of a tick acted on [s]
        self.last_tick_s = 0.0  # wall time [s] the last tick took
        self.tick_budget_s = 1.0 / cfg.time.control_hz
        self.action = Action.NONE  # the safety monitor's action at the last tick
        self.land_asked = False  # the launcher asked every drone to land (swarm.landing) ...
        self.landing = False  # ... and this agent has turned to land
        _warm_up(self.step, self.source, agent_id, np.asarray(me.start, float))
        self.plan = FlightPlan(me) if self.real else None  # a real drone's phases (after the warm-up)

    def open(self, conf: Any) -> None:
        """The session, its subscribers and publishers (not yet its liveliness: :meth:`run`)."""
        keys, cfg = self.keys, self.cfg
        self.session = session = tp.open_session(conf)
        self.meas_key, self.tick_key = keys.measurement(self.id), keys.tick(self.id)
        self.inbox = tp.Inbox(
            session,
            [
                self.tick_key if self.ticked else keys.clock,
                *self.source.subscriptions(),
                *([self.meas_key] if self.real else []),
                keys.land,
            ],
        )
        self.live_sub = tp.liveliness_subscriber(session, keys.all_alive)
        self.state_pubs: dict[str, Any] = {}  # key -> publisher of this agent's state there
        self.cell_subs = tp.Channels(session)  # the neighbours' states, drained when the tick has woken us
        start = np.asarray(cfg.agent(self.id).start, float)
        start_b = body_centre(start, np.zeros(3), np.array([0, 0, 0, 1.0]), np.zeros(3), self.step.model.params.l_m)[0]
        self.source.follow(self.cell_subs, start_b)  # (cells: listen near the start before anyone sees this agent)
        first = self.source.state_key(start_b)
        if first is not None:
            self.state_pubs[first] = session.declare_publisher(first)
        self.pub_cmd = session.declare_publisher(keys.command(self.id))
        self.goals = GoalInbox(session, keys, self.id, self.run_id, self.counter) if cfg.ros2.enabled else None
        self.orders = OrderInbox(session, cfg, self.id, self.run_id, self.counter) if self.id in cfg.steerable else None
        self.startup_cpu_s = time.process_time()

    def retarget(self, x_w: FloatArray, goal_w: FloatArray, speed_mps: float | None = None) -> None:
        """Fly from ``x_w`` to ``goal_w`` [m, world] from this tick on (a goal from ROS 2 or a
        script), cruising at ``speed_mps`` [m/s] (None: its own ``speed_mps``): the course the
        planner gives for that goal from here (``swarm.ros2.goals.course``); a real drone's
        mission becomes that path."""
        me = self.me if speed_mps is None else self.me.model_copy(update={"speed_mps": speed_mps})
        c = course(me, self.still, self.step.level, x_w, goal_w, self.cfg.world.realism, self.cfg.time.control_hz)
        self.step.follow(c.goal_w, c.tracker, c.route, c.filter_config)
        if self.plan is not None:
            self.plan.mission = c.tracker

    def land(self, x_w: FloatArray) -> None:
        """Land from ``x_w`` [m, world]: a real drone by its flight plan (motors off on the
        ground), a simulated one straight down to its floor (``swarm.ros2.goals.landing_goal``)."""
        if self.plan is not None:
            self.plan.land()
        else:
            self.retarget(x_w, landing_goal(self.me, x_w))

    def connect_drone(self) -> bool:
        """A real drone: its link up (False: not reached in 15 s)."""
        settings = self.cfg.agent(self.id).crazyflie
        if self.plan is None or settings is None:
            return True
        link = CrazyflieLink(settings, self.id)
        if not link.wait_ready(15.0):
            print(f"agent {self.id}: Crazyflie at {settings.uri} not reached: {link.lost_reason}", file=sys.stderr)
            return False
        self.drone = RealDrone(self.id, self.plan, link, settings.mocap_timeout_s)
        return True

    def safety_stop(self, reason: str) -> None:
        if self.drone is not None:
            self.drone.safety_stop(reason)

    def neighbour_gone(self, name: str, how: str) -> None:
        if name not in self.reported_gone:
            self.reported_gone.add(name)
            print(f"agent {self.id}: neighbour {name} gone ({how}) at wall {time.time():.4f}", file=sys.stderr)

    def _measurement(self, m: Message) -> None:
        self.pending.append(m)
        if self.lockstep:  # (realtime acts on the newest at once: nothing to time)
            self.msg_seen.setdefault(m.k, time.monotonic())
        self.source.at(m.t)  # how far the run is: no neighbour's state is much newer

    def _obstacles(self, m: Message) -> None:
        """The obstacles of a clock or tick message, if it is the newest."""
        if m.k >= self._newest_k:
            self._newest_k = m.k
            self.obstacles = NamedObstacles(items_to_arrays(m["items"]), [i["id"] for i in m["items"]])

    def handle(self, sample: Any) -> None:
        """One sample: the neighbours' traffic (the source's), a measurement, this agent's
        tick or the clock."""
        key = str(sample.key_expr)
        if self.source.hear(key, sample):
            return
        m = tp.decode_sample(sample, self.run_id, self.counter)
        if m is None:
            return
        if key == self.meas_key and m.kind == "measurement":
            self._measurement(m)
            if self.drone is not None:
                self.drone.measured()
        elif m.kind == "tick" and key == self.tick_key:
            self.on_tick(m)
        elif m.kind == "clock" and key == self.keys.clock:
            self.on_clock(m)
        elif m.kind == "land" and key == self.keys.land and m.src == LAUNCHER:
            self.land_asked = True
        else:
            self.counter.drop(f"unexpected {m.kind} on {key}")

    def on_tick(self, m: Message) -> Message | None:
        """This agent's own tick (neighbours by bundles or cells): the near neighbours of tick
        k for the source, the obstacles, the neighbours the world has seen go (in a star no
        agent hears another's liveliness); its measurement queued (returned), or the run over."""
        self.source.on_near(m.k, m["near"])
        for name in m["gone"]:
            if name in self.others:
                self.source.lost(name)
                self.neighbour_gone(name, "the world's live list")
        self._obstacles(m)
        if m["done"]:
            self.stop.set()
            return None
        body = {f: m[f] for f in ("x", "v", "q", "w")}
        body["frames"] = frames_of(m["frames"], 0)
        mine = Message("measurement", m.run, m.src, m.seq, m.t, m.k, body)
        self._measurement(mine)
        return mine

    def on_clock(self, m: Message) -> None:
        """Tick k's clock: the live agents (a neighbour the live list lost since the newest
        clock before is gone: in a star agents hear no liveliness but the hubs'), the
        obstacles, the source's roster, and a simulated drone's measurement."""
        before = self.clock_live.get(self._newest_k) if m.k > self._newest_k else None
        if before is not None and m["live"] != before:
            for name in before:
                if name not in m["live"] and name in self.others:
                    self.neighbour_gone(name, "the world's live list")
        self.clock_live[m.k] = m["live"]
        while len(self.clock_live) > HELD_TICKS:
            del self.clock_live[next(iter(self.clock_live))]
        self._obstacles(m)
        self.source.on_clock(m)
        mine = None if self.real or m["done"] else clock_measurement(m, self.id)
        if mine is not None:
            self._measurement(mine)
        if m["done"] and (self.drone is None or self.drone.run_over()):
            self.stop.set()

    def listen(self, wake_s: float) -> bool:
        """Wait for what the oldest pending tick still needs (or ``wake_s``), take what
        arrived and the liveliness changes; False once the world is gone."""
        pending_k = min(m.k for m in self.pending) if self.pending else None
        count, most_s = self.source.wake(self.lockstep, pending_k, self.acted_k)
        self.inbox.wait_for(count, time.monotonic() + (wake_s if most_s is None else most_s))
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
                if name in self.others:
                    self.source.lost(name)
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

    def next_message(self) -> Message | None:
        """The measurement to act on now: lockstep, the oldest once its tick is complete
        (or at the deadline); realtime, the newest."""
        pending = self.pending
        if not pending:
            return None
        if not self.lockstep:
            msg = max(pending, key=lambda m: m.k)  # realtime: only the newest matters, with every frame since
            if len(pending) > 1 and "frames" in msg.body:
                msg.body["frames"] = [f for m in sorted(pending, key=lambda m: m.k) for f in m.body.get("frames", ())]
            pending.clear()
            return msg
        msg = min(pending, key=lambda m: m.k)
        if self.source.missing(msg.k) != 0:
            if time.monotonic() - self.msg_seen[msg.k] < self.cfg.time.lockstep_timeout_s:
                return None  # wait for the rest of tick k (the inbox wakes us)
            self.source.late(msg.k)
            self.counter.drop("lockstep: tick incomplete at the deadline")
        pending.remove(msg)
        self.acted_k = max(self.acted_k, msg.k)
        self.waited_s += time.monotonic() - self.msg_seen.pop(msg.k, time.monotonic())
        return msg

    def act(self, msg: Message) -> StepResult | None:
        """The control step on ``msg``, flown by a real drone; None when a rule stopped it."""
        drone = self.drone
        if drone is not None and not drone.inside_geofence(msg["x"]):
            return None
        try:
            result = self.tick(msg)
        except Exception:
            self.safety_stop("the control step raised")
            raise
        if drone is not None and not drone.fly(msg, result):
            return None
        return result

    def tick(self, msg: Message) -> StepResult:
        """The control step on a measurement, with the neighbours its source gives for that
        tick (a real drone: the tracker of its flight phase)."""
        state = QuadState(msg["x"], msg["v"], msg["q"], msg["w"])
        x_b = body_centre(state.x_w, state.v_w, state.q, state.Omega_b, self.step.model.params.l_m)[0]
        neighbours = self.source.rows(msg.t + self.step.lead_s, msg.k, x_b, self.lockstep)
        late_s = 0.0
        if not self.lockstep:  # realtime: how far the world's clock has fallen behind the wall clock
            behind = time.monotonic() - msg.t
            self.pace_s = behind if self.pace_s is None else min(self.pace_s, behind)
            late_s = behind - self.pace_s
        overrun = self.last_tick_s > self.tick_budget_s
        if self.plan is None:
            result = self.step(
                msg.t, state, self.obstacles, neighbours, frames=msg.body.get("frames"), world_late_s=late_s,
                tick_overrun=overrun,
            )  # fmt: skip
        else:
            tracker = self.plan.tracker(state.x_w)
            if tracker is None:  # landed or stopped: motors off
                return self.step.motors_off(state)
            phase = self.plan.phase
            result = self.step(
                msg.t, state, self.obstacles, neighbours, tracker=tracker, landing=phase is Phase.LAND,
                airborne=phase is not Phase.TAKEOFF, world_late_s=late_s, tick_overrun=overrun,
            )  # fmt: skip
        self.on_verdict(msg.t, result)
        return result

    def on_verdict(self, t_s: float, result: StepResult) -> None:
        """Say when the safety monitor's action changes; a real drone it lands lands by its
        flight plan (motors off on the ground)."""
        v = result.verdict
        if v.action is not self.action:
            why = ", ".join(n for b, n in BREACH_NAMES.items() if b in v.breaches) or "settling"
            print(f"agent {self.id}: monitor: {v.action.name.lower()} at t={t_s:.2f} s ({why})", file=sys.stderr)
            self.action = v.action
        if v.action is Action.LAND and self.plan is not None and self.plan.phase in (Phase.TAKEOFF, Phase.MISSION):
            self.plan.land()

    def publish(self, msg: Message, result: StepResult) -> None:
        """This agent's state (on the key its source gives: its own, or its cell's) and then its command."""
        run, source = self.run_id, self.source
        if source.publishes_state:
            self.seq += 1
            body = StateBody(result.x_b_w, result.v_b_w, self.radius_m, result.solo, result.sd)
            state = encode_state(run, self.id, self.seq, msg.t + result.ahead_s, msg.k, body)
            key = source.state_key(result.x_b_w)
            if key is not None:
                pub = self.state_pubs.get(key)
                if pub is None:
                    pub = self.state_pubs[key] = self.session.declare_publisher(key)
                pub.put(state)
            source.follow(self.cell_subs, result.x_b_w)
        self.seq += 1
        self.pub_cmd.put(
            encode_command(run, self.id, self.seq, msg.t, msg.k, command_body(result), self.counter.dropped)
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
            if self.goals is not None and not self.landing:  # a goal, land or stop from ROS 2
                self.goals.apply(self, msg["x"])
            if self.orders is not None and not self.landing:  # a script's order
                self.orders.apply(self, msg.t, msg.k, msg["x"])
            if self.land_asked and not self.landing:  # the launcher's land request (Ctrl-C), latched
                self.landing = True
                print(f"agent {self.id}: landing at t={msg.t:.2f} s (the launcher asked)", file=sys.stderr)
                self.land(msg["x"])
            t0 = time.perf_counter()
            result = self.act(msg)
            if result is None:
                break
            self.publish(msg, result)
            if self.orders is not None:
                self.orders.after(msg.t, msg.k, result.arrived, msg["x"])
            self.last_tick_s = time.perf_counter() - t0
            self.tick_s.add(self.last_tick_s)

    def summary(self) -> dict[str, Any]:
        ts = self.tick_s
        counter = self.counter
        return {
            "id": self.id,
            "ticks": int(ts.count),
            "compute_median_ms": 1e3 * (ts.get_quantile_value(0.5) or 0.0),  # (within 1 %)
            "compute_p99_ms": 1e3 * (ts.get_quantile_value(0.99) or 0.0),
            "waited_s": self.waited_s,
            "cpu_s": time.process_time(),
            "startup_cpu_s": self.startup_cpu_s,
            "dropped": counter.dropped,
            "rx_bytes": counter.rx_bytes,
            "rx_messages": counter.rx_messages,
            "missed_neighbours": self.source.missed,
            "cells_declared": self.source.cells_declared,
            "rejected": tp.rejected(self.source.rejected, counter.by_sender),  # per sender and reason
        }

    def run(self, conf: Any) -> int:
        """Open, connect a real drone, declare this agent live, fly until the run ends or a
        rule stops it, report; 2 when the drone was not reached. The world starts once every
        agent is live, so an agent whose drone cannot be reached fails the run before its first
        tick (``RunHandle.poll``), not in the middle of it."""
        self.open(conf)
        if not self.connect_drone():
            return 2
        self.token = tp.declare_liveliness(self.session, self.keys.alive(self.id))
        self.world_deadline = time.monotonic() + self.cfg.time.start_timeout_s  # the world must show up by then
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
    return AgentProcess(cfg, agent_id, run).run(conf)
