"""A forged command from an outside session (issue 20's attack): a header naming another
agent than its key, or a tick and time the world has not reached, with zero thrust. The
world drops and counts both, and the victim flies on. (Who may publish on an agent's key
at all is for Zenoh's access control, not yet set up: a plausible forged command on the
victim's own key is still flown.)"""

from __future__ import annotations

import json

import numpy as np

from swarm.messages import encode

from .conftest import scenario


def test_forged_commands_are_dropped_and_the_victim_flies_on(start_run):
    h = start_run(scenario("swap_2.yaml"), "forged")
    h.wait_sim_time(1.0)
    body = dict(level="attitude", u=np.array([0.0, 0.0, 0.0, 0.0]), intervention=0.0, status="ok", solve_us=0.0,
                row_ids=[], h_rows=np.zeros(0), min_h=0.0, infeasible=0, goal_reached=False, dropped=0)  # fmt: skip
    evil = h.session.declare_publisher(f"swarm/{h.run}/agent/evil/command")
    own = h.session.declare_publisher(f"swarm/{h.run}/agent/cf1/command")
    for i in range(5):
        evil.put(encode("command", h.run, "cf1", 10**9 + i, 1.2, 120, **body))  # header says cf1, key says evil
        own.put(encode("command", h.run, "cf1", 10**9 + i, 1e9, 10**9, **body))  # a tick from the far future
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["all_reached_goal"], m
    assert m["agents"]["cf1"]["path_length_m"] > 3.5  # it flew its swap, never brought down
    log = (h.out / "logs" / "world.log").read_text()
    assert "sender is not its key's agent" in log or m["dropped_messages"] >= 10, log[-2000:]
