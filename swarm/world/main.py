"""The world process: the physics (``swarm.sim.stepper``) wired to Zenoh, measurements out,
commands in.

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
relay (``swarm.world.mocap``) publishes their measurements at the capture rate from its own
thread, PyBullet holds them as kinematic bodies at their measured poses (so contacts are
still detected), their commands are recorded but not flown (they went to the drones by
radio), and after the end the relay keeps going until they have landed or
``time.land_timeout_s`` has passed.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from ddsketch import DDSketch

from swarm.config import ScenarioConfig, TimeMode
from swarm.geometry import items_to_arrays, min_pair_distance, obstacle_items, surface_clearance
from swarm.landing import down, landing_height_m
from swarm.ledger import timing_sketch
from swarm.net import access
from swarm.net import transport as tp
from swarm.net.cells import near_lists
from swarm.net.messages import encode, frames_wire, warm_up
from swarm.rotation import quat_to_R
from swarm.safety.monitor import Action
from swarm.shutdown import StopFlag
from swarm.sim.physics import DroneStates
from swarm.sim.stepper import Stepper
from swarm.world.real_drones import RealDroneFeed


def _ms(s: float | None) -> float | None:
    """Seconds as milliseconds (None stays None)."""
    return None if s is None else s * 1e3


@dataclass
class AgentSlot:
    """What the world holds for one agent: its liveliness, the ticks it was sent and how it
    answered them, what its commands reported."""

    goal: np.ndarray  # (3,) m, world
    alive: bool = False
    dead: bool = False
    command_k: int = -1  # the newest tick it answered
    sent_at: dict[int, float] = field(default_factory=dict)  # tick -> wall time published
    latencies_s: DDSketch = field(default_factory=timing_sketch)  # tick sent to command [s]
    on_time: int = 0
    answered: int = 0
    reached_at_s: float | None = None
    infeasible: int = 0  # commands the agent's filter marked infeasible (or failed)
    solo: bool = False  # not doing its share of a pair's avoidance (unfiltered, or its last command not "ok")
    monitor: int = 0  # its safety monitor's action in its newest command (swarm.safety.monitor.Action)
    fallbacks: int = 0  # ticks its plugins' (filter's, controller's) commands were replaced, as its newest says
    behind: bool = False  # lockstep: let a tick time out; not waited for until it answers again


def monitor_acting(slots: Iterable[AgentSlot]) -> int:
    """How many live agents' safety monitors slow, hold or land their drones (as their newest
    commands say): the status's ``acting``."""
    return sum(1 for s in slots if not s.dead and s.monitor >= Action.SLOW)


STATUS_HZ = 10.0  # rate of the world's status messages [Hz]
# what the world reads of a command (the report is the recorder's): its monitor's action for the status
COMMAND_FIELDS = ("level", "u", "status", "monitor", "fallbacks", "ctrl_fallbacks")


@dataclass
class TickView:
    """What the world measured at the start of tick k (ground truth; motion capture for
    real drones), in ``World.names`` order."""

    ds: DroneStates  # x_w (n, 3) m, v_w (n, 3) m/s, q (n, 4), Omega_b (n, 3) rad/s, R (n, 3, 3)
    items: list[dict]  # the obstacles at tick k
    live: list[str]  # agents the world expects answers from
    x_b: np.ndarray  # (n, 3) m, world: body centres
    roster: np.ndarray  # (n * 7,): per drone body centre [m], its velocity [m/s], radius [m]
    measured: list[str]  # simulated drones of live agents, measured in the clock
    meas: np.ndarray  # (len(measured) * 13,): x, v, q, w of each
    frames: dict[str, list]  # measured drone -> its motion-capture frames since the last tick (world.realism)


@dataclass
class RunCounts:
    """The world's running metrics of a run."""

    collisions: int = 0  # contacts among live agents' drones (and obstacles)
    dead_contacts: int = 0  # contacts of a dead agent's drone (landing, or left to the firmware)
    stalls: int = 0  # lockstep ticks that waited longer than stall_warn_s
    late: int = 0
    skipped: int = 0  # realtime with real drones: ticks flown unpublished, the world behind the wall clock
    min_sep: float = math.inf
    min_clear: float = math.inf
    touching: set[tuple[str, str]] = field(default_factory=set)


class World:
    """The world process's state and one method per phase of a tick: :meth:`measure`,
    :meth:`publish`, :meth:`collect` (lockstep: wait for the commands) and
    :meth:`step_physics`; :meth:`run` wires them to a Zenoh session."""

    def __init__(self, cfg: ScenarioConfig, run: str, gui: bool = False) -> None:
        self.cfg, self.run_id, self.keys = cfg, run, tp.Keys(run)
        self.physics = physics = Stepper(cfg, gui)
        self.slots = {a.id: AgentSlot(np.asarray(a.final_goal, float)) for a in cfg.agents}
        self.real, self.names, self.flown, self.index = physics.real, physics.names, physics.flown, physics.index
        self.unfiltered = {a.id for a in cfg.agents if not a.filter.enabled}  # they take no share of a pair
        self.l_m, self.radius_m = physics.l_m, physics.radius_m  # body-centre offsets, bounding radii [m]
        self.goals = np.array([self.slots[a].goal for a in self.names])  # (n, 3) m, world
        self.cells = cfg.uses_ticks  # each simulated agent gets its own tick message (swarm.net.cells)
        self.near_m = np.array([cfg.near_radius_m(a) for a in self.names]) if self.cells else np.zeros(0)  # m
        self.dt_ctrl = 1.0 / cfg.time.control_hz
        self.K = round(cfg.duration_s * cfg.time.control_hz)  # the last tick
        self.lockstep = cfg.time.mode is TimeMode.LOCKSTEP
        self.lag_ticks = int(cfg.time.max_lag_s * cfg.time.control_hz)  # realtime with real drones: catch_up
        self.counts = RunCounts()
        self.counter = tp.Counter()
        self.seq = 0
        self.others_alive: set[str] = set()
        self.phase = {"publish": 0.0, "wait": 0.0, "physics": 0.0}
        self.feed = RealDroneFeed(cfg, run, self.real, lambda: physics.t_s)  # the real drones' measurements
        self.wall0 = time.monotonic()
        self.stop = StopFlag()
        self.landing = False  # the launcher asked every drone to land (swarm.landing) ...
        self.land_from_s: float | None = None  # ... from this sim time [s]
        self.land_z_m = np.array([landing_height_m(cfg.agent(a)) for a in self.flown])  # (flown,) m
        self.script_end: Any = None  # a script's end of the run (script.enabled)
        self.ended_by_script = False

    # --- wiring -------------------------------------------------------------------
    def open(self, conf: Any) -> None:
        """The session, its publishers and subscribers, this world's liveliness, and the
        motion-capture relay of the real drones."""
        keys = self.keys
        self.session = session = tp.open_session(conf)
        self.token = tp.declare_liveliness(session, keys.alive("world"))
        self.cmd_in = tp.Inbox(session, keys.all_commands)
        self.script_end = tp.open_channel(session, keys.script_done, 8) if self.cfg.script.enabled else None
        self.live_sub = tp.liveliness_subscriber(session, keys.all_alive)
        self.pub_tick = {a: session.declare_publisher(keys.tick(a)) for a in self.flown if self.cells}
        self.pub_clock = session.declare_publisher(keys.clock)
        self.pub_status = session.declare_publisher(keys.status)
        self.pub_coll = session.declare_publisher(keys.collision)
        self.pub_stall = session.declare_publisher(keys.stall)
        self.land_sub = tp.open_channel(session, keys.land, 16)
        self.feed.open(session, keys)

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
                    self.physics.drones[name].dead = True
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
        if m.k >= slot.command_k:
            slot.monitor = m["monitor"]
            slot.fallbacks = m["fallbacks"] + m["ctrl_fallbacks"]
        if m.src in self.real:  # a real drone's command went to it by radio: recorded, not flown
            slot.command_k = max(slot.command_k, m.k)
            return
        u = m["u"]
        if u.shape != (4,) or m["level"] != self.physics.drones[m.src].level.value:
            counter.drop("command of wrong level or size")
            return
        if m.k < slot.command_k:
            return  # older than what we hold
        slot.command_k = m.k
        slot.behind = False  # it answers again (a backlog's oldest tick first): waited for again
        self.physics.send(m.src, u, m.t, m.k)
        sent = slot.sent_at.pop(m.k, None)
        if sent is not None:
            slot.answered += 1
            slot.latencies_s.add(time.monotonic() - sent)
            if m.k >= k_now:
                slot.on_time += 1

    def warm_up(self) -> None:
        """The first call of compiled code loads it (a few hundred ms), and compiles it when
        the kernel cache is cold (the first run after an install or an edit: seconds). Do
        both before any tick, with the argument types the ticks use, or a realtime world
        starts behind the wall clock: a real drone's motion-capture frames, stamped on that
        clock, then meet simulated drones from the past
        (``tests/integration/test_world_warm_up.py``)."""
        self.physics.warm_up()
        min_pair_distance(np.zeros((2, 3)))  # (measure: the closest pair)
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
        names, slots, feed, c = self.names, self.slots, self.feed, self.counts
        ds = self.physics.read()
        for i, a in enumerate(names):
            est = feed.latest(a) if a in self.real else None
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
        frames: dict[str, list] = {}
        if self.physics.mocap is not None:  # world.realism.sensing: what motion capture saw by now
            f_rows = [self.index[a] for a in self.flown]
            self.physics.capture(t, DroneStates(*(a[f_rows] for a in (ds.x_w, ds.v_w, ds.q, ds.Omega_b, ds.R))))
            frames = {a: self.physics.frames_of(a) for a in measured}
        flying = x_b[[not slots[a].dead for a in names]]
        if len(flying) >= 2:
            c.min_sep = min(c.min_sep, min_pair_distance(flying))
        if len(obs) and len(flying):
            c.min_clear = min(c.min_clear, float(surface_clearance(flying, obs).min()))
        at_goal = np.linalg.norm(ds.x_w - self.goals, axis=1) <= self.cfg.goal_tolerance_m
        for a, there in zip(names, at_goal.tolist(), strict=True):
            if there and slots[a].reached_at_s is None:
                slots[a].reached_at_s = t
        return TickView(ds, items, live, x_b, roster, measured, meas, frames)

    def poll_land(self, k: int) -> None:
        """The launcher's request to land every drone (swarm.landing): from tick ``k`` the run
        ends once every simulated drone is down, or ``time.land_timeout_s`` later (the real
        drones land after the ticks, :meth:`land_real_drones`)."""
        for s in tp.drain(self.land_sub):
            m = tp.decode_sample(s, self.run_id, self.counter, ("land",))
            if m is None:
                continue
            if m.src != "launcher":
                self.counter.drop("land: not from the launcher")
                continue
            if not self.landing:
                self.landing, self.land_from_s = True, k * self.dt_ctrl
                self.K = k + round(self.cfg.time.land_timeout_s * self.cfg.time.control_hz)
                print(f"world: landing every drone from t = {k * self.dt_ctrl:.2f} s ({m['why']})", file=sys.stderr)

    def is_done(self, k: int, view: TickView) -> bool:
        """The last tick (``duration_s``), every drone at its goal (``stop_when_all_reached``;
        not in a run a script steers, which lasts until the script ends it), a script's end, a
        signal, or no agent left; once landing on request, every simulated drone down."""
        if self.landing:
            sim = [j for j, a in enumerate(self.flown) if not self.slots[a].dead]
            rows = [self.index[self.flown[j]] for j in sim]
            landed = down(view.ds.x_w[rows], view.ds.v_w[rows], self.land_z_m[sim])
            return bool(k == self.K or landed or self.stop or not view.live)
        all_reached = all(s.reached_at_s is not None for s in self.slots.values() if not s.dead)
        by_goals = self.cfg.stop_when_all_reached and all_reached and not self.cfg.script.enabled
        return bool(k == self.K or by_goals or self.script_ended() or self.stop or not view.live)

    def script_ended(self) -> bool:
        """A script (its ``end`` message, from the run's ``script`` user) has ended the run."""
        if self.script_end is None:
            return self.ended_by_script
        for s in tp.drain(self.script_end):
            m = tp.decode_sample(s, self.run_id, self.counter, ("end",))
            if m is not None and m.src == access.SCRIPT:
                print(f"world: the script ended the run ({m['reason']})", file=sys.stderr, flush=True)
                self.script_end = None  # (ended: every later tick is past the end)
                self.ended_by_script = True
        return self.ended_by_script

    def publish(self, k: int, t: float, view: TickView, done: bool, status_every: int, skipped: int = 0) -> None:
        """Tick k out: the status (every ``status_every`` ticks and the last), the clock (with
        the ``skipped`` ticks before it flown unpublished: :meth:`catch_up`), and with
        neighbours by cells each agent's own tick."""
        slots, names, c = self.slots, self.names, self.counts
        now = time.monotonic()
        if not done:
            for a in view.live:
                if a not in self.real:  # the relay publishes real drones' measurements at the capture rate
                    slots[a].sent_at[k] = now
        if done or k % status_every <= skipped:  # (a status tick among the skipped: this one's)
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
                acting=monitor_acting(slots.values()),
                fallback_ids=[a for a in names if slots[a].fallbacks],
                fallback_ticks=[float(slots[a].fallbacks) for a in names if slots[a].fallbacks],
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
            frames=frames_wire([(j, f) for j, a in enumerate(view.measured) for f in view.frames.get(a, ())]),
            skipped=skipped,
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
                    frames=frames_wire([(0, f) for f in view.frames.get(aid, ())]),
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
        if any(slots[a].behind for a in live):
            self.poll_commands(k)  # (an answer from one behind: waited for again, even when no one else is)
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
        that came meanwhile; each substep places the real drones where motion capture saw
        them last, flies every simulated drone's command and notes the contacts."""
        sub = self.cfg.time.substeps
        for j in range(sub):
            if not self.lockstep:
                # take the commands that came meanwhile in one go (waking for each would take
                # the CPU from the agents computing them)
                time.sleep(max(0.0, self.wall0 + (k + j / sub) * self.dt_ctrl - time.monotonic()))
                self.poll_commands(k)
            self._substep(k, j, view)
        if not self.lockstep:
            for a in view.live:
                sl = self.slots[a]
                stale = [kk for kk in sl.sent_at if kk < k]
                self.counts.late += len(stale)
                for kk in stale:
                    sl.sent_at.pop(kk)

    def catch_up(self, k: int, view: TickView) -> int:
        """Realtime with real drones: when the wall clock has left tick ``k`` more than
        ``time.max_lag_s`` behind, fly ticks from k towards the wall clock's with the commands
        held (physics, contacts, the real drones' poses), unpublished, at most ``max_lag_s``
        of them at a time (a clock goes out between); their count (0: on time). The real
        drones do not wait for the world: a world that ran its backlog tick by tick would stay
        behind them. So a real drone's measurement, stamped at most ``max_lag_s`` after the
        physics (:meth:`_on_frame`), is at most about twice that after the newest clock."""
        if self.lockstep or not self.real:
            return 0
        behind = int((time.monotonic() - self.wall0) / self.dt_ctrl) - k
        if behind <= self.lag_ticks:
            return 0
        n = min(behind, self.K - k, max(1, self.lag_ticks))
        self.poll_commands(k)
        for kk in range(k, k + n):
            for j in range(self.cfg.time.substeps):
                self._substep(kk, j, view)
        self.counts.skipped += n
        return n

    def _substep(self, k: int, j: int, view: TickView) -> None:
        """Substep j of tick k: the commands that reach their drones by now, the real drones
        where motion capture saw them last, every simulated drone flown, the contacts."""
        self.physics.deliver(k)  # (world.realism.comms)
        poses = {}
        for a in self.real:
            est = self.feed.latest(a)
            if est is not None:
                poses[a] = (est.x_w, est.q)
        fs = view.ds if j == 0 and not self.real else None  # (`flown` order: every drone is flown)
        self._contacts(self.physics.substep(fs, j == 0, poses, view.ds.v_w), k)

    def _contacts(self, pairs: set[tuple[str, str]], k: int) -> None:
        """Count and publish the contacts that began in this substep."""
        c = self.counts
        for pair in pairs - c.touching:
            dead = any(x in self.slots and self.slots[x].dead for x in pair)
            if dead:
                c.dead_contacts += 1
            else:
                c.collisions += 1
            self._put(self.pub_coll, "collision", self.physics.t_s, k, a=pair[0], b=pair[1], dead=dead)
        c.touching = pairs

    # --- the run --------------------------------------------------------------------
    def loop(self) -> int:
        """Every tick, phase by phase, until done; returns the last tick."""
        status_every = max(1, round(self.cfg.time.control_hz / STATUS_HZ))
        k, skipped = 0, 0
        while k <= self.K:
            t_phase = time.perf_counter()
            t = k * self.dt_ctrl
            self.pace(k)
            self.poll_liveliness()
            view = self.measure(k, t)
            self.poll_land(k)
            done = self.is_done(k, view)
            self.publish(k, t, view, done, status_every, skipped)
            if done:
                break
            t_pub_end = time.perf_counter()
            self.phase["publish"] += t_pub_end - t_phase
            if self.lockstep:
                self.collect(k, t, view.live)
            t_wait_end = time.perf_counter()
            self.phase["wait"] += t_wait_end - t_pub_end
            self.step_physics(k, view)
            skipped = self.catch_up(k + 1, view)
            self.phase["physics"] += time.perf_counter() - t_wait_end
            k += 1 + skipped
        return k

    def land_real_drones(self) -> None:
        """Real drones land on their own measurements: keep relaying until they are gone."""
        until = time.monotonic() + self.cfg.time.land_timeout_s
        while any(self.slots[a].alive for a in self.real) and time.monotonic() < until and not self.stop:
            self.poll_liveliness()
            time.sleep(0.02)

    def summary(self, k: int, startup_cpu_s: float) -> dict[str, Any]:
        slots, c = self.slots.values(), self.counts
        lat = timing_sketch()
        for s in slots:
            lat.merge(s.latencies_s)
        answered = sum(s.answered for s in slots)
        return {
            "ticks": k,
            "t_s": k * self.dt_ctrl,
            "landing_from_s": self.land_from_s,  # sim time of the launcher's land request (None: none)
            "collisions": c.collisions,
            "dead_agent_contacts": c.dead_contacts,
            "stalls": c.stalls,
            "late": c.late,
            "skipped_ticks": c.skipped,
            "on_time_fraction": sum(s.on_time for s in slots) / (answered + c.late) if answered + c.late else None,
            "p99_tick_latency_ms": _ms(lat.get_quantile_value(0.99)),  # (within 1 %)
            "median_tick_latency_ms": _ms(lat.get_quantile_value(0.5)),
            "real_time_factor": k * self.dt_ctrl / (time.monotonic() - self.wall0),
            "cpu_s": time.process_time(),
            "startup_cpu_s": startup_cpu_s,
            "phase_wall_s": {n: round(v, 3) for n, v in self.phase.items()},
            "dropped": self.counter.dropped,
            "dropped_reasons": dict(self.counter.reasons),
            "braking_ticks": sum(d.braking_ticks for d in self.physics.drones.values()),
            "commands_lost": self.physics.commands_lost,  # world.realism.comms.command
            "mocap_frames_dropped": 0 if self.physics.mocap is None else self.physics.mocap.dropped,
            "mocap": self.feed.summary(),
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
        self.feed.start(self.wall0)
        try:
            k = self.loop()
            self.feed.end(time.monotonic() - self.wall0)
            if self.feed.relay is not None:
                self.land_real_drones()
        finally:
            self.feed.stop()
            self.token.undeclare()
            self.physics.close()
        print("WORLD_SUMMARY " + json.dumps(self.summary(k, startup_cpu_s)), file=sys.stderr)
        return 0


def main(cfg: ScenarioConfig, run: str, conf: Any, gui: bool = False, expect: tuple[str, ...] = ()) -> int:
    """The world process: ``swarm world``."""
    return World(cfg, run, gui).run(conf, expect)
