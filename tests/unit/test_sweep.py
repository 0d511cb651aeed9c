"""The sweep's grid and knobs (no processes: the runs themselves are in the integration tests)."""

import numpy as np
import pytest

from swarm.config import ConfigError, load
from swarm.runs.sweep import build, grid, parse_axes

BASE = load("configs/sweeps/head_on.yaml").model_dump(mode="json")


def test_axes_and_grid():
    axes = parse_axes(["filter=c3bf,hocbf", "obstacle_speed=0.1, 1,3"])
    assert axes == {"filter": ["c3bf", "hocbf"], "obstacle_speed": ["0.1", "1", "3"]}
    pts = grid(axes)
    assert len(pts) == 6 and pts[0] == {"filter": "c3bf", "obstacle_speed": "0.1"}


@pytest.mark.parametrize(
    ("spec", "needle"),
    [("nope=1", "unknown knob"), ("gamma", "NAME=v1"), ("gamma=", "NAME=v1")],
)
def test_bad_axes_are_named(spec, needle):
    with pytest.raises(ConfigError, match=needle):
        parse_axes([spec])


def test_bad_values_are_named_before_any_run():
    with pytest.raises(ConfigError, match="gamma"):
        build(BASE, {"gamma": "-1"})
    with pytest.raises(ConfigError, match="not a number"):
        build(BASE, {"obstacle_speed": "fast"})
    with pytest.raises(ConfigError, match="filter"):
        build(BASE, {"filter": "mpc"})


@pytest.mark.parametrize("angle", [0.0, 45.0, 90.0, 135.0])
@pytest.mark.parametrize("speed", [0.1, 1.0, 3.0])
def test_the_obstacle_is_aimed_at_the_meeting_point(speed, angle):
    cfg, _ = build(BASE, {"obstacle_speed": str(speed), "approach_angle_deg": str(angle)})
    o, a = cfg.obstacles[0], cfg.agents[0]
    meet = np.array(BASE["obstacles"][0]["center"])
    t_meet = np.linalg.norm(meet - np.array(a.start)) / a.speed_mps
    v = np.array(o.velocity)
    assert np.linalg.norm(v) == pytest.approx(speed)
    np.testing.assert_allclose(np.array(o.center) + v * t_meet, meet, atol=1e-8)  # there when the drone is
    heading = np.array(a.goal) - np.array(a.start)
    cos = -(v @ heading) / (np.linalg.norm(v) * np.linalg.norm(heading))
    assert cos == pytest.approx(np.cos(np.radians(angle)), abs=1e-9)  # 0 deg: head-on


def test_filter_and_gains_reach_every_agent():
    cfg, _ = build(BASE, {"filter": "hocbf", "gamma_ho": "2.5", "rho": "0.5"})
    assert all(a.filter.kind == "hocbf" and a.filter.gamma_ho == 2.5 and a.filter.rho == 0.5 for a in cfg.agents)
    assert all(not a.filter.enabled for a in build(BASE, {"filter": "none"})[0].agents)
    assert all(a.filter.horizon_s == 2.0 for a in build(BASE, {"horizon_s": "2"})[0].agents)
    assert all(a.filter.horizon_s is None for a in build(BASE, {"horizon_s": "none"})[0].agents)
    with pytest.raises(ConfigError, match="horizon_s"):
        build(BASE, {"horizon_s": "0"})
    assert all(a.filter.buffer_mps == 0.0 for a in build(BASE, {"buffer_mps": "0"})[0].agents)
    assert all(
        a.filter.filter_config(a.command_level).buffer_mps == 0.1 for a in build(BASE, {"buffer_mps": "0.1"})[0].agents
    )
    with pytest.raises(ConfigError, match="buffer_mps"):
        build(BASE, {"buffer_mps": "-1"})
    cfg = build(BASE, {"contact_s": "0.75"})[0]
    assert all(a.filter.filter_config(a.command_level).contact_s == 0.75 for a in cfg.agents)
    with pytest.raises(ConfigError, match="contact_s"):
        build(BASE, {"contact_s": "-1"})


def test_an_obstacle_that_would_start_on_the_agent_is_refused():
    with pytest.raises(ConfigError, match="start on the agent"):
        build(BASE, {"obstacle_speed": "1", "approach_angle_deg": "180"})


def test_plots_run_against_the_axis_that_varies():
    from swarm.runs.sweep import aggregate

    rows = [
        {"filter": f, "obstacle_speed": "1", "gamma": g, "success": 1, "mean_time_to_goal_s": 8.0 + float(g)}
        for f in ("c3bf", "hocbf")
        for g in ("0.5", "1", "2")
    ]
    x_axis, table = aggregate(rows, ["filter", "obstacle_speed", "gamma"])
    assert x_axis == "gamma"  # not obstacle_speed, which has one value
    assert sorted(table) == [
        (("filter", "c3bf"), ("obstacle_speed", "1")),
        (("filter", "hocbf"), ("obstacle_speed", "1")),
    ]
    assert table[(("filter", "c3bf"), ("obstacle_speed", "1"))][2.0]["mean_time_to_goal_s"] == 10.0


def test_the_ray_engine_without_ray_names_the_extra(monkeypatch):
    import sys

    from swarm.errors import InputError
    from swarm.runs.ray_engine import import_ray

    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    with pytest.raises(InputError, match=r"pip install -e '\.\[cluster\]'"):
        import_ray()


def test_an_unknown_engine_is_refused_before_any_run(tmp_path):
    from swarm.config import ConfigError
    from swarm.runs.sweep import sweep

    with pytest.raises(ConfigError, match="--engine"):
        sweep({}, {}, tmp_path, engine="slurm")
