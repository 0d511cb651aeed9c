"""A running swarm scripted through its Python client (issue 68): real processes in lockstep
in the lab world. A script takes off, flies a square, swaps two drones and lands them, and
``metrics.json`` lists each order's arrival; wrong credentials, an order for a drone the
script may not steer, a forged drone, a goal that is not finite or out of bounds are each
refused with a clear error and nothing flies. Every wait is on the run's time or on
messages, with a deadline."""

from __future__ import annotations

import asyncio
import json
import time

import numpy as np
import pytest

from swarm.errors import RefusedError, ScriptError
from swarm.net import access
from swarm.net import transport as tp
from swarm.net.messages import encode
from swarm.runs.runfiles import read_records
from swarm.script import Swarm

from .conftest import scenario

SQUARE = ([-0.5, -0.5, 1.0], [0.5, -0.5, 1.0], [0.5, 0.5, 1.0], [-0.5, 0.5, 1.0])


def test_a_script_takes_off_flies_a_square_swaps_and_lands_the_swarm(tmp_path):
    cfg = scenario("script_lab.yaml", time={"mode": "lockstep"})
    with Swarm.launch(cfg, tmp_path / "s") as swarm:
        assert swarm.drones == ["cf1", "cf2", "cf3"] and swarm.steerable == swarm.drones
        up = swarm.takeoff(1.0, duration_s=2.0).wait(timeout_s=20.0)
        assert set(up) == {"cf1", "cf2", "cf3"}
        for d in swarm.drones:
            assert abs(swarm.state(d).pos_w[2] - 1.0) <= cfg.goal_tolerance_m + 0.05
        for corner in SQUARE:
            swarm.go_to("cf1", corner, duration_s=1.5).wait(timeout_s=20.0)
            assert np.linalg.norm(swarm.state("cf1").pos_w - corner) <= cfg.goal_tolerance_m + 0.05
        a, b = swarm.state("cf1").pos_w, swarm.state("cf2").pos_w
        swarm.go_to_many({"cf1": b, "cf2": a}).wait(timeout_s=40.0)
        snap = swarm.states()
        assert np.linalg.norm(snap.drones["cf1"].pos_w - b) <= cfg.goal_tolerance_m + 0.05
        assert np.linalg.norm(snap.drones["cf2"].pos_w - a) <= cfg.goal_tolerance_m + 0.05
        ticks = [snap.k for snap in swarm.stream(duration_s=0.25)]  # the blocking stream: ticks in order
        assert len(ticks) >= 2 and ticks == sorted(set(ticks))

        async def land() -> list[int]:  # the async forms: a stream, a sleep in run time, and an await
            seen = [snap.k async for snap in swarm.astream(duration_s=0.1)]
            t0 = swarm.now_s
            await swarm.asleep(0.2)
            assert swarm.now_s >= t0 + 0.2
            reports = await swarm.land()
            assert set(reports) == {"cf1", "cf2", "cf3"} and {r.state for r in reports.values()} == {"arrived"}
            return seen

        assert asyncio.run(land())
        ended_at = swarm.now_s
        swarm.end("the experiment is done")
    m = json.loads((tmp_path / "s" / "metrics.json").read_text())
    assert m["stop_reason"] == "completed" and m["finished"]
    assert m["duration_s"] < cfg.duration_s and m["duration_s"] >= ended_at  # the script ended it
    assert m["collisions"] == 0
    orders = m["orders"]
    actions = [(o["drone"], o["action"]) for o in orders]
    assert actions.count(("cf1", "goto")) == 4 + 1 and actions.count(("cf2", "goto")) == 1
    assert {o["action"] for o in orders} == {"takeoff", "goto", "land"}
    for o in orders:  # every order taken, then arrived, in the run's time
        assert o["refused"] is None and o["taken_s"] is not None and o["arrived_s"] is not None, o
        assert o["arrived_s"] >= o["taken_s"]
    corners = [o["goal_m"] for o in orders if o["drone"] == "cf1" and o["action"] == "goto"][:4]
    np.testing.assert_allclose(corners, SQUARE)


def test_wrong_credentials_forged_drones_and_bad_goals_are_refused(start_run, tmp_path):
    cfg = scenario("script_lab.yaml", time={"mode": "lockstep"}, script={"drones": ["cf1", "cf2"]})
    h = start_run(cfg, "refused")
    h.wait_sim_time(0.2)

    wrong = tmp_path / "wrong"
    wrong.mkdir(mode=0o700)
    (wrong / "users.txt").write_text("script:not-the-password\n")
    (wrong / "users.txt").chmod(0o600)
    with pytest.raises(ScriptError, match="refused this client"):
        Swarm.connect(h.out, secrets=wrong, timeout_s=5.0)

    swarm = Swarm.connect(h.out)
    try:
        start = {d: swarm.state(d).pos_w.copy() for d in swarm.drones}
        assert swarm.steerable == ["cf1", "cf2"]
        with pytest.raises(RefusedError, match="'cf3' is not one a script may steer"):
            swarm.go_to("cf3", [0.0, 1.5, 1.0])
        with pytest.raises(RefusedError, match="no drone 'cf9'"):
            swarm.go_to("cf9", [0.0, 1.5, 1.0])
        with pytest.raises(RefusedError, match="not finite"):
            swarm.go_to("cf1", [float("nan"), 0.0, 1.0])
        with pytest.raises(RefusedError, match="outside script.bounds_m"):
            swarm.go_to("cf1", [9.0, 0.0, 1.0])
        with pytest.raises(RefusedError, match="below its floor"):
            swarm.takeoff(0.1, drones="cf2")
        with pytest.raises(RefusedError, match="is not one a script may steer"):
            swarm.land(["cf1", "cf3"])  # a group with one it may not steer: none is sent

        # past the client, with the script's own credentials: the router refuses an order for a
        # drone the script may not steer, a command and a ROS 2 goal; the agent refuses a bad goal
        keys = tp.Keys(h.run)
        watch = h.session  # the launcher hears everything of the run
        heard = tp.open_channel(watch, f"{keys.root}/script/order/*")
        commands = tp.open_channel(watch, keys.command("cf3"))
        to_agent = tp.open_channel(watch, keys.ros2_goal("cf1"))
        raw = swarm.session
        probe = b"probe"  # not a message: the agent drops it
        s, deadline = None, time.monotonic() + 20.0
        while s is None and time.monotonic() < deadline:  # until the router routes the script's puts here
            raw.put(keys.order("cf1"), probe)
            s = tp.wait_sample(heard, time.monotonic() + 0.2)
        assert s is not None, "the script's orders for cf1 never reached the run"
        fly = encode("order", h.run, access.SCRIPT, 10**6, 0.0, 0, order=10**6, action="goto", x=[0.0, 1.5, 1.2],
                     yaw=0.0, speed=0.0)  # fmt: skip
        forged = encode("command", h.run, "cf3", 1, 0.0, 0, level="attitude", u=np.zeros(4))
        for _ in range(3):
            raw.put(keys.order("cf3"), fly)  # a drone it may not steer
            raw.put(keys.command("cf3"), forged)  # a drone's own command
            raw.put(keys.ros2_goal("cf1"), fly)  # the ROS 2 bridge's key
        bad = encode("order", h.run, access.SCRIPT, 10**6 + 1, 0.0, 0, order=10**6 + 1, action="goto",
                     x=[9.0, 0.0, 1.0], yaw=0.0, speed=0.0)  # fmt: skip
        raw.put(keys.order("cf1"), bad)  # allowed by the router: the agent checks it again
        for _ in range(30):
            raw.put(keys.order("cf1"), probe)
        got: list[str] = []
        deadline = time.monotonic() + 30.0
        while got.count(keys.order("cf1")) < 31 and time.monotonic() < deadline:
            s = tp.wait_sample(heard, deadline)
            if s is not None:
                got.append(str(s.key_expr))
        assert got.count(keys.order("cf1")) >= 31, got
        assert keys.order("cf3") not in got, "an order for a drone the script may not steer went through"
        assert all(tp.payload(c) != forged for c in tp.drain(commands)), "a forged command went through"
        assert not list(tp.drain(to_agent)), "the script reached an agent's ROS 2 goal key"
        deadline_s = swarm.now_s + 5.0
        swarm.pump_until(deadline_s, lambda: bool(swarm.reports_on({"cf1": 10**6 + 1})), "cf1's refusal")
        refused = swarm.reports_on({"cf1": 10**6 + 1})
        assert refused["cf1"].state == "refused" and "outside script.bounds_m" in refused["cf1"].why
        swarm.sleep(1.0)  # nothing flies: every drone still holds where it started
        for d in swarm.drones:
            assert np.linalg.norm(swarm.state(d).pos_w - start[d]) < 0.1, d
        swarm.end("refusals checked")
    finally:
        swarm.close()
    assert h.wait(timeout_s=120.0) == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert [o["refused"] is not None for o in m["orders"]] == [True]  # the one the router let through
    assert m["collisions"] == 0
    order_keys = {r["topic"] for r in read_records(h.out / "run.mcap") if r["kind"] == "report"}
    assert order_keys == {"/agent/cf1/report"}
