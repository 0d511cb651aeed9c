"""The agent process: one quadrotor's reference controller and C3BF-QP safety filter.

    python -m agents.agent CONFIG --run RUN --id ID [--port P]   (or: swarm agent CONFIG --id ID)

Every tick (each new measurement): drain what arrived (neighbour states, obstacles,
liveliness), build one row per obstacle and per neighbour in range, filter the
reference command, publish this agent's state and then its command. In lockstep the
agent first waits (with a deadline) for every live neighbour's state of the previous
tick, so two runs of one config compute the same commands.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import time

import numpy as np

from swarm import transport as tp
from swarm.config import ScenarioConfig, TimeMode, load
from swarm.control import AttitudeController, PathTracker, setpoint_from_thrust_vector, yaw_of
from swarm.filter import FilterStatus, SafetyFilter
from swarm.messages import encode
from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.neighbours import NeighbourTable
from swarm.obstacles import ObstacleArrays
from swarm.rotation import quat_to_R
from swarm.scenario import items_to_arrays


def main(cfg: ScenarioConfig, agent_id: str, run: str, conf) -> int:  # noqa: ANN001, C901
    me = cfg.agent(agent_id)
    keys = tp.Keys(run)
    model = QuadModel(me.airframe.params())
    level = me.command_level
    filt = SafetyFilter(model, me.filter.filter_config(level))
    tracker = PathTracker(me.path(), me.speed_mps)
    att = AttitudeController(model)
    f = cfg.failure
    table = NeighbourTable(f.neighbour_timeout_s, f.neighbour_growth_mps, f.neighbour_hard_limit_s, f.on_lost)
    goal = np.asarray(me.final_goal)
    lockstep = cfg.time.mode is TimeMode.LOCKSTEP
    others = {a.id for a in cfg.agents} - {agent_id}

    stop = {"now": False}

    def on_signal(signum, frame):  # noqa: ANN001, ARG001
        stop["now"] = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    session = tp.open_session(conf)
    counter = tp.Counter()
    meas_in = tp.Inbox(session, keys.measurement(agent_id), 256)
    state_sub = tp.open_channel(session, keys.all_states, 1 << 14)
    obs_sub = tp.open_channel(session, keys.obstacles, 256)
    clock_sub = tp.open_channel(session, keys.clock, 256)
    live_sub = tp.liveliness_subscriber(session, keys.all_alive)
    # first filter call loads numba's compiled code (about a second): do it before the
    # world can see us, so no tick pays for it
    filt.filter(QuadState.hover(me.start), filt.input_set.lb.copy(), ObstacleArrays.empty())
    pub_state = session.declare_publisher(keys.state(agent_id))
    pub_cmd = session.declare_publisher(keys.command(agent_id))
    token = tp.declare_liveliness(session, keys.alive(agent_id))

    own_state_key = keys.state(agent_id)
    alive: set[str] = set()
    world_seen = False
    obstacles = ObstacleArrays.empty()
    obstacles_k = -1
    seq = 0
    infeasible = 0
    min_h = math.inf
    reached = False
    exit_code = 0
    tick_s: list[float] = []
    tick_s: list[float] = []  # wall time from measurement received to command sent

    def drain_background() -> None:
        nonlocal obstacles, obstacles_k, world_seen
        for name, up in tp.liveliness_events(live_sub):
            if up:
                alive.add(name)
                world_seen |= name == "world"
            else:
                alive.discard(name)
                table.mark_gone(name)
        for s in tp.drain(state_sub):
            if str(s.key_expr) == own_state_key:
                continue  # our own state comes back to us: skip it before decoding
            m = tp.decode_sample(s, run, counter, ("state",))
            if m is not None:
                table.update(m.src, m.t, m.k, m["x"], m["v"], m["r"])
        for s in tp.drain(obs_sub):
            m = tp.decode_sample(s, run, counter, ("obstacles",))
            if m is not None and m.k >= obstacles_k:
                obstacles, obstacles_k = items_to_arrays(m["items"]), m.k

    try:
        while not stop["now"]:
            sample = meas_in.get(time.monotonic() + 0.05)
            drain_background()
            for s in tp.drain(clock_sub):
                m = tp.decode_sample(s, run, counter, ("clock",))
                if m is not None and m["done"]:
                    stop["now"] = True
            if world_seen and "world" not in alive:
                print(f"agent {agent_id}: the world is gone, stopping", file=sys.stderr)
                break
            if sample is None:
                continue
            msg = tp.decode_sample(sample, run, counter, ("measurement",))
            if not lockstep:  # realtime: only the newest measurement matters
                for s in meas_in.drain():
                    newer = tp.decode_sample(s, run, counter, ("measurement",))
                    if newer is not None and (msg is None or newer.k > msg.k):
                        msg = newer
            if msg is None:
                continue
            t_recv = time.perf_counter()
            k, t = msg.k, msg.t
            if lockstep:
                # this tick's obstacles and every live neighbour's state of tick k-1
                deadline = time.monotonic() + cfg.time.lockstep_timeout_s
                while time.monotonic() < deadline and not stop["now"]:
                    need_obs = bool(cfg.obstacles) and obstacles_k < k
                    waiting = [
                        n for n in alive if n in others and table.latest_k(n) < k - 1
                    ]  # fmt: skip
                    if not need_obs and not waiting:
                        break
                    time.sleep(0.0001)
                    drain_background()
            state = QuadState(msg["x"], msg["v"], msg["q"], msg["w"])
            R = quat_to_R(state.q)
            x_b = state.x_w + model.params.l_m * R[:, 2]
            wx, wy, _wz = state.Omega_b
            v_b = state.v_w + model.params.l_m * (R[:, 0] * wy - R[:, 1] * wx)  # l R (Omega x e3)
            F_ref = tracker.thrust_vector(model, state.x_w, state.v_w)
            u_ref = att.from_thrust_vector(state, F_ref, me.yaw_rad) if level is CommandLevel.ROTORS else F_ref
            rows = ObstacleArrays.concat([obstacles, table.arrays(t)])
            if me.filter.enabled:
                res = filt.filter(state, u_ref, rows)
                u, status = res.u, res.status
                if status is not FilterStatus.OK:
                    infeasible += 1
                if res.h.size:
                    min_h = min(min_h, res.min_h)
                intervention, solve_us = res.intervention, res.solve_time_s * 1e6
            else:
                u, status, intervention, solve_us = u_ref, FilterStatus.OK, 0.0, 0.0
            reached = reached or bool(np.linalg.norm(state.x_w - goal) <= cfg.goal_tolerance_m)
            seq += 1
            pub_state.put(
                encode(
                    "state",
                    run,
                    agent_id,
                    seq,
                    t,
                    k,
                    x=x_b,
                    v=v_b,
                    r=model.params.body_radius_m,
                    goal_reached=reached,
                    min_h=min_h if math.isfinite(min_h) else 1e9,
                    status=status.value,
                    infeasible=infeasible,
                    solve_us=solve_us,
                    dropped=counter.dropped,
                )  # fmt: skip
            )
            if level is CommandLevel.ATTITUDE:
                sp = setpoint_from_thrust_vector(u, yaw_of(state), me.yaw_rad)
                cmd = np.array([sp.roll_rad, sp.pitch_rad, sp.yaw_rate_radps, sp.thrust_N])
            else:
                cmd = u
            seq += 1
            pub_cmd.put(
                encode(
                    "command",
                    run,
                    agent_id,
                    seq,
                    t,
                    k,
                    level=level.value,
                    u=cmd,
                    intervention=intervention,
                    status=status.value,
                )  # fmt: skip
            )
            tick_s.append(time.perf_counter() - t_recv)
    finally:
        token.undeclare()
    if tick_s:
        ts = np.array(tick_s) * 1e3
        print(
            f"agent {agent_id}: {len(ts)} ticks, compute median {np.median(ts):.3f} ms,"
            f" p99 {np.percentile(ts, 99):.3f} ms,"
            f" cpu {time.process_time():.2f} s",
            file=sys.stderr,
        )
    if counter.dropped:
        print(f"agent {agent_id}: dropped {counter.dropped} messages {counter.reasons}", file=sys.stderr)
    return exit_code


def run_from_args(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="c3swarm agent process")
    ap.add_argument("config")
    ap.add_argument("--run", required=True)
    ap.add_argument("--id", required=True)
    ap.add_argument("--port", type=int)
    ap.add_argument("--mode", choices=["lockstep", "realtime"])
    args = ap.parse_args(argv)
    over: dict = {}
    if args.port is not None:
        over["network"] = {"port": args.port}
    if args.mode:
        over["time"] = {"mode": args.mode}
    cfg = load(args.config, over)
    return main(cfg, args.id, args.run, tp.process_config(cfg.network, is_world=False))


if __name__ == "__main__":
    code = run_from_args()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # no interpreter teardown: zenoh sessions can hang there
