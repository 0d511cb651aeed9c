"""Safety filter plugins installed as a user installs them (``examples/vo_filter``, and the faulty
ones of ``tests/data/plugins``): the example flies in processes (``swarm run``, ``swarm compare``
beside c3bf and hocbf in the ideal and the lab world, ``swarm sweep``) and offline; a plugin
that raises, returns NaN, leaves the input set or overruns its budget is contained (the C3BF-QP
flies), counted and reported per agent in ``metrics.json`` and on the status channel, with no
contact; a bad plugin config exits 2 naming the field."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from swarm.build import contained_plugin, step_of
from swarm.config import load, resolve
from swarm.offline.closed_loop import fly_scenario, outcome
from swarm.runs.compare import in_world, with_filter
from swarm.runs.launch import RunHandle
from swarm.runs.runfiles import read_records
from swarm.runs.sweep import parse_axes, sweep

pytestmark = pytest.mark.integration

VO = "c3swarm_vo.vo"
EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "vo_filter"


def _swap(**filt: Any) -> dict[str, Any]:
    """Two drones swapping head-on (``configs/swap_2.yaml``'s), in the ideal world, every agent on ``filt``."""
    return {
        "version": 1,
        "name": "plugin_swap",
        "duration_s": 8.0,
        "goal_tolerance_m": 0.1,
        "time": {"mode": "lockstep", "physics_hz": 240, "control_hz": 120},
        "world": {"realism": "ideal"},
        "defaults": {"speed_mps": 1.0, "command_level": "attitude", "filter": dict(filt)},
        "agents": [
            {"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [4.0, 0.0, 1.0]},
            {"id": "cf2", "start": [4.0, 0.05, 1.0], "goal": [0.0, 0.05, 1.0]},
        ],
    }


def _swarm(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "swarm.cli", *args], capture_output=True, text=True, timeout=600, cwd=cwd
    )


def test_the_example_is_compared_beside_c3bf_and_hocbf_in_the_ideal_and_the_lab_world(plugins, tmp_path):
    example = EXAMPLE / "swap_2_vo.yaml"  # the example's own config, as its README flies it
    p = _swarm(
        "compare", str(example), "--filters", f"c3bf,hocbf,{VO}", "--realism", "ideal,crazyflie_lab", "--out", "cmp",
        cwd=tmp_path,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr[-3000:]
    rows = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert [(r["world"], r["filter"]) for r in rows] == [
        (w, f) for w in ("ideal", "crazyflie_lab") for f in ("c3bf", "hocbf", VO)
    ]
    for r in rows:
        assert r["collisions"] == 0 and r["all_reached_goal"] and r["plugin_fallbacks"] == 0, r
    table = (tmp_path / "cmp" / "compare.md").read_text()
    assert f"| crazyflie_lab | {VO} | 0 |" in table and "| plugin fallbacks |" in table, table
    flown = load(tmp_path / "cmp" / "ideal" / VO / "config.yaml")  # the run's own config: the plugin's options kept
    assert (
        flown.agents[0].filter.kind == VO and flown.agents[0].filter.options == load(example).agents[0].filter.options
    )


def test_the_example_flies_in_a_local_sweep_and_offline(plugins, tmp_path):
    rows = sweep(_swap(kind="c3bf"), parse_axes([f"filter=c3bf,{VO}"]), tmp_path / "sweep", jobs=2)
    assert [r["filter"] for r in rows] == ["c3bf", VO] and not any(r["error"] for r in rows)
    assert all(r["collisions"] == 0 and r["success"] == 1 and r["plugin_fallbacks"] == 0 for r in rows), rows
    base = resolve(_swap(kind=VO))
    for world in ("ideal", "crazyflie_lab"):
        cfg = in_world(base, world)
        log = fly_scenario(cfg)
        out = outcome(cfg, log)
        assert (out.collisions, out.reached, log.fallbacks) == (0, 2, [0, 0]), (world, out)


def test_a_raising_a_nan_a_wild_and_a_slow_plugin_are_each_contained_counted_and_reported(plugins, tmp_path):
    raw = _swap(kind="c3bf")
    raw["duration_s"] = 6.0
    raw["agents"] = [
        {"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [4.0, 0.0, 1.0], "filter": {"kind": "faulty.raises"}},
        {"id": "cf2", "start": [4.0, 0.05, 1.0], "goal": [0.0, 0.05, 1.0], "filter": {"kind": "faulty.nan"}},
        {"id": "cf3", "start": [2.0, 1.5, 1.0], "goal": [2.0, -1.5, 1.0], "filter": {"kind": "faulty.wild"}},
        {
            "id": "cf4",
            "start": [2.0, -1.5, 1.6],
            "goal": [2.0, 1.5, 1.6],
            "filter": {"kind": "faulty.slow", "budget_ms": 2.0, "options": {"sleep_ms": 20.0}},
        },
    ]
    h = RunHandle.start(resolve(raw), tmp_path / "run")
    assert h.wait() == "completed"
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["margin_violations"] == 0, m["collision_pairs"]
    why = {"cf1": "raised", "cf2": "non_finite", "cf3": "out_of_limits", "cf4": "overrun"}
    for a, reason in why.items():
        fb = m["agents"][a]["plugin_fallbacks"]
        assert fb[reason] > 0 and fb["total"] == fb[reason] == sum(v for k, v in fb.items() if k != "total"), (a, fb)
    assert m["fallback_agents"] == sorted(why) and m["plugin_fallbacks"] == sum(
        m["agents"][a]["plugin_fallbacks"]["total"] for a in why
    )
    status = [r for r in read_records(tmp_path / "run" / "run.mcap") if r["kind"] == "status"][-1]
    said = dict(zip(status["fallback_ids"], status["fallback_ticks"], strict=True))
    assert said == {a: float(m["agents"][a]["plugin_fallbacks"]["total"]) for a in why}


def test_a_raising_controller_is_contained_and_a_sound_one_flies(plugins, tmp_path):
    raw = _swap(kind="c3bf")
    raw["agents"][0]["controller"] = {"kind": "faulty.raises", "options": {"after_s": 0.5}}
    raw["agents"][1]["controller"] = {"kind": "faulty.gentle"}
    h = RunHandle.start(resolve(raw), tmp_path / "run")
    assert h.wait() == "completed"
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["margin_violations"] == 0 and m["all_reached_goal"], m["agents"]
    cf1, cf2 = m["agents"]["cf1"]["controller_fallbacks"], m["agents"]["cf2"]["controller_fallbacks"]
    assert cf1["raised"] > 0 and cf1["total"] == cf1["raised"] and cf2["total"] == 0, (cf1, cf2)
    assert m["fallback_agents"] == ["cf1"] and m["plugin_fallbacks"] == cf1["total"]
    assert m["agents"]["cf1"]["plugin_fallbacks"]["total"] == 0  # (its filter, the built-in C3BF, never replaced)
    status = [r for r in read_records(tmp_path / "run" / "run.mcap") if r["kind"] == "status"][-1]
    assert dict(zip(status["fallback_ids"], status["fallback_ticks"], strict=True)) == {"cf1": float(cf1["total"])}
    log = fly_scenario(resolve(raw))  # offline: the same plugins, the same containment
    assert log.controller_fallbacks[0] > 0 and log.controller_fallbacks[1] == 0 and log.all_reached


@pytest.mark.parametrize(
    ("section", "value", "field", "says"),
    [
        ("controller", {"kind": "mypkg.mpc"}, "controller.kind", "unknown controller 'mypkg.mpc'"),
        ("controller", {"kind": "faulty.gentle", "options": {"k": 1}}, "controller.options", "no options"),
        ("controller", {"kind": "faulty.raises", "options": {"after_s": -1}}, "controller.options.after_s",
         "greater than or equal to 0"),
    ],
)  # fmt: skip
def test_a_bad_controller_config_exits_2_naming_the_field(plugins, tmp_path, section, value, field, says):
    raw = _swap(kind="c3bf")
    raw["defaults"][section] = value
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(raw))
    p = _swarm("run", "bad.yaml", "--out", "run", cwd=tmp_path)
    assert p.returncode == 2 and re.search(rf"bad\.yaml:\d+: defaults\.{field}: ", p.stderr), (
        p.stderr
    )  # file:line: field
    assert says in p.stderr, p.stderr
    assert not (tmp_path / "run").exists()


def test_a_planner_plugin_s_path_is_flown_and_a_faulty_one_is_refused_at_load(plugins, tmp_path):
    from swarm.planning import StaticObstacles

    raw = _swap(kind="c3bf")
    raw["agents"][0]["planner"] = {"kind": "faulty.detour", "options": {"side_m": 0.6}}
    cfg = resolve(raw)
    step = step_of(cfg.agents[0], StaticObstacles.of([]), cfg.goal_tolerance_m, control_hz=120.0)
    assert step.tracker.W.round(9).tolist() == [[0.0, 0.0, 1.0], [2.0, 0.6, 1.0], [4.0, 0.0, 1.0]]
    log = fly_scenario(cfg)
    out = outcome(cfg, log)
    assert (out.collisions, out.reached) == (0, 2) and float(log.x_b_w[:, 0, 1].max()) > 0.4  # it took the detour
    for kind, says in (("faulty.raises", "raised RuntimeError"), ("faulty.lost", "not the goal")):
        raw["agents"][0]["planner"] = {"kind": kind}
        (tmp_path / "bad.yaml").write_text(yaml.safe_dump(raw))
        p = _swarm("run", "bad.yaml", "--out", "run", cwd=tmp_path)
        assert p.returncode == 2 and re.search(r"bad\.yaml:\d+: agents\.0\.planner\.kind: ", p.stderr), p.stderr
        assert says in p.stderr and not (tmp_path / "run").exists(), p.stderr


@pytest.mark.parametrize(
    ("filt", "level", "field", "says"),
    [
        ({"kind": "mypkg.fancy_cbf"}, "attitude", "filter.kind", "unknown filter 'mypkg.fancy_cbf'"),
        ({"kind": "faulty.missing"}, "attitude", "filter.kind", "cannot be imported: ModuleNotFoundError"),
        ({"kind": VO, "options": {"horizon_s": -1}}, "attitude", "filter.options.horizon_s", "greater than 0"),
        ({"kind": VO, "options": {"horizon": 1}}, "attitude", "filter.options.horizon", "Extra inputs"),
        ({"kind": VO}, "rotors", "filter.kind", "filters the attitude level"),
    ],
)
def test_a_bad_plugin_config_exits_2_naming_the_field(plugins, tmp_path, filt, level, field, says):
    raw = _swap(**filt)
    raw["defaults"]["command_level"] = level
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(raw))
    p = _swarm("run", "bad.yaml", "--out", "run", cwd=tmp_path)
    assert p.returncode == 2 and re.search(rf"bad\.yaml:\d+: defaults\.{field}: ", p.stderr), (
        p.stderr
    )  # file:line: field
    assert says in p.stderr, p.stderr
    assert not (tmp_path / "run").exists()  # nothing flew


def test_compare_refuses_an_unknown_filter_before_anything_flies(plugins, tmp_path):
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(_swap(kind="c3bf")))
    p = _swarm("compare", "c.yaml", "--filters", "c3bf,mypkg.nope", "--out", "cmp", cwd=tmp_path)
    assert p.returncode == 2 and "mypkg.nope" in p.stderr and VO in p.stderr, p.stderr
    assert not (tmp_path / "cmp").exists()
    assert with_filter(resolve(_swap(kind=VO, options={"horizon_s": 2.0})), "c3bf").agents[0].filter.options == {}


def test_swarm_plugins_lists_every_registered_plugin_and_says_which_cannot_be_used(plugins, tmp_path):
    p = _swarm("plugins", cwd=tmp_path)
    assert p.returncode == 1, p.stderr  # faulty.missing cannot be imported
    out = p.stdout
    assert out.startswith("safety filters (c3swarm.filters):\n  c3bf  (c3swarm: swarm.safety.external:C3BF)"), out
    assert f"  {VO}  (c3swarm-vo: c3swarm_vo:VelocityObstacle)\n    levels: attitude\n    options: horizon_s=1.5" in out
    assert "faulty.missing" in out and "cannot be imported: ModuleNotFoundError" in out
    ctrl = out[out.index("reference controllers (c3swarm.controllers):") :]
    assert (
        "  path_tracker  (c3swarm: swarm.reference:PathTracking)" in ctrl and "  faulty.gentle  (c3swarm-faulty" in ctrl
    )


def test_a_plugin_s_default_budget_is_one_tick_on_the_wall_clock_and_none_in_lockstep(plugins):
    agent = resolve(_swap(kind=VO)).agents[0]
    fc = agent.filter.filter_config(agent.command_level)
    assert contained_plugin(agent, fc, 120.0, realtime=True).budget_s == 1 / 120.0
    assert contained_plugin(agent, fc, 120.0, realtime=False).budget_s == float("inf")
    timed = resolve(_swap(kind=VO, budget_ms=5.0)).agents[0]
    assert contained_plugin(timed, fc, 120.0, realtime=False).budget_s == 0.005
