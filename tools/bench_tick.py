"""What one agent's tick costs in Python without the transport, printed as JSON lines: the
agent process's own work between the bytes of its tick and bundle and the bytes of its state
and command (docs/benchmarks.md, "Where the time goes").

    python -m tools.bench_tick [--neighbours 5] [--ticks 2000] [--realism crazyflie_lab,ideal]

Agent ``cf1`` of a 16-drone ``circle_16`` swap (:class:`swarm.agents.agent.AgentProcess`,
built and warmed up as ``swarm agent`` builds it, with no session) is handed, tick after tick,
its bundle of ``--neighbours`` states of the tick before and its tick message (with one
motion-capture frame in the lab world), as Zenoh would hand them, in lockstep. The line gives
the calling thread's CPU per tick [us] for ``hear_us`` (decoding and checking both messages,
the neighbour table), ``act_us`` (the control step: estimator, tracker, neighbour rows,
filter) and ``encode_us`` (the state and command messages), their sum ``tick_us``, and the
neighbour rows the filter had. What Zenoh adds on a real swarm (the puts, the receive
threads) is in ``tools.bench_put`` and ``tools.bench_swarm``.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarm.agents.agent import AgentProcess, command_body
from swarm.config import resolve
from swarm.net import statewire
from swarm.net import transport as tp
from swarm.net.messages import StateBody, encode, encode_command, encode_state, frames_wire
from swarm.offline.scenario import SwapSettings, circle_swap
from swarm.realism.sensing import MocapFrame

RUN = "bench"
AGENTS = 16
CONTROL_HZ = 100.0


@dataclass(frozen=True)
class _Payload:
    data: bytes

    def to_bytes(self) -> bytes:
        return self.data


@dataclass(frozen=True)
class _Sample:
    """What the agent reads of a Zenoh sample: its key and payload."""

    key_expr: str
    payload: _Payload


def _messages(cfg: Any, neighbours: int, ticks: int, lab: bool) -> list[tuple[_Sample, _Sample]]:
    """Per tick k >= 1: cf1's bundle (its neighbours' states of tick k - 1, on their start
    points drawn in to a third) and its tick message."""
    keys, ids = tp.Keys(RUN), [a.id for a in cfg.agents]
    near = ids[1 : 1 + neighbours]
    x = {a.id: np.asarray(a.start, float) / 3.0 for a in cfg.agents}
    z, q = np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])
    out = []
    for k in range(1, ticks + 1):
        t = k / CONTROL_HZ
        states = [statewire.encode_state(RUN, a, k, t - 1 / CONTROL_HZ, k - 1, x[a], z, 0.07) for a in near]
        bundle = statewire.encode_bundle(RUN, "cf1", k, t - 1 / CONTROL_HZ, k - 1, states)
        frames = frames_wire([(0, MocapFrame(0, k, t, t, x["cf1"], q))] if lab else [])
        tick = encode("tick", RUN, "world", k, t, k, x=x["cf1"], v=z, q=q, w=z, near=near, items=[], gone=[],
                      done=False, frames=frames)  # fmt: skip
        out.append((_Sample(keys.bundle("cf1"), _Payload(bundle)), _Sample(keys.tick("cf1"), _Payload(tick))))
    return out


def bench(neighbours: int, ticks: int, realism: str) -> dict[str, Any]:
    settings = SwapSettings(neighbours="agents", realism=realism, control_hz=CONTROL_HZ, duration_s=ticks / CONTROL_HZ)
    cfg = resolve(circle_swap(AGENTS, 0.35 * AGENTS, settings, name=f"circle_{AGENTS}"), RUN)
    agent = AgentProcess(cfg, "cf1", RUN)
    keys = tp.Keys(RUN)
    agent.meas_key, agent.tick_key = keys.measurement("cf1"), keys.tick("cf1")  # (what open() sets)
    warm = 100
    messages = _messages(cfg, neighbours, ticks + warm, realism != "ideal")
    hear_s = act_s = encode_s = 0.0
    rows = 0
    for i, (bundle, tick) in enumerate(messages):
        t0 = time.thread_time()
        agent.handle(bundle)
        agent.handle(tick)
        msg = agent.next_message()
        t1 = time.thread_time()
        assert msg is not None, "the tick was not complete"
        result = agent.act(msg)
        assert result is not None
        t2 = time.thread_time()
        agent.seq += 1
        encode_state(RUN, "cf1", agent.seq, msg.t, msg.k, StateBody(result.x_b_w, result.v_b_w, 0.07, result.solo))
        encode_command(RUN, "cf1", agent.seq, msg.t, msg.k, command_body(result), agent.counter.dropped)
        t3 = time.thread_time()
        if i >= warm:
            hear_s, act_s, encode_s = hear_s + t1 - t0, act_s + t2 - t1, encode_s + t3 - t2
            rows = len(result.row_ids)
    us = 1e6 / ticks
    return {
        "realism": realism,
        "neighbours": neighbours,
        "ticks": ticks,
        "hear_us": round(hear_s * us, 1),
        "act_us": round(act_s * us, 1),
        "encode_us": round(encode_s * us, 1),
        "tick_us": round((hear_s + act_s + encode_s) * us, 1),
        "rows": rows,
        "dropped": agent.counter.dropped,
    }


def main(neighbours: list[int], ticks: int, realisms: list[str]) -> None:
    for realism in realisms:
        for n in neighbours:
            print(json.dumps(bench(n, ticks, realism)), flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--neighbours", default="5")
    ap.add_argument("--ticks", type=int, default=2000)
    ap.add_argument("--realism", default="crazyflie_lab,ideal")
    args = ap.parse_args()
    main([int(n) for n in args.neighbours.split(",")], args.ticks, args.realism.split(","))
