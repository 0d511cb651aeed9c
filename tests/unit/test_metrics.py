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
