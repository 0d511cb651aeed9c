"""Metrics from records."""

import math

import numpy as np
import pytest

from swarm.config import resolve
from swarm.offline.metrics import compute


def test_metrics_from_synthetic_records():
    cfg = resolve(
        {
            "version": 1,
            "name": "m",
            "duration_s": 1.0,
            "goal_tolerance_m": 0.1,
            "agents": [
                {"id": "a", "start": [0, 0, 1], "goal": [1, 0, 1], "airframe": {"l_m": 0.0}},
                {"id": "b", "start": [3, 0, 1], "goal": [5, 0, 1], "airframe": {"l_m": 0.0}},
            ],
            "obstacles": [{"id": "s", "shape": "sphere", "center": [0.5, 1.0, 1.0], "radius_m": 0.5}],
        }
    )
    recs = []
    for k in range(11):
        for aid, x in (("a", [0.1 * k, 0, 1]), ("b", [3.0 - 0.1 * k, 0, 1])):
            topic = f"/swarm/r/world/{aid}/measurement"
            recs.append(
                {"kind": "measurement", "topic": topic, "k": k, "t": 0.1 * k, "x": x, "q": [0, 0, 0, 1], "v": [0, 0, 0]}
            )
        sphere = {"id": "s", "shape": "sphere", "c": [0.5, 1.0, 1.0], "cd": [0, 0, 0], "r": 0.5, "a": [0, 0, 0]}
        recs.append({"kind": "obstacles", "k": k, "t": 0.1 * k, "items": [sphere]})
    recs.append({"kind": "collision", "a": "a", "b": "s", "k": 3, "t": 0.3})
    recs.append(
        {
            "kind": "status",
            "t": 1.0,
            "k": 10,
            "rtf": 2.0,
            "late": 1,
            "dropped": 3,
            "live": ["a", "b"],
            "min_sep": 1.0,
            "min_clear": 0.5,
            "collisions": 1,
            "done": True,
        }
    )
    m = compute(cfg, recs, recorder_dropped=2)
    assert m["collisions"] == 1 and m["late_ticks"] == 1 and m["dropped_messages"] == 5
    assert m["min_separation_m"] == pytest.approx(1.0)  # at k = 10: 1.0 vs 2.0
    assert m["min_obstacle_clearance_m"] == pytest.approx(0.5)  # (0.5, 0, 1) is 1.0 from the centre
    assert m["agents"]["a"]["reached_goal"] and m["agents"]["a"]["time_to_goal_s"] == pytest.approx(0.9)
    assert not m["agents"]["b"]["reached_goal"] and not m["all_reached_goal"]
    assert m["agents"]["a"]["path_length_m"] == pytest.approx(1.0)


def test_path_deviation_is_the_distance_to_the_polyline():
    from swarm.offline.metrics import path_deviation

    path = np.array([[0.0, 0, 1], [2.0, 0, 1], [2.0, 2, 1]])
    pts = np.array([[1.0, 0.3, 1], [2.5, 1.0, 1], [0.0, 0, 1]])
    assert path_deviation(pts, path) == pytest.approx(0.5)
    assert path_deviation(pts[:1], path[:1]) == pytest.approx(np.hypot(1.0, 0.3))


def test_metrics_from_a_stream_read_once_are_those_of_the_list(monkeypatch):
    """A long run's records come as a stream (read once, never held): the figures of a tick are
    taken once the measurements are the window past it, so a tick's late measurement still
    counts and the metrics are those of the whole list."""
    import swarm.offline.metrics as metrics

    monkeypatch.setattr(metrics, "TICK_WINDOW", 3)  # ticks taken during the stream, not only at its end
    cfg = resolve(
        {
            "version": 1,
            "name": "s",
            "duration_s": 3.0,
            "agents": [
                {"id": "a", "start": [0, 0, 1], "goal": [2, 0, 1], "airframe": {"l_m": 0.0}},
                {"id": "b", "start": [2, 0, 1], "goal": [0, 0, 1], "airframe": {"l_m": 0.0}},
            ],
        }
    )
    recs = []
    for k in range(30):
        x = 0.06 * k
        for aid, p in (("a", [x, 0.0, 1.0]), ("b", [2.0 - x, 0.05, 1.0])):
            recs.append({"kind": "measurement", "agent": aid, "topic": "/c", "k": k, "t": 0.1 * k, "x": p,
                         "q": [0, 0, 0, 1], "v": [0.6, 0, 0]})  # fmt: skip
    late = recs.pop(2 * 17 + 1)  # b's measurement of tick 17 (the closest pair) arrives two ticks late
    recs.insert(2 * 19, late)
    recs.append({"kind": "status", "t": 2.9, "k": 29, "rtf": 1.0, "late": 0, "dropped": 0, "live": ["a", "b"],
                 "done": True})  # fmt: skip
    streamed = compute(cfg, (r for r in recs))
    listed = compute(cfg, sorted(recs, key=lambda r: r["k"]))
    assert streamed == listed
    assert streamed["min_separation_m"] == pytest.approx(math.hypot(0.04, 0.05))  # tick 17: 1.02 and 0.98


def test_metrics_count_the_safety_monitors_actions_and_breaches_per_agent_and_run():
    """The verdicts the recorded commands carry: ticks per action and per breach (the bitmask's
    names), the first slow-or-stronger, whether the monitor landed the agent, the largest live
    margin, and the estimate's largest deviation and age (est of 9 floats)."""
    from swarm.safety.monitor import Action, Breach

    cfg = resolve(
        {
            "version": 1,
            "name": "mon",
            "duration_s": 1.0,
            "agents": [
                {"id": "a", "start": [0, 0, 1], "goal": [1, 0, 1], "airframe": {"l_m": 0.0}},
                {"id": "b", "start": [3, 0, 1], "goal": [5, 0, 1], "airframe": {"l_m": 0.0}},
            ],
        }
    )
    # a: two ticks of estimate_std (slow), one of estimate_age (hold), then lost (land) twice, and
    # a warn on tick_overrun at the start; b: nothing but margins, no estimate
    a_verdicts = [
        (Action.WARN, Breach.TICK_OVERRUN),
        (Action.NONE, Breach.NONE),
        (Action.SLOW, Breach.ESTIMATE_STD),
        (Action.SLOW, Breach.ESTIMATE_STD | Breach.NEIGHBOUR_AGE),
        (Action.HOLD, Breach.ESTIMATE_AGE),
        (Action.LAND, Breach.ESTIMATE_LOST),
        (Action.LAND, Breach.NONE),
    ]
    recs = []
    for k, (action, breaches) in enumerate(a_verdicts):
        t = 0.1 * k
        for aid, x in (("a", [0.0, 0, 1]), ("b", [3.0, 0, 1])):
            recs.append({"kind": "measurement", "agent": aid, "topic": "/c", "k": k, "t": t, "x": x,
                         "q": [0, 0, 0, 1], "v": [0, 0, 0]})  # fmt: skip
        cmd = {"kind": "command", "k": k, "t": t, "status": "ok", "min_h": 1.0, "solve_us": 10.0, "infeasible": 0}
        est = [0.0, 0, 1, 0, 0, 0, 0.01 * k, 0.002, 0.05 * k]  # x, v, position sd, velocity sd, age
        recs.append({**cmd, "src": "a", "monitor": int(action), "breaches": int(breaches),
                     "live_margin": 0.01 * k, "est": est})  # fmt: skip
        recs.append({**cmd, "src": "b", "monitor": 0, "breaches": 0, "live_margin": 0.02, "est": []})
    recs.append({"kind": "status", "t": 0.6, "k": 6, "live": ["a", "b"], "done": True})
    m = compute(cfg, recs)
    a, b = m["agents"]["a"], m["agents"]["b"]
    assert a["monitor"]["action_ticks"] == {"warn": 1, "slow": 2, "hold": 1, "land": 2}
    assert a["monitor"]["breach_ticks"]["estimate_std"] == 2
    assert a["monitor"]["breach_ticks"]["neighbour_age"] == 1
    assert a["monitor"]["breach_ticks"]["estimate_lost"] == 1 and a["monitor"]["breach_ticks"]["tick_overrun"] == 1
    assert a["monitor"]["breach_ticks"]["infeasible"] == 0
    assert a["monitor"]["first_action_s"] == pytest.approx(0.2)  # the first slow, not the warn
    assert a["monitor"]["landed_by_monitor"]
    assert a["max_live_margin_m"] == pytest.approx(0.06)
    assert a["max_estimate_sd_m"] == pytest.approx(0.06) and a["max_estimate_age_s"] == pytest.approx(0.3)
    assert a["estimate_error_max_m"] == pytest.approx(0.0)  # an est of 9 floats is read as an estimate
    assert b["monitor"]["action_ticks"] == {"warn": 0, "slow": 0, "hold": 0, "land": 0}
    assert b["monitor"]["first_action_s"] is None and not b["monitor"]["landed_by_monitor"]
    assert b["max_live_margin_m"] == pytest.approx(0.02)
    assert b["max_estimate_sd_m"] is None and b["max_estimate_age_s"] is None
    assert m["monitor"]["action_ticks"] == {"warn": 1, "slow": 2, "hold": 1, "land": 2}
    assert m["monitor"]["breach_ticks"]["estimate_std"] == 2
    assert m["monitor"]["acting_agents"] == ["a"] and m["monitor"]["landed_agents"] == ["a"]
