"""The world process: PyBullet physics, measurements out, commands in.

    swarm world CONFIG [--run RUN] [--port P] [--gui]

Each tick the world publishes one clock message (``swarm.messages``: the live agents,
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

import numpy as np

from swarm import transport as tp
from swarm.cells import near_lists
from swarm.config import ScenarioConfig, TimeMode
from swarm.control import AttitudeController, AttitudeSetpoint, OnboardController, onboard_rotor_thrusts
from swarm.crazyflie_fw import WDT_SHUTDOWN_S, WDT_STABILIZE_S
from swarm.messages import encode, warm_up
from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.rotation import quat_to_R
from swarm.scenario import items_to_arrays, min_pair_distance, obstacle_items, surface_clearance
from swarm.shutdown import StopFlag
from world.mocap import BodyEstimate, MocapRelay, connect
from world.physics import PhysicsWorld


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


def main(cfg: ScenarioConfig, run: str, conf, gui: bool = False, expect: tuple[str, ...] = ()) -> int:
    keys = tp.Keys(run)
    sim = PhysicsWorld(cfg.time.physics_hz, gui=gui or cfg.gui)
    slots: dict[str, DroneSlot] = {}
    real = {a.id for a in cfg.agents if a.backend == "crazyflie"}  # placed from motion capture
    unfiltered = {a.id for a in cfg.agents if not a.filter.enabled}  # they take no share of a pair
    firmware_death = cfg.failure.on_agent_death == "firmware"  # a dead agent's drone: the firmware's watchdog
    for a in cfg.agents:
        model = QuadModel(a.quad_params())
        sim.add_drone(
            a.id,
            model,
            np.asarray(a.start, float),
            a.yaw_rad,
            np.asarray(a.start_velocity, float),
            kinematic=a.id in real,
        )
        slots[a.id] = DroneSlot(
            model,
            a.command_level,
            OnboardController(model, a.yaw_rad),
            AttitudeController(model),
            np.asarray(a.final_goal),
        )
    for o in cfg.obstacles:
        if o.shape == "sphere":
            sim.add_sphere(o.id, np.asarray(o.center), o.radius_m, np.asarray(o.velocity))
        else:
            sim.add_cylinder(
                o.id, np.asarray(o.center), np.asarray(o.axis), o.radius_m, o.length_m, np.asarray(o.velocity)
            )

    stop = StopFlag()

    session = tp.open_session(conf)
    counter = tp.Counter()
    seq = 0
    token = tp.declare_liveliness(session, keys.alive("world"))
    cmd_in = tp.Inbox(session, keys.all_commands)
    live_sub = tp.liveliness_subscriber(session, keys.all_alive)
    pubs = {aid: session.declare_publisher(keys.measurement(aid)) for aid in real}  # motion capture
    cells = cfg.uses_cells  # each simulated agent gets its own tick message (swarm.cells)
    pub_tick = {a.id: session.declare_publisher(keys.tick(a.id)) for a in cfg.agents if cells and a.id not in real}
    pub_clock = session.declare_publisher(keys.clock)
    pub_status = session.declare_publisher(keys.status)
    pub_coll = session.declare_publisher(keys.collision)
    pub_stall = session.declare_publisher(keys.stall)
    others_alive: set[str] = set()

    # --- motion capture for the real drones: measurements at the capture rate --------
    relay: MocapRelay | None = None
    running = threading.Event()  # the relay publishes only while the run is on
    mocap_seq = [10**9]  # the relay thread's own sequence numbers
    wall0 = time.monotonic()
    dt_ctrl = 1.0 / cfg.time.control_hz

    def on_frame(aid: str, est: BodyEstimate) -> None:
        if not running.is_set():
            return
        t = time.monotonic() - wall0
        mocap_seq[0] += 1
        pubs[aid].put(encode("measurement", run, "world", mocap_seq[0], t, int(t / dt_ctrl), x=est.x_w, v=est.v_w,
                             q=est.q, w=est.Omega_b))  # fmt: skip

    if real and cfg.mocap is not None:  # (the config requires mocap when any drone is real)
        m = cfg.mocap
        bodies = {a.mocap_body: a.id for a in cfg.agents if a.id in real}
        relay = MocapRelay(
            connect(m.type, m.hostname, m.options), bodies, m.rate_hz, m.lost_after_s, m.velocity_filter_s,
            on_frame, lambda aid: None,
        ).start()  # fmt: skip

    def poll_liveliness() -> None:
        for name, up in tp.liveliness_events(live_sub):
            if name in slots:
                if up:
                    slots[name].alive = True
                elif slots[name].alive:
                    slots[name].alive = False
                    slots[name].dead = True
                    print(
                        f"world: agent {name} gone at wall {time.time():.4f}: {cfg.failure.on_agent_death}",
                        file=sys.stderr,
                    )
            elif up:
                others_alive.add(name)
            else:
                others_alive.discard(name)

    def poll_commands(k_now: int, wait_until: float | None = None) -> None:
        first = cmd_in.get(wait_until) if wait_until is not None else None
        for s in ([first] if first is not None else []) + list(cmd_in.drain()):
            m = tp.decode_sample(s, run, counter, ("command",), COMMAND_FIELDS)
            if m is None:
                continue
            slot = slots.get(m.src)
            if slot is None or slot.dead:
                counter.drop("command from unknown or dead agent")
                continue
            if str(s.key_expr) != keys.command(m.src):  # a header naming another agent than its key
                counter.drop("command whose sender is not its key's agent")
                continue
            if m.k > k_now + 1 or abs(m.t - m.k * dt_ctrl) > 2.0 * dt_ctrl:  # not an answer to a tick we sent
                counter.drop("command for a tick or time the world has not reached")
                continue
            if m["status"] != "ok":
                slot.infeasible += 1
            slot.solo = m["status"] != "ok"
            if m.src in real:  # a real drone's command went to it by radio: recorded, not flown
                slot.command_k = max(slot.command_k, m.k)
                continue
            u = m["u"]
            want = 4
            if u.shape != (want,) or m["level"] != slot.level.value:
                counter.drop("command of wrong level or size")
                continue
            if m.k < slot.command_k:
                continue  # older than what we hold
            slot.command, slot.command_k, slot.command_t_s = u, m.k, m.t
            sent = slot.sent_at.pop(m.k, None)
            if sent is not None:
                slot.answered += 1
                slot.latencies_s.append(time.monotonic() - sent)
                if m.k >= k_now:
                    slot.on_time += 1

    # The first call of compiled code loads it (a few hundred ms): do it before any tick,
    # or a realtime world starts behind the wall clock and bursts ticks to catch up.
    for sl in slots.values():
        st0 = QuadState.hover()
        sl.onboard.rotor_thrusts(st0, AttitudeSetpoint(0.0, 0.0, 0.0, sl.model.params.weight_N), sim.dt_s)
        sl.att.from_thrust_vector(st0, np.array([0.0, 0.0, sl.model.params.weight_N]))
        sl.onboard.yaw_sp_rad = sl.yaw_sp_rad
    warm_up()

    # --- wait for everyone ----------------------------------------------------------
    deadline = time.monotonic() + cfg.time.start_timeout_s
    while not all(s.alive for s in slots.values()) or not set(expect) <= others_alive:
        poll_liveliness()
        if stop or time.monotonic() > deadline:
            missing = [a for a, s in slots.items() if not s.alive] + sorted(set(expect) - others_alive)
            print(f"world: gave up waiting for {missing}", file=sys.stderr)
            token.undeclare()
            return 2
        time.sleep(0.005)

    K = round(cfg.duration_s * cfg.time.control_hz)
    # the status (progress, running metrics) at about STATUS_HZ, and always the last one: a
    # message every tick would wake the launcher and the recorder 100 times a second
    status_every = max(1, round(cfg.time.control_hz / STATUS_HZ))
    sub = cfg.time.substeps
    lockstep = cfg.time.mode is TimeMode.LOCKSTEP
    collisions = 0  # contacts among live agents' drones (and obstacles)
    dead_contacts = 0  # contacts of a dead agent's drone (landing, or left to the firmware)
    stalls = 0  # lockstep ticks that waited longer than stall_warn_s
    stall_warn_s = cfg.time.stall_warn_fraction * cfg.time.lockstep_timeout_s
    touching: set[tuple[str, str]] = set()
    min_sep, min_clear, late = math.inf, math.inf, 0
    wall0 = time.monotonic()
    startup_cpu_s = time.process_time()  # imports, PyBullet, compiled code, waiting for everyone
    running.set()
    k = 0
    done = False
    names = list(slots)
    flown = [a for a in names if a not in real]  # simulated drones: PyBullet flies them
    index = {a: i for i, a in enumerate(names)}
    l_m = np.array([slots[a].model.params.l_m for a in names])  # body-centre offsets [m]
    radius_m = np.array([slots[a].model.params.body_radius_m for a in names])  # bounding radii [m]
    goals = np.array([slots[a].goal for a in names])  # (n, 3) m, world
    near_m = np.array([cfg.near_radius_m(a) for a in names]) if cells else np.zeros(0)  # m
    onboard_consts: dict[tuple[str, ...], tuple[np.ndarray, ...]] = {}  # drones -> stacked gains
    phase = {"publish": 0.0, "wait": 0.0, "physics": 0.0}
    try:
        for k in range(K + 1):
            t_phase = time.perf_counter()
            t = k * dt_ctrl
            if not lockstep and k > 0:
                # realtime: publish tick k at its wall time k * dt, not right after the last
                # substep of tick k-1 (which runs at (k - 1/substeps) * dt); commands that
                # arrive until then answered tick k-1 in time
                target = wall0 + k * dt_ctrl
                while time.monotonic() < target:
                    poll_commands(k - 1, target)
            poll_liveliness()
            # ground truth for metrics and measurements (motion capture for real drones)
            ds = sim.read_states(names)
            for i, a in enumerate(names):
                est = relay.latest(a) if relay and a in real else None
                if est is not None:
                    ds.x_w[i], ds.v_w[i], ds.q[i], ds.Omega_b[i] = est.x_w, est.v_w, est.q, est.Omega_b
                    ds.R[i] = quat_to_R(est.q)
            items = obstacle_items(cfg.obstacles, t)
            obs = items_to_arrays(items)
            live = [a for a in names if slots[a].alive]
            # the roster: body centre [m], its velocity [m/s] and radius [m] of every drone,
            # in `names` order; the measurements of the simulated drones
            x_b = ds.x_w + l_m[:, None] * ds.R[:, :, 2]
            v_b = ds.v_w + l_m[:, None] * (ds.R[:, :, 0] * ds.Omega_b[:, 1:2] - ds.R[:, :, 1] * ds.Omega_b[:, 0:1])
            roster = np.hstack([x_b, v_b, radius_m[:, None]]).ravel()
            measured = [a for a in flown if slots[a].alive]  # a dead agent's drone is no longer measured
            rows = [index[a] for a in measured]
            meas = np.hstack([ds.x_w[rows], ds.v_w[rows], ds.q[rows], ds.Omega_b[rows]]).ravel()
            flying = x_b[[not slots[a].dead for a in names]]
            if len(flying) >= 2:
                min_sep = min(min_sep, min_pair_distance(flying))
            if len(obs) and len(flying):
                min_clear = min(min_clear, float(surface_clearance(flying, obs).min()))
            at_goal = np.linalg.norm(ds.x_w - goals, axis=1) <= cfg.goal_tolerance_m
            for a, there in zip(names, at_goal.tolist(), strict=True):
                if there and slots[a].reached_at_s is None:
                    slots[a].reached_at_s = t
            all_reached = all(slots[a].reached_at_s is not None for a in names if not slots[a].dead)
            done = bool(k == K or (cfg.stop_when_all_reached and all_reached) or stop or not live)
            wall = time.monotonic() - wall0
            now = time.monotonic()
            if not done:
                for a in live:
                    if a not in real:  # the relay publishes real drones' measurements at the capture rate
                        slots[a].sent_at[k] = now
            if done or k % status_every == 0:
                status = dict(
                    rtf=t / wall if wall > 0 else 0.0, min_sep=min(min_sep, 1e9), min_clear=min(min_clear, 1e9),
                    collisions=collisions, late=late, dropped=counter.dropped, live=live, done=done,
                    infeasible=sum(sl.infeasible for sl in slots.values()), stalls=stalls,
                    dead=[a for a in names if slots[a].dead],
                )  # fmt: skip
                seq += 1
                pub_status.put(encode("status", run, "world", seq, t, k, **status))
            seq += 1
            solo = [a for a in names if slots[a].solo or slots[a].dead or a in unfiltered]
            pub_clock.put(encode("clock", run, "world", seq, t, k, live=live, done=done, ids=names, xvr=roster,
                                 meas_ids=measured, meas=meas, items=items, solo=solo))  # fmt: skip
            if cells:  # each agent's own tick: its measurement and the live agents near it
                expected = np.array([slots[a].alive and not slots[a].dead for a in names])
                near = near_lists(x_b, expected, near_m)
                for aid in measured:
                    i = index[aid]
                    seq += 1
                    pub_tick[aid].put(encode("tick", run, "world", seq, t, k, x=ds.x_w[i], v=ds.v_w[i], q=ds.q[i],
                                           w=ds.Omega_b[i], near=[names[j] for j in near[i]], items=items,
                                           done=done))  # fmt: skip
            if done:
                break

            t_pub_end = time.perf_counter()
            phase["publish"] += t_pub_end - t_phase
            if lockstep:
                wait_from = time.monotonic()
                wait_until = wait_from + cfg.time.lockstep_timeout_s
                held: list[str] = []  # the agents still missing when the wait became a stall
                while True:
                    poll_liveliness()
                    waiting = [a for a in live if slots[a].alive and slots[a].command_k < k]
                    if not waiting or stop:
                        break
                    now = time.monotonic()
                    if not held and now - wait_from > stall_warn_s:
                        held = waiting
                        print(f"world: tick {k} (t = {t:.2f} s) has waited {now - wait_from:.2f} s for {waiting}",
                              file=sys.stderr)  # fmt: skip
                    if now > wait_until:
                        late += len(waiting)
                        for a in waiting:
                            slots[a].sent_at.pop(k, None)
                        break
                    # wake once the missing commands can all be here (not on each one), at the
                    # latest after 20 ms to look at liveliness
                    cmd_in.wait_for(len(waiting), min(wait_until, now + 0.02))
                    poll_commands(k)
                if held:
                    stalls += 1
                    waited = time.monotonic() - wait_from
                    print(f"world: tick {k} stalled {waited:.2f} s on {held}", file=sys.stderr)
                    seq += 1
                    pub_stall.put(encode("stall", run, "world", seq, t, k, agents=held, wait_s=waited))
            t_wait_end = time.perf_counter()
            phase["wait"] += t_wait_end - t_pub_end
            for j in range(sub):
                if not lockstep:
                    # follow the wall clock; take the commands that came meanwhile in one go
                    # (waking for each would take the CPU from the agents computing them)
                    time.sleep(max(0.0, wall0 + (k + j / sub) * dt_ctrl - time.monotonic()))
                    poll_commands(k)
                fs = ds if j == 0 and not real else sim.read_states(flown)  # simulated drones, `flown` order
                for a in real:  # real drones: where motion capture saw them last
                    est = relay.latest(a) if relay else None
                    if est is not None:
                        sim.set_pose(a, est.x_w, est.q)
                stale = set()
                if not lockstep:  # realtime: a rotor command older than the timeout is not flown
                    stale = {
                        a for a in names
                        if not slots[a].dead and slots[a].command is not None
                        and (slots[a].level is CommandLevel.ROTORS or cfg.time.late_command == "brake")
                        and sim.t_s - slots[a].command_t_s > cfg.time.command_timeout_s
                    }  # fmt: skip
                f_all = np.zeros((len(flown), 4))  # rotor thrusts [N]
                att = [
                    i for i, a in enumerate(flown) if (not slots[a].dead or firmware_death) and a not in stale
                    and (slots[a].level is CommandLevel.ATTITUDE or slots[a].command is None)
                ]  # fmt: skip
                if att:
                    att_names = tuple(flown[i] for i in att)
                    consts = onboard_consts.get(att_names)
                    if consts is None:
                        consts = onboard_consts[att_names] = (
                            *(np.stack([slots[a].onboard.consts[c][0] for a in att_names]) for c in range(4)),
                            np.array([slots[a].onboard.consts[4][0] for a in att_names]),
                        )  # fmt: skip
                    sp = np.array([_setpoint(slots[a], sim.t_s) for a in att_names])
                    for a, yaw_rate in zip(att_names, sp[:, 2].tolist(), strict=True):
                        slots[a].yaw_sp_rad += yaw_rate * sim.dt_s
                    f_all[att] = onboard_rotor_thrusts(
                        fs.q[att], fs.Omega_b[att], sp[:, 0], sp[:, 1],
                        np.array([slots[a].yaw_sp_rad for a in att_names]), sp[:, 3], *consts,
                    )  # fmt: skip
                attitude = set(att)
                for i, a in enumerate(flown):
                    sl = slots[a]
                    if i in attitude:
                        continue
                    if sl.dead:
                        landed = cfg.failure.on_agent_death == "motors_off" or fs.x_w[i, 2] < 0.05
                        if not landed:
                            f_all[i] = _velocity_hold(sl, fs.state(i), _DESCEND)
                    elif a in stale:
                        f_all[i] = _velocity_hold(sl, fs.state(i), _STOP)
                        if j == 0:
                            sl.braking_ticks += 1
                    else:  # rotor level: the agent's thrusts, held
                        f_all[i] = np.clip(sl.command, 0.0, sl.model.params.f_max_N)
                sim.apply_rotors_all(flown, f_all, fs)
                pairs = {p for p in sim.step() if "ground" not in p or _impact(p, index, ds.v_w)}
                for pair in pairs - touching:
                    dead = any(x in slots and slots[x].dead for x in pair)
                    if dead:
                        dead_contacts += 1
                    else:
                        collisions += 1
                    seq += 1
                    pub_coll.put(encode("collision", run, "world", seq, sim.t_s, k, a=pair[0], b=pair[1], dead=dead))
                touching = pairs
            phase["physics"] += time.perf_counter() - t_wait_end
            if not lockstep:
                for a in live:
                    sl = slots[a]
                    stale = [kk for kk in sl.sent_at if kk < k]
                    late += len(stale)
                    for kk in stale:
                        sl.sent_at.pop(kk)
        if relay is not None:
            # real drones land on their own measurements: keep relaying until they are gone
            until = time.monotonic() + cfg.time.land_timeout_s
            while any(slots[a].alive for a in real) and time.monotonic() < until and not stop:
                poll_liveliness()
                time.sleep(0.02)
    finally:
        running.clear()
        if relay is not None:
            relay.stop()
        token.undeclare()
        sim.close()
    lat = [x for s in slots.values() for x in s.latencies_s]
    answered = sum(s.answered for s in slots.values())
    summary = {
        "ticks": k, "t_s": k * dt_ctrl, "collisions": collisions, "dead_agent_contacts": dead_contacts,
        "stalls": stalls, "late": late,
        "on_time_fraction": sum(s.on_time for s in slots.values()) / (answered + late) if answered + late else None,
        "p99_tick_latency_ms": float(np.percentile(lat, 99) * 1e3) if lat else None,
        "median_tick_latency_ms": float(np.median(lat) * 1e3) if lat else None,
        "real_time_factor": k * dt_ctrl / (time.monotonic() - wall0), "cpu_s": time.process_time(),
        "startup_cpu_s": startup_cpu_s,
        "phase_wall_s": {n: round(v, 3) for n, v in phase.items()}, "dropped": counter.dropped,
        "braking_ticks": sum(s.braking_ticks for s in slots.values()),
        "mocap": None if relay is None else {"frames": relay.frames, "dropped_frames": relay.dropped_frames,
                                             "lost": sorted(relay.lost)},
    }  # fmt: skip
    print("WORLD_SUMMARY " + json.dumps(summary), file=sys.stderr)
    return 0
