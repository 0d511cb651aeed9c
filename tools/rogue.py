"""A run's own agent gone wrong, as a real process with that agent's credentials (issue 55).

    python -m tools.rogue CONFIG --run RUN --secrets DIR --id ID --mode MODE

It takes the place of agent ID's process: it declares ID's liveliness, hears the world's
clock, and holds its drone in a hover where it started (an attitude command of level thrust
each tick). Its states are its drone's true ones, as the world measures it, until
``BAD_FROM_S`` of sim time; then, by ``MODE``:

* ``flood``: :data:`FLOOD` states of each tick (its true one and the same again), 30,000 a second;
* ``nan``: its position not a number;
* ``far``: a kilometre away;
* ``fast``: a speed no airframe reaches;
* ``reorder``: each tick's true state, then the same tick again and one from 50 ticks ago;
* ``mute``: true states, and never a command (from the start).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from swarm.config import load
from swarm.model import body_centre
from swarm.net import transport as tp
from swarm.net.messages import clock_measurement, decode, encode

MODES = ("flood", "nan", "far", "fast", "reorder", "mute")
BAD_FROM_S = 1.0
FLOOD = 300  # states a tick in a flood (300 times an agent's rate); with 1000 the rogue's own puts made the test 34 s


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("config")
    ap.add_argument("--run", required=True)
    ap.add_argument("--secrets", type=Path, required=True)
    ap.add_argument("--id", required=True)
    ap.add_argument("--mode", choices=MODES, required=True)
    args = ap.parse_args()
    cfg = load(Path(args.config))
    me = cfg.agent(args.id)
    params = me.airframe.params()
    acc = tp.Access.of(cfg, args.run, tp.Role.AGENT, args.secrets, args.id)
    session = tp.open_session(tp.process_config(cfg, tp.Role.AGENT, acc))
    keys = tp.Keys(args.run)
    clock = tp.open_channel(session, keys.clock, 1 << 14)
    pub_state = session.declare_publisher(keys.state(args.id))
    pub_cmd = session.declare_publisher(keys.command(args.id))
    token = tp.declare_liveliness(session, keys.alive(args.id))
    hover = dict(
        level="attitude",
        u=np.array([0.0, 0.0, 0.0, params.weight_N]),  # roll, pitch [rad], yaw rate [rad/s], thrust [N]
        intervention=0.0,
        status="ok",
        solve_us=0.0,
        row_ids=[],
        h_rows=np.zeros(0),
        min_h=1e9,
        infeasible=0,
        goal_reached=True,
        dropped=0,
        est=np.zeros(0),  # (the world reads the monitor's action for its status; a command carries all of v11)
        monitor=0,
        breaches=0,
        live_margin=0.0,
        fallback="",
        fallbacks=0,
        ctrl_fallback="",
        ctrl_fallbacks=0,
    )
    # its commands numbered as an agent numbers them (2, 4, ...: a state before each), its
    # states apart: what the recording holds of it stays whole however it floods
    n_cmd, state_seq, states, sent_states = 0, 10**9, {}, 0
    deadline = time.monotonic() + cfg.time.start_timeout_s + 600.0
    while time.monotonic() < deadline:
        s = tp.wait_sample(clock, time.monotonic() + 0.5)
        if s is None:
            continue
        m = decode(tp.payload(s), args.run, ("clock",))
        if m["done"]:
            break
        meas = clock_measurement(m, args.id)
        if meas is None:
            continue
        c, cd, _ = body_centre(meas["x"], meas["v"], meas["q"], meas["w"], params.l_m)
        states[m.k] = (m.t, c, cd)
        bad = m.t >= BAD_FROM_S
        out: list[tuple[int, float, object, object]] = [(m.k, m.t, c, cd)]  # (tick, time, x, v)
        if bad and args.mode == "flood":
            out *= FLOOD
        elif bad and args.mode == "nan":
            out = [(m.k, m.t, np.array([math.nan, c[1], c[2]]), cd)]
        elif bad and args.mode == "far":
            out = [(m.k, m.t, c + np.array([1000.0, 0.0, 0.0]), cd)]
        elif bad and args.mode == "fast":
            out = [(m.k, m.t, c, np.array([0.0, 300.0, 0.0]))]
        elif bad and args.mode == "reorder":
            old = states.get(m.k - 50)
            out += [(m.k, m.t, c, cd)] + ([(m.k - 50, *old)] if old else [])
        for k, t, x, v in out:
            state_seq += 1
            pub_state.put(encode("state", args.run, args.id, state_seq, t, k, x=x, v=v, r=params.body_radius_m))
            sent_states += 1
        if args.mode != "mute":
            n_cmd += 1
            pub_cmd.put(encode("command", args.run, args.id, 2 * n_cmd, m.t, m.k, **hover))
        states.pop(m.k - 60, None)
    token.undeclare()
    print(f"rogue {args.id}: {args.mode}, {sent_states} states sent", file=sys.stderr, flush=True)
    tp.exit_when_sent(0, f"rogue {args.id}")


if __name__ == "__main__":
    main()
