"""A run's own agent that misbehaves, injected by a real process with that agent's
credentials in place of its agent (``tools/rogue.py``, issue 55): it floods,
sends NaN, a position a kilometre away, an impossible speed, repeated and reordered ticks,
or never a command. Its drone hovers where it started, on the others' way. The receivers
drop and count what it sends, the metrics name it, and the others fly home without contact.

In a star (the default) the bundle relay meets the rogue's states first; in a mesh each
agent's neighbour table does."""

from __future__ import annotations

import json
import sys

import pytest

from swarm.net import statewire
from swarm.runs.launch import RunHandle
from tools.rogue import FLOOD

from .conftest import scenario

ROGUE = "cf3"
AGENTS = [
    {"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [4.0, 0.0, 1.0]},
    {"id": "cf2", "start": [4.0, 0.05, 1.0], "goal": [0.0, 0.05, 1.0]},
    {"id": ROGUE, "start": [2.0, 0.0, 1.0], "goal": [2.0, 0.0, 1.0]},  # it hovers between them
]
# what the receivers count against the rogue, by its fault
REASONS = {
    "flood": {statewire.REPEATED},
    "nan": {"state: not finite, or a negative radius", "x: expected finite numbers"},
    "far": {statewire.OUTSIDE},
    "fast": {statewire.TOO_FAST},
    "reorder": {statewire.REPEATED, statewire.OUT_OF_ORDER},
}


def _run(start_run, mode: str, topology: str) -> tuple[dict, RunHandle]:
    cfg = scenario(
        "swap_2.yaml",
        name=f"rogue_{mode}",
        duration_s=12.0,
        agents=AGENTS,
        network={"topology": topology},
        # in the mesh every agent hears every other's own state key (by cells, a state goes to its cell)
        neighbours={"interest": "all"} if topology == "mesh" else {},
        time={"lockstep_timeout_s": 1.0},  # (an agent that never answers costs the world one timeout)
    )
    h = start_run(cfg, f"{mode}-{topology}", stand_ins={ROGUE: ("tools.rogue", ["--mode", mode])})
    assert h.wait() == "completed", (h.out / "logs" / f"agent-{ROGUE}.log").read_text()[-2000:]
    return json.loads((h.out / "metrics.json").read_text()), h


def _safe_and_home(m: dict) -> None:
    assert m["collisions"] == 0 and m["margin_violations"] == 0, (m["collision_pairs"], m["margin_violation_pairs"])
    assert m["lost_agents"] == [] and m["all_reached_goal"], {a: v["reached_goal"] for a, v in m["agents"].items()}
    # the honest agents went round the hovering rogue
    assert m["min_separation_m"] > 2 * 0.07, m["min_separation_m"]


@pytest.mark.parametrize(
    ("mode", "topology"),
    [
        # the relay (star) floods, a NaN and repeated and old ticks; in the mesh each agent's compiled
        # table a state far outside the world (the relay's and the table's plausibility checks are one
        # rule, statewire.Plausible; "fast" and the other pairs are in tests/unit/test_insiders.py)
        ("flood", "star"),
        ("nan", "star"),
        ("reorder", "star"),
        ("far", "mesh"),
    ],
)
def test_a_rogue_agents_bad_states_are_dropped_counted_and_named(start_run, mode, topology):
    m, h = _run(start_run, mode, topology)
    _safe_and_home(m)
    assert list(m["offenders"]) == [ROGUE], m["offenders"]
    o = m["offenders"][ROGUE]
    assert set(o["reasons"]) <= REASONS[mode] and o["dropped"] > 0, o
    receivers = ["router"] if topology == "star" else ["agent-cf1", "agent-cf2"]
    assert set(receivers) <= set(o["dropped_by"]), o
    if mode == "flood":  # all but one of every tick's FLOOD, from 1 s on
        assert o["dropped"] >= (FLOOD - 1) * 100 * len(receivers), o
    # its commands were flown and recorded as any agent's: the recording is whole
    assert m["complete"] is True and m["lost_messages"] == 0, m["recording_gaps"]
    # the honest agents waited for its states at most once (a whole timeout), not once per tick
    timeout_s = h.cfg.time.lockstep_timeout_s
    assert sum(w["wait_s"] >= 0.99 * timeout_s for w in m["stall_events"] if ROGUE not in w["agents"]) <= 1, m


def test_an_agent_that_never_commands_costs_one_timeout_and_is_named(start_run):
    m, h = _run(start_run, "mute", "star")
    _safe_and_home(m)
    o = m["offenders"][ROGUE]
    assert o["dropped"] == 0 and o["longest_silence_s"] > 0.9 * m["duration_s"], o  # live all along, never a command
    assert list(m["offenders"]) == [ROGUE]
    # the world waited for it once (a stall of one timeout), then no more: not a timeout per tick
    waits = m["stall_events"]
    assert waits[0]["agents"] == [ROGUE] and len(waits) <= 3, waits
    assert sum(w["wait_s"] for w in waits) < 3 * h.cfg.time.lockstep_timeout_s, waits
    assert m["late_ticks"] >= 0.9 * m["duration_s"] * h.cfg.time.control_hz


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
