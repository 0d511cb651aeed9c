"""The world process: PyBullet physics, measurements out, commands in.

    swarm world CONFIG [--run RUN] [--port P] [--gui]

Each tick the world publishes one clock message (``swarm.net.messages``: the live agents,
every drone's body centre, velocity and radius, each simulated drone's measurement, the
obstacles) and, at ``STATUS_HZ``, a status. Lockstep: publish tick k, wait until
every live agent answered k or the timeout passed (those are late and keep their last
command), then step physics. Realtime: physics follows the wall clock and tick k is
published at wall time k * dt; commands are applied when they arrive and held until
replaced, but a command older than ``time.command_timeout_s`` is not flown (the drone
levels out and brakes). Agents with ``neighbours.source: world`` take their neighbours
from the clock's roster.

Real drones (``backend: crazyflie``, realtime only) are not simulated: the motion-capture
relay (``world/mocap.py``) publishes their measurements at the capture rate from its own
thread, PyBullet holds them as kinematic bodies at their measured poses (so contacts are
still detected), their commands are recorded but not flown (they went to the drones by
radio), and after the end the relay keeps going until they have landed or
``time.land_timeout_s`` has passed.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarm.config import ScenarioConfig, TimeMode
from swarm.control import (
    AttitudeController,
    AttitudeSetpoint,
    OnboardController,
    OnboardGains,
    onboard_rotor_thrusts,
)
from swarm.crazyflie_fw import WDT_SHUTDOWN_S, WDT_STABILIZE_S
from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.net import transport as tp
from swarm.net.cells import near_lists
from swarm.net.messages import encode, warm_up
from swarm.offline.scenario import items_to_arrays, min_pair_distance, obstacle_items, surface_clearance
from swarm.rotation import quat_to_R
from swarm.shutdown import StopFlag
from swarm.world.mocap import BodyEstimate, MocapRelay, connect
from swarm.world.physics import PhysicsWorld


@dataclass
class DroneSlot:
    """What the world holds for one agent's drone."""

    model: QuadModel
    level: CommandLevel
    onboard: OnboardController
    att: AttitudeController
    goal: np.ndarray
    alive: bool = False
    dead: bool = False
    command: np.ndarray | None = None  # rotors: f (4,) N; attitude: roll, pitch, yaw rate, thrust
    command_k: int = -1
    command_t_s: float = 0.0  # sim time of the tick the held command answered
    braking_ticks: int = 0  # realtime: ticks flown on the braking fallback (command too old)
    sent_at: dict[int, float] = field(default_factory=dict)  # tick -> wall time published
    latencies_s: list[float] = field(default_factory=list)
    on_time: int = 0
    answered: int = 0
    reached_at_s: float | None = None
    yaw_sp_rad: float = 0.0  # the onboard controller's integrated yaw setpoint
    infeasible: int = 0  # commands the agent's filter marked infeasible (or failed)
    solo: bool = False  # not doing its share of a pair's avoidance (unfiltered, or its last command not "ok")
    behind: bool = False  # lockstep: let a tick time out; not waited for until it answers again


GROUND_IMPACT_MPS = 0.5
"""A drone touching the ground slower than this [m/s] stands, takes off or lands on it:
not a collision (a real drone takes off from the ground and lands on it)."""


def _impact(pair: tuple[str, str], index: dict[str, int], v_w: np.ndarray) -> bool:
    """A ground contact of ``pair``'s drone at ``GROUND_IMPACT_MPS`` or faster."""
    drone = pair[0] if pair[1] == "ground" else pair[1]
    i = index.get(drone)
    return i is None or float(np.linalg.norm(v_w[i])) >= GROUND_IMPACT_MPS


def _setpoint(slot: DroneSlot, t_s: float) -> tuple[float, ...] | np.ndarray:
    """Roll, pitch [rad], yaw rate [rad/s], thrust [N] at sim time ``t_s``: level hover
    before the agent's first command, then its newest command as the Crazyflie firmware
    flies it (swarm.crazyflie_fw): as it is while younger than 500 ms, levelled out with
    its thrust until 2 s, then motors off."""
    if slot.command is None:
        return (0.0, 0.0, 0.0, slot.model.params.weight_N)
    age = t_s - slot.command_t_s
    if age > WDT_SHUTDOWN_S:
        return (0.0, 0.0, 0.0, 0.0)
    if age > WDT_STABILIZE_S:
        return (0.0, 0.0, 0.0, float(slot.command[3]))
    return slot.command


STATUS_HZ = 10.0  # rate of the world's status messages [Hz]
COMMAND_FIELDS = ("level", "u", "status")  # what the world reads of a command (the report is the recorder's)
_STOP = np.zeros(3)
_DESCEND = np.array([0.0, 0.0, -0.3])  # m/s, landing


def _velocity_hold(slot: DroneSlot, state: QuadState, v_des_w: np.ndarray) -> np.ndarray:
    """The world's own fallback: fly level at ``v_des_w`` [m/s, world] with the thrust
    vector ``m (g e3 + 2 (v_des - v))``. Braking (a command too old, as the firmware's
    setpoint timeout) holds zero velocity; landing (a dead agent) descends."""
    p = slot.model.params
    F = p.mass_kg * (np.array([0.0, 0.0, p.g_mps2]) + 2.0 * (v_des_w - state.v_w))
    return slot.att.from_thrust_vector(state, F)


@dataclass
class TickView:
    """What the world measured at the start of tick k (ground truth; motion capture for
    real drones), in ``World.names`` order."""

    ds: Any  # PhysicsWorld states: x_w (n, 3) m, v_w (n, 3) m/s, q (n, 4), Omega_b (n, 3) rad/s, R (n, 3, 3)
    items: list[dict]  # the obstacles at tick k
    live: list[str]  # agents the world expects answers from
    x_b: np.ndarray  # (n, 3) m, world: body centres
    roster: np.ndarray  # (n * 7,): per drone body centre [m], its velocity [m/s], radius [m]
    measured: list[str]  # simulated drones of live agents, measured in the clock
    meas: np.ndarray  # (len(measured) * 13,): x, v, q, w of each


@dataclass
class RunCounts:
    """The world's running metrics of a run."""

    collisions: int = 0  # contacts among live agents' drones (and obstacles)
    dead_contacts: int = 0  # contacts of a dead agent's drone (landing, or left to the firmware)
    stalls: int = 0  # lockstep ticks that waited longer than stall_warn_s
    late: int = 0
    min_sep: float = math.inf
    min_clear: float = math.inf
    touching: set[tuple[str, str]] = field(default_factory=set)


class World:
    """The world process's state and one method per phase of a tick: :meth:`measure`,
    :meth:`publish`, :meth:`collect` (lockstep: wait for the commands) and
    :meth:`step_physics`; :meth:`run` wires them to a Zenoh session."""

    def __init__(self, cfg: ScenarioConfig, run: str, gui: bool = False) -> None:
        self.cfg, self.run_id, self.keys = cfg, run, tp.Keys(run)
        self.sim = PhysicsWorld(cfg.time.physics_hz, gui=gui or cfg.gui)
        self.slots: dict[str, DroneSlot] = {}
        self.real = {a.id for a in cfg.agents if a.backend == "crazyflie"}  # placed from motion capture
        self.unfiltered = {a.id for a in cfg.agents if not a.filter.enabled}  # they take no share of a pair
        self.firmware_death = cfg.failure.on_agent_death == "firmware"  # a dead agent's drone: the firmware's watchdog
        for a in cfg.agents:
            model = QuadModel(a.quad_params())
            self.sim.add_drone(
                a.id,
                model,
                np.asarray(a.start, float),
                a.yaw_rad,
                np.asarray(a.start_velocity, float),
                kinematic=a.id in self.real,
            )
            self.slots[a.id] = DroneSlot(
                model,
                a.command_level,
                OnboardController(model, a.yaw_rad),
                AttitudeController(model),
                np.asarray(a.final_goal),
            )
        for o in cfg.obstacles:
            if o.shape == "sphere":
                self.sim.add_sphere(o.id, np.asarray(o.center), o.radius_m, np.asarray(o.velocity))
            else:
                self.sim.add_cylinder(
                    o.id, np.asarray(o.center), np.asarray(o.axis), o.radius_m, o.length_m, np.asarray(o.velocity)
                )
        self.names = list(self.slots)
        self.flown = [a for a in self.names if a not in self.real]  # simulated drones: PyBullet flies them
        self.index = {a: i for i, a in enumerate(self.names)}
        self.l_m = np.array([self.slots[a].model.params.l_m for a in self.names])  # body-centre offsets [m]
        self.radius_m = np.array([self.slots[a].model.params.body_radius_m for a in self.names])  # bounding radii [m]
        self.goals = np.array([self.slots[a].goal for a in self.names])  # (n, 3) m, world
        self.cells = cfg.uses_ticks  # each simulated agent gets its own tick message (swarm.net.cells)
        self.near_m = np.array([cfg.near_radius_m(a) for a in self.names]) if self.cells else np.zeros(0)  # m
        self.dt_ctrl = 1.0 / cfg.time.control_hz
        self.K = round(cfg.duration_s * cfg.time.control_hz)  # the last tick
        self.lockstep = cfg.time.mode is TimeMode.LOCKSTEP
        self.counts = RunCounts()
        self.counter = tp.Counter()
        self.seq = 0
        self.others_alive: set[str] = set()
        self.onboard_gains: dict[tuple[str, ...], OnboardGains] = {}  # drones -> their stacked gains
        self.phase = {"publish": 0.0, "wait": 0.0, "physics": 0.0}
        self.relay: MocapRelay | None = None
        self.running = threading.Event()  # the relay publishes only while the run is on
        self._mocap_seq = 10**9  # the relay thread's own sequence numbers
        self.wall0 = time.monotonic()
        self.stop = StopFlag()

    # --- wiring -------------------------------------------------------------------
    def open(self, conf: Any) -> None:
        """The session, its publishers and subscribers, this world's liveliness, and the
        motion-capture relay of the real drones."""
        keys, cfg = self.keys, self.cfg
        self.session = session = tp.open_session(conf)
        self.token = tp.declare_liveliness(session, keys.alive("world"))
        self.cmd_in = tp.Inbox(session, keys.all_commands)
        self.live_sub = tp.liveliness_subscriber(session, keys.all_alive)
        self.pubs = {aid: session.declare_publisher(keys.measurement(aid)) for aid in self.real}  # motion capture
        self.pub_tick = {a: session.declare_publisher(keys.tick(a)) for a in self.flown if self.cells}
        self.pub_clock = session.declare_publisher(keys.clock)
        self.pub_status = session.declare_publisher(keys.status)
        self.pub_coll = session.declare_publisher(keys.collision)
        self.pub_stall = session.declare_publisher(keys.stall)
        if self.real and cfg.mocap is not None:  # (the config requires mocap when any drone is real)
            m = cfg.mocap
            bodies = {a.mocap_body: a.id for a in cfg.agents if a.id in self.real}
            self.relay = MocapRelay(
                connect(m.type, m.hostname, m.options),
                bodies,
                m.rate_hz,
                m.lost_after_s,
                m.velocity_filter_s,
                self._on_frame,
                lambda aid: None,
            ).start()

    def _on_frame(self, aid: str, est: BodyEstimate) -> None:
        """The relay's thread: a real drone's measurement, at the capture rate."""
        if not self.running.is_set():
            return
        t = time.monotonic() - self.wall0
        self._mocap_seq += 1
        self.pubs[aid].put(
            encode(
                "measurement",
                self.run_id,
                "world",
                self._mocap_seq,
                t,
                int(t / self.dt_ctrl),
                x=est.x_w,
                v=est.v_w,
                q=est.q,
                w=est.Omega_b,
            )
        )

    def _put(self, pub: Any, kind: str, t: float, k: int, **body: Any) -> None:
        self.seq += 1
        pub.put(encode(kind, self.run_id, "world", self.seq, t, k, **body))

    def poll_liveliness(self) -> None:
        for name, up in tp.liveliness_events(self.live_sub):
            slot = self.slots.get(name)
            if slot is not None:
                if up:
                    slot.alive = True
                elif slot.alive:
                    slot.alive, slot.dead = False, True
                    print(
                        f"world: agent {name} gone at wall {time.time():.4f}: {self.cfg.failure.on_agent_death}",
                        file=sys.stderr,
                    )
            elif up:
                self.others_alive.add(name)
            else:
                self.others_alive.discard(name)

    def poll_commands(self, k_now: int, wait_until: float | None = None) -> None:
        """Take every command that has arrived (first waiting until ``wait_until`` for one)."""
        first = self.cmd_in.get(wait_until) if wait_until is not None else None
        for s in ([first] if first is not None else []) + list(self.cmd_in.drain()):
            m = tp.decode_sample(s, self.run_id, self.counter, ("command",), COMMAND_FIELDS)
            if m is not None:
                self._take_command(m, str(s.key_expr), k_now)

    def _take_command(self, m: Any, key: str, k_now: int) -> None:
        counter, slot = self.counter, self.slots.get(m.src)
        if slot is None or slot.dead:
            counter.drop("command from unknown or dead agent")
            return
        if key != self.keys.command(m.src):  # a header naming another agent than its key
            counter.drop("command whose sender is not its key's agent")
            return
        if m.src in self.real:  # it answers a motion-capture frame, stamped on the wall clock (_on_frame),
            # which runs ahead of the ticks while the world is late
            k_now = max(k_now, int((time.monotonic() - self.wall0) / self.dt_ctrl))
        if m.k > k_now + 1 or abs(m.t - m.k * self.dt_ctrl) > 2.0 * self.dt_ctrl:  # not an answer to a tick we sent
            counter.drop("command for a tick or time the world has not reached")
            return
        if m["status"] != "ok":
            slot.infeasible += 1
        slot.solo = m["status"] != "ok"
        if m.src in self.real:  # a real drone's command went to it by radio: recorded, not flown
            slot.command_k = max(slot.command_k, m.k)
            return
        u = m["u"]
        if u.shape != (4,) or m["level"] != slot.level.value:
            counter.drop("command of wrong level or size")
            return
        if m.k < slot.command_k:
            return  # older than what we hold
        slot.command, slot.command_k, slot.command_t_s = u, m.k, m.t
        slot.behind = False  # it answers again (a backlog's oldest tick first): waited for again
        sent = slot.sent_at.pop(m.k, None)
        if sent is not None:
            slot.answered += 1
            slot.latencies_s.append(time.monotonic() - sent)
            if m.k >= k_now:
                slot.on_time += 1

    def warm_up(self) -> None:
        """The first call of compiled code loads it (a few hundred ms), and compiles it when
        the kernel cache is cold (the first run after an install or an edit: seconds). Do
        both before any tick, with the argument types the ticks use, or a realtime world
        starts behind the wall clock: a real drone's motion-capture frames, stamped on that
        clock, then meet simulated drones from the past (measured on
        ``configs/mixed_sitl.yaml`` with a cold cache: tick 0 took 1.5 to 2.5 s, and the real
        drones' rows went down to h = -0.09)."""
        for sl in self.slots.values():
            st0 = QuadState.hover()
            sl.onboard.rotor_thrusts(st0, AttitudeSetpoint(0.0, 0.0, 0.0, sl.model.params.weight_N), self.sim.dt_s)
            sl.att.from_thrust_vector(st0, np.array([0.0, 0.0, sl.model.params.weight_N]))
            sl.onboard.yaw_sp_rad = sl.yaw_sp_rad
        min_pair_distance(np.zeros((2, 3)))  # (measure: the closest pair)
        fs = self.sim.read_states(self.flown)  # reading only: the drones do not move
        if self.flown:  # _onboard_thrusts' call, with its argument layouts, changing no slot
            n = len(self.flown)
            self._onboard_call(fs, list(range(n)), tuple(self.flown), np.zeros((n, 4)), np.zeros(n))
        warm_up()

    def wait_for_everyone(self, expect: tuple[str, ...]) -> bool:
        """Until every agent and the ``expect``ed processes are alive (False at the start timeout)."""
        deadline = time.monotonic() + self.cfg.time.start_timeout_s
        while not all(s.alive for s in self.slots.values()) or not set(expect) <= self.others_alive:
            self.poll_liveliness()
            if self.stop or time.monotonic() > deadline:
                missing = [a for a, s in self.slots.items() if not s.alive] + sorted(set(expect) - self.others_alive)
                print(f"world: gave up waiting for {missing}", file=sys.stderr)
                return False
            time.sleep(0.005)
        return True

    # --- the phases of a tick -------------------------------------------------------
    def pace(self, k: int) -> None:
        """Realtime: publish tick k at its wall time k * dt, not right after the last
        substep of tick k-1 (which runs at (k - 1/substeps) * dt); commands that arrive
        until then answered tick k-1 in time."""
        if not self.lockstep and k > 0:
            target = self.wall0 + k * self.dt_ctrl
            while time.monotonic() < target:
                self.poll_commands(k - 1, target)

    def measure(self, k: int, t: float) -> TickView:
        """Ground truth for metrics and measurements (motion capture for real drones), and
        the running metrics it updates."""
        names, slots, relay, c = self.names, self.slots, self.relay, self.counts
        ds = self.sim.read_states(names)
        for i, a in enumerate(names):
            est = relay.latest(a) if relay and a in self.real else None
            if est is not None:
                ds.x_w[i], ds.v_w[i], ds.q[i], ds.Omega_b[i] = est.x_w, est.v_w, est.q, est.Omega_b
                ds.R[i] = quat_to_R(est.q)
        items = obstacle_items(self.cfg.obstacles, t)
        obs = items_to_arrays(items)
        live = [a for a in names if slots[a].alive]
        l_m = self.l_m[:, None]
        x_b = ds.x_w + l_m * ds.R[:, :, 2]
        v_b = ds.v_w + l_m * (ds.R[:, :, 0] * ds.Omega_b[:, 1:2] - ds.R[:, :, 1] * ds.Omega_b[:, 0:1])
        roster = np.hstack([x_b, v_b, self.radius_m[:, None]]).ravel()
        measured = [a for a in self.flown if slots[a].alive]  # a dead agent's drone is no longer measured
        rows = [self.index[a] for a in measured]
        meas = np.hstack([ds.x_w[rows], ds.v_w[rows], ds.q[rows], ds.Omega_b[rows]]).ravel()
        flying = x_b[[not slots[a].dead for a in names]]
        if len(flying) >= 2:
            c.min_sep = min(c.min_sep, min_pair_distance(flying))
        if len(obs) and len(flying):
            c.min_clear = min(c.min_clear, float(surface_clearance(flying, obs).min()))
        at_goal = np.linalg.norm(ds.x_w - self.goals, axis=1) <= self.cfg.goal_tolerance_m
        for a, there in zip(names, at_goal.tolist(), strict=True):
            if there and slots[a].reached_at_s is None:
                slots[a].reached_at_s = t
        return TickView(ds, items, live, x_b, roster, measured, meas)

    def is_done(self, k: int, view: TickView) -> bool:
        all_reached = all(s.reached_at_s is not None for s in self.slots.values() if not s.dead)
        return bool(k == self.K or (self.cfg.stop_when_all_reached and all_reached) or self.stop or not view.live)

    def publish(self, k: int, t: float, view: TickView, done: bool, status_every: int) -> None:
        """Tick k out: the status (every ``status_every`` ticks and the last), the clock, and
        with neighbours by cells each agent's own tick."""
        slots, names, c = self.slots, self.names, self.counts
        now = time.monotonic()
        if not done:
            for a in view.live:
                if a not in self.real:  # the relay publishes real drones' measurements at the capture rate
                    slots[a].sent_at[k] = now
        if done or k % status_every == 0:
            wall = now - self.wall0
            self._put(
                self.pub_status,
                "status",
                t,
                k,
                rtf=t / wall if wall > 0 else 0.0,
                min_sep=min(c.min_sep, 1e9),
                min_clear=min(c.min_clear, 1e9),
                collisions=c.collisions,
                late=c.late,
                dropped=self.counter.dropped,
                live=view.live,
                done=done,
                infeasible=sum(sl.infeasible for sl in slots.values()),
                stalls=c.stalls,
                dead=[a for a in names if slots[a].dead],
            )
        solo = [a for a in names if slots[a].solo or slots[a].dead or a in self.unfiltered]
        self._put(
            self.pub_clock,
            "clock",
            t,
            k,
            live=view.live,
            done=done,
            ids=names,
            xvr=view.roster,
            meas_ids=view.measured,
            meas=view.meas,
            items=view.items,
            solo=solo,
        )
        if self.cells:  # each agent's own tick: its measurement and the live agents near it
            expected = np.array([slots[a].alive and not slots[a].dead for a in names])
            near = near_lists(view.x_b, expected, self.near_m)
            ds = view.ds
            gone = [a for a in names if slots[a].dead]
            for aid in view.measured:
                i = self.index[aid]
                self._put(
                    self.pub_tick[aid],
                    "tick",
                    t,
                    k,
                    x=ds.x_w[i],
                    v=ds.v_w[i],
                    q=ds.q[i],
                    w=ds.Omega_b[i],
                    near=[names[j] for j in near[i]],
                    items=view.items,
                    gone=gone,
                    done=done,
                )

    def collect(self, k: int, t: float, live: list[str]) -> None:
        """Lockstep: wait until every live agent answered tick k, or the timeout passed
        (those are late and keep their last command); a long wait is a stall, logged and
        published."""
        cfg, slots, c = self.cfg, self.slots, self.counts
        wait_from = time.monotonic()
        wait_until = wait_from + cfg.time.lockstep_timeout_s
        stall_warn_s = cfg.time.stall_warn_fraction * cfg.time.lockstep_timeout_s
        held: list[str] = []  # the agents still missing when the wait became a stall
        while True:
            self.poll_liveliness()
            waiting = [a for a in live if slots[a].alive and slots[a].command_k < k and not slots[a].behind]
            if not waiting or self.stop:
                break
            now = time.monotonic()
            if not held and now - wait_from > stall_warn_s:
                held = waiting
                print(
                    f"world: tick {k} (t = {t:.2f} s) has waited {now - wait_from:.2f} s for {waiting}", file=sys.stderr
                )
            if now > wait_until:
                c.late += len(waiting)
                for a in waiting:
                    slots[a].sent_at.pop(k, None)
                    slots[a].behind = True  # (an agent that never answers costs one timeout, not one per tick)
                break
            # wake once the missing commands can all be here (not on each one), at the latest
            # after 20 ms to look at liveliness
            self.cmd_in.wait_for(len(waiting), min(wait_until, now + 0.02))
            self.poll_commands(k)
        for a in live:  # behind since a timeout: late, not waited for
            if slots[a].behind and slots[a].command_k < k and slots[a].sent_at.pop(k, None) is not None:
                c.late += 1
        if held:
            c.stalls += 1
            waited = time.monotonic() - wait_from
            print(f"world: tick {k} stalled {waited:.2f} s on {held}", file=sys.stderr)
            self._put(self.pub_stall, "stall", t, k, agents=held, wait_s=waited)

    def step_physics(self, k: int, view: TickView) -> None:
        """The substeps of tick k: realtime follows the wall clock and takes the commands
        that came meanwhile; each substep flies every drone's rotor thrusts and notes the
        contacts."""
        sub = self.cfg.time.substeps
        for j in range(sub):
            if not self.lockstep:
                # take the commands that came meanwhile in one go (waking for each would take
                # the CPU from the agents computing them)
                time.sleep(max(0.0, self.wall0 + (k + j / sub) * self.dt_ctrl - time.monotonic()))
                self.poll_commands(k)
            fs = view.ds if j == 0 and not self.real else self.sim.read_states(self.flown)  # `flown` order
            for a in self.real:  # real drones: where motion capture saw them last
                est = self.relay.latest(a) if self.relay else None
                if est is not None:
                    self.sim.set_pose(a, est.x_w, est.q)
            self.sim.apply_rotors_all(self.flown, self._rotor_thrusts(fs, self._stale(), j == 0), fs)
            pairs = {p for p in self.sim.step() if "ground" not in p or _impact(p, self.index, view.ds.v_w)}
            self._contacts(pairs, k)
        if not self.lockstep:
            for a in view.live:
                sl = self.slots[a]
                stale = [kk for kk in sl.sent_at if kk < k]
                self.counts.late += len(stale)
                for kk in stale:
                    sl.sent_at.pop(kk)

    def _stale(self) -> set[str]:
        """Realtime: the drones whose held command is older than the timeout (a rotor
        command, or any with ``late_command: brake``): not flown."""
        if self.lockstep:
            return set()
        cfg, slots, t_s = self.cfg, self.slots, self.sim.t_s
        return {
            a
            for a in self.names
            if not slots[a].dead
            and slots[a].command is not None
            and (slots[a].level is CommandLevel.ROTORS or cfg.time.late_command == "brake")
            and t_s - slots[a].command_t_s > cfg.time.command_timeout_s
        }

    def _rotor_thrusts(self, fs: Any, stale: set[str], first_substep: bool) -> np.ndarray:
        """Rotor thrusts [N] (len(flown), 4): the onboard controller for attitude commands
        (and before the first command), the agent's thrusts for rotor commands, the world's
        own fallbacks for dead agents and stale commands."""
        slots, flown = self.slots, self.flown
        f_all = np.zeros((len(flown), 4))
        att = [
            i
            for i, a in enumerate(flown)
            if (not slots[a].dead or self.firmware_death)
            and a not in stale
            and (slots[a].level is CommandLevel.ATTITUDE or slots[a].command is None)
        ]
        if att:
            f_all[att] = self._onboard_thrusts(fs, att)
        attitude = set(att)
        for i, a in enumerate(flown):
            sl = slots[a]
            if i in attitude:
                continue
            if sl.dead:
                landed = self.cfg.failure.on_agent_death == "motors_off" or fs.x_w[i, 2] < 0.05
                if not landed:
                    f_all[i] = _velocity_hold(sl, fs.state(i), _DESCEND)
            elif a in stale:
                f_all[i] = _velocity_hold(sl, fs.state(i), _STOP)
                if first_substep:
                    sl.braking_ticks += 1
            elif sl.command is not None:  # rotor level: the agent's thrusts, held (`att` has the drones without one)
                f_all[i] = np.clip(sl.command, 0.0, sl.model.params.f_max_N)
        return f_all

    def _onboard_thrusts(self, fs: Any, att: list[int]) -> np.ndarray:
        """The onboard attitude controller of the drones ``att`` (indices into ``flown``),
        flying their setpoints as the firmware does (``_setpoint``), in one compiled call."""
        slots, dt_s = self.slots, self.sim.dt_s
        att_names = tuple(self.flown[i] for i in att)
        sp = np.array([_setpoint(slots[a], self.sim.t_s) for a in att_names])
        for a, yaw_rate in zip(att_names, sp[:, 2].tolist(), strict=True):
            slots[a].yaw_sp_rad += yaw_rate * dt_s
        return self._onboard_call(fs, att, att_names, sp, np.array([slots[a].yaw_sp_rad for a in att_names]))

    def _onboard_call(
        self, fs: Any, att: list[int], names: tuple[str, ...], sp: np.ndarray, yaw_sp_rad: np.ndarray
    ) -> np.ndarray:
        """The one compiled call of the onboard controller for the drones ``names`` (indices
        ``att`` into ``flown``): setpoints ``sp`` (k, 4) as ``_setpoint`` gives them (the yaw
        rate column unused), yaw setpoints ``yaw_sp_rad`` (k,); their gains stacked once per set."""
        gains = self.onboard_gains.get(names)
        if gains is None:
            gains = self.onboard_gains[names] = OnboardGains.stack([self.slots[a].onboard.gains for a in names])
        return onboard_rotor_thrusts(fs.q[att], fs.Omega_b[att], sp[:, 0], sp[:, 1], yaw_sp_rad, sp[:, 3], *gains)

    def _contacts(self, pairs: set[tuple[str, str]], k: int) -> None:
        """Count and publish the contacts that began in this substep."""
        c = self.counts
        for pair in pairs - c.touching:
            dead = any(x in self.slots and self.slots[x].dead for x in pair)
            if dead:
                c.dead_contacts += 1
            else:
                c.collisions += 1
            self._put(self.pub_coll, "collision", self.sim.t_s, k, a=pair[0], b=pair[1], dead=dead)
        c.touching = pairs

    # --- the run --------------------------------------------------------------------
    def loop(self) -> int:
        """Every tick, phase by phase, until done; returns the last tick."""
        status_every = max(1, round(self.cfg.time.control_hz / STATUS_HZ))
        k = 0
        for k in range(self.K + 1):
            t_phase = time.perf_counter()
            t = k * self.dt_ctrl
            self.pace(k)
            self.poll_liveliness()
            view = self.measure(k, t)
            done = self.is_done(k, view)
            self.publish(k, t, view, done, status_every)
            if done:
                break
            t_pub_end = time.perf_counter()
            self.phase["publish"] += t_pub_end - t_phase
            if self.lockstep:
                self.collect(k, t, view.live)
            t_wait_end = time.perf_counter()
            self.phase["wait"] += t_wait_end - t_pub_end
            self.step_physics(k, view)
            self.phase["physics"] += time.perf_counter() - t_wait_end
        return k

    def land_real_drones(self) -> None:
        """Real drones land on their own measurements: keep relaying until they are gone."""
        until = time.monotonic() + self.cfg.time.land_timeout_s
        while any(self.slots[a].alive for a in self.real) and time.monotonic() < until and not self.stop:
            self.poll_liveliness()
            time.sleep(0.02)

    def summary(self, k: int, startup_cpu_s: float) -> dict[str, Any]:
        slots, c, relay = self.slots.values(), self.counts, self.relay
        lat = [x for s in slots for x in s.latencies_s]
        answered = sum(s.answered for s in slots)
        return {
            "ticks": k,
            "t_s": k * self.dt_ctrl,
            "collisions": c.collisions,
            "dead_agent_contacts": c.dead_contacts,
            "stalls": c.stalls,
            "late": c.late,
            "on_time_fraction": sum(s.on_time for s in slots) / (answered + c.late) if answered + c.late else None,
            "p99_tick_latency_ms": float(np.percentile(lat, 99) * 1e3) if lat else None,
            "median_tick_latency_ms": float(np.median(lat) * 1e3) if lat else None,
            "real_time_factor": k * self.dt_ctrl / (time.monotonic() - self.wall0),
            "cpu_s": time.process_time(),
            "startup_cpu_s": startup_cpu_s,
            "phase_wall_s": {n: round(v, 3) for n, v in self.phase.items()},
            "dropped": self.counter.dropped,
            "dropped_reasons": dict(self.counter.reasons),
            "braking_ticks": sum(s.braking_ticks for s in slots),
            "mocap": None
            if relay is None
            else {"frames": relay.frames, "dropped_frames": relay.dropped_frames, "lost": sorted(relay.lost)},
        }

    def run(self, conf: Any, expect: tuple[str, ...] = ()) -> int:
        """Open, wait for everyone, fly every tick, land the real drones; 2 when the
        processes did not all come up."""
        self.open(conf)
        self.warm_up()
        if not self.wait_for_everyone(expect):
            self.token.undeclare()
            return 2
        self.wall0 = time.monotonic()
        startup_cpu_s = time.process_time()  # imports, PyBullet, compiled code, waiting for everyone
        self.running.set()
        try:
            k = self.loop()
            if self.relay is not None:
                self.land_real_drones()
        finally:
            self.running.clear()
            if self.relay is not None:
                self.relay.stop()
            self.token.undeclare()
            self.sim.close()
        print("WORLD_SUMMARY " + json.dumps(self.summary(k, startup_cpu_s)), file=sys.stderr)
        return 0


def main(cfg: ScenarioConfig, run: str, conf: Any, gui: bool = False, expect: tuple[str, ...] = ()) -> int:
    """The world process: ``swarm world``."""
    return World(cfg, run, gui).run(conf, expect)
