"""The distributed runtime end to end: real processes on 2 cores."""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

from swarm.config import load
from swarm.net import transport as tp
from swarm.net.cells import cell_of
from swarm.net.messages import VERSION, encode, measurement_agent
from swarm.runs.runfiles import read_records

from .conftest import CONFIGS, scenario

BODY = 0.07  # Crazyflie bounding radius [m] (QuadParams default)
MARGIN = 0.02  # filter margin [m] (FilterSettings default)
# 120 Hz control with each command held, PyBullet at 240 Hz: measured at most 0.8 mm inside BODY + MARGIN
CLEAR_TOL = 1.5e-3


def trajectories(run_dir) -> dict[str, dict[int, np.ndarray]]:
    out: dict[str, dict[int, np.ndarray]] = defaultdict(dict)
    for r in read_records(run_dir / "run.mcap"):
        if r["kind"] == "measurement":
            out[measurement_agent(r)][r["k"]] = np.array(r["x"] + r["q"] + r["v"])
    return out


def _world_of(source: str) -> dict:
    """swap_2's lab world, or the ideal one with the world's roster: the roster hands the agents
    the world's exact states, which the lab's motion-capture noise does not allow (its config error)."""
    return {"realism": "ideal"} if source == "world" else {}


@pytest.mark.parametrize("source", ["agents", "world"])
def test_swap_2_lockstep_reaches_goals_safely_and_repeats_exactly(start_run, source):
    cfg = scenario("swap_2.yaml", neighbours={"source": source}, world=_world_of(source))
    runs = []
    for name in ("first", "second"):
        h = start_run(cfg, name)
        assert h.wait() == "completed"
        m = json.loads((h.out / "metrics.json").read_text())
        assert m["collisions"] == 0
        assert m["all_reached_goal"] is True
        # the barrier keeps body centres 2 * body radius + margin apart; sampled control
        # at 120 Hz may eat a fraction of a millimetre of the margin, never the bodies
        assert m["min_separation_m"] >= 2 * BODY + MARGIN - 1e-3
        assert m["late_ticks"] == 0 and m["dropped_messages"] == 0
        assert set(m["exit_codes"].values()) == {0}
        runs.append(trajectories(h.out))
    a, b = runs
    assert a.keys() == b.keys() == {"cf1", "cf2"}
    for agent in a:
        assert a[agent].keys() == b[agent].keys()
        for k in a[agent]:
            np.testing.assert_array_equal(a[agent][k], b[agent][k])


def _cpus_of(pid: int) -> set[frozenset[int]]:
    """The CPU sets of every thread of a process (Zenoh's threads included)."""
    return {frozenset(os.sched_getaffinity(int(t.name))) for t in Path(f"/proc/{pid}/task").iterdir()}


def test_circle_8_realtime_completes_without_collision_with_each_process_on_its_cpu(start_run):
    from swarm.runs.launch import cpu_plan

    # (late commands brake, as before the firmware's watchdog: this test is of realtime and CPU placement)
    cfg = scenario("circle_8.yaml", time={"mode": "realtime", "late_command": "brake"})
    assert cfg.time.pin_cpus  # the default
    h = start_run(cfg)
    h.wait_sim_time(0.0)  # every process is up and running its loop
    plan = cpu_plan(len(cfg.agents))
    if plan:  # (more than one CPU)
        names = {"world": "world", "recorder": "recorder"} | {i: f"agent-{a.id}" for i, a in enumerate(cfg.agents)}
        for key, name in names.items():
            assert _cpus_of(h.procs[name].pid) == {frozenset({plan[key]})}, name
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["mode"] == "realtime"
    assert m["collisions"] == 0
    assert m["min_separation_m"] > 2 * BODY


@pytest.mark.parametrize("source", ["agents", "world"])  # a star with and without the bundle relay
def test_killed_agent_is_seen_gone_and_the_others_fly_on(start_run, source):
    cfg = scenario(
        "swap_2.yaml",
        name="kill_3",
        duration_s=10.0,
        neighbours={"source": source},
        world=_world_of(source),
        agents=[
            {"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [4.0, 0.0, 1.0]},
            {"id": "cf2", "start": [4.0, 0.05, 1.0], "goal": [0.0, 0.05, 1.0]},
            {"id": "cf3", "start": [2.0, 1.5, 1.0], "goal": [2.0, -1.5, 1.0], "speed_mps": 0.3},
        ],
    )
    assert cfg.topology == "star" and cfg.uses_bundles == (source == "agents")
    h = start_run(cfg)
    h.wait_sim_time(1.0)  # the swarm is flying
    killed_at = time.time()
    h.kill("agent-cf3", signal.SIGKILL)
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["lost_agents"] == ["cf3"]
    assert m["collisions"] == 0
    assert m["agents"]["cf1"]["reached_goal"] and m["agents"]["cf2"]["reached_goal"]
    for survivor in ("cf1", "cf2"):
        log = (h.out / "logs" / f"agent-{survivor}.log").read_text()
        # its liveliness token, directly (mesh only) or as the world's live list, whichever came first
        seen = re.search(r"neighbour cf3 gone \((liveliness|the world's live list)\) at wall ([0-9.]+)", log)
        assert seen, log
        assert float(seen.group(2)) - killed_at < 0.5
    assert "agent cf3 gone" in (h.out / "logs" / "world.log").read_text()
    assert m["exit_codes"]["agent-cf3"] == -signal.SIGKILL


@pytest.mark.parametrize("source", ["agents", "world"])  # a router (cells), a star
def test_garbage_on_every_topic_is_dropped_and_counted(start_run, source):
    # long enough that the injected garbage is routed to every process while they run
    cfg = scenario(
        "swap_2.yaml",
        name="garbage",
        duration_s=8.0,
        stop_when_all_reached=False,
        neighbours={"source": source},
        world=_world_of(source),
    )
    h = start_run(cfg)
    keys = [
        *(f"swarm/{h.run}/world/{a}/measurement" for a in ("cf1", "cf2")),
        *(f"swarm/{h.run}/agent/{a}/{t}" for a in ("cf1", "cf2") for t in ("state", "command")),
        *(f"swarm/{h.run}/world/{t}" for t in ("clock", "status", "collision")),
        *(tp.Keys(h.run).tick(a.id) for a in h.cfg.agents),  # neighbours by cells: each agent's tick
        *(tp.Keys(h.run).cell_state(cell_of(a.start, h.cfg.cell_m), a.id) for a in h.cfg.agents),
    ]
    bad = [
        b"\x00\xffgarbage",
        msgpack.packb({"hello": 1}),
        msgpack.packb([1, 2, 3]),
        encode("state", "another-run", "cf9", 1, 0.0, 0, x=[0, 0, 0], v=[0, 0, 0], r=0.1),
        msgpack.packb({"ver": 99, "kind": "command", "run": h.run, "src": "cf1", "seq": 1, "t": 0.0, "k": 0}),
        msgpack.packb(
            {
                "ver": VERSION,
                "kind": "command",
                "run": h.run,
                "src": "cf1",
                "seq": 1,
                "t": 0.0,
                "k": 5,
                "level": "attitude",
                "u": np.array([0.0, np.nan, 0.0, 0.3]).tobytes(),
                "intervention": 0.0,
                "status": "ok",
            }
        ),
    ]
    pubs = [h.session.declare_publisher(k) for k in keys]
    sent = 0
    h.wait_sim_time(0.0)  # the world is ticking and its messages reach us
    while h.progress.t_s < 6.0:  # inject on each world status message until 6 s of sim time
        for p in pubs:
            for payload in bad:
                p.put(payload)
                sent += 1
        h.wait_sim_time(h.progress.t_s + 0.01)
    assert sent > 0
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert set(m["exit_codes"].values()) == {0}
    assert m["all_reached_goal"] is True and m["collisions"] == 0
    assert m["dropped_messages"] > 0
    assert all(a["dropped_messages"] > 0 for a in m["agents"].values())  # the garbage reached every agent
    recorder = json.loads((h.out / "recorder.json").read_text())
    assert recorder["dropped"] > 0


def test_a_malformed_config_fails_before_anything_starts(tmp_path):
    bad = tmp_path / "bad.yaml"
    text = (CONFIGS / "swap_2.yaml").read_text().replace("start: [4.0, 0.05, 1.0]", "start: [4.0, 0.05]")
    bad.write_text(text)
    out = tmp_path / "out"
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "run", str(bad), "--out", str(out), "--no-progress"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert str(bad) in proc.stderr and "agents.1.start" in proc.stderr
    assert not out.exists()  # nothing was started or written
    assert time.monotonic() - t0 < 30


def _processes_mentioning(text: str) -> list[int]:
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if text.encode() in (entry / "cmdline").read_bytes():
                    pids.append(int(entry.name))
            except OSError:
                continue
    return pids


def _swarm_run(
    tmp_path: Path, cfg_over: dict, *args: str, config: str = "circle_8.yaml"
) -> tuple[subprocess.Popen, Any, Path, str, Any]:
    """``swarm run`` of ``config`` (``cfg_over`` merged) as a child of its own session, a
    channel of the run's status messages this test may hear (the run's credentials), the
    run folder, the run id, and the session the channel lives in (keep it)."""
    from swarm.config import dump, load
    from swarm.net import transport as tp
    from swarm.runs.launch import ensure_secrets, free_port

    out, run_id = tmp_path / "out", f"stop-{time.monotonic_ns()}"
    cfg = load(CONFIGS / config, {"network": {"port": free_port()}, **cfg_over})
    (tmp_path / "circle_8.yaml").write_text(dump(cfg))
    secrets = ensure_secrets(cfg, tmp_path / "secrets")
    cli = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", str(tmp_path / "circle_8.yaml"), "--out", str(out),
         "--no-progress", "--run-id", run_id, "--secrets", str(secrets), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        start_new_session=True,
        text=True,
    )  # fmt: skip
    conf = tp.process_config(cfg, tp.Role.OBSERVER, tp.Access.of(cfg, run_id, tp.Role.OBSERVER, secrets))
    deadline = time.monotonic() + 60
    while True:  # (a run through a router: its router comes up first)
        try:
            session = tp.open_session(conf)
            break
        except Exception:
            if time.monotonic() > deadline or cli.poll() is not None:
                raise
            conf = tp.process_config(cfg, tp.Role.OBSERVER, tp.Access.of(cfg, run_id, tp.Role.OBSERVER, secrets))
    status = tp.open_channel(session, tp.Keys(run_id).status)
    return cli, status, out, run_id, session


def _last_heights(out: Path) -> dict[str, float]:
    """Each drone's height [m] in its last recorded measurement."""
    return {a: float(xs[max(xs)][2]) for a, xs in trajectories(out).items()}


# long enough that no drone is down by itself, slow enough that landing from 1 m takes seconds
_STAY_UP = {"duration_s": 60.0, "stop_when_all_reached": False, "defaults": {"speed_mps": 0.3}}


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_stop_signal_lands_every_drone_then_ends_the_run_and_keeps_the_recording(tmp_path, sig):
    from swarm.config import load
    from swarm.landing import DOWN_ABOVE_M, LANDED, LANDING_BANNER, LANDING_NOW, landing_height_m

    cli, status, out, run_id, _session = _swarm_run(tmp_path, _STAY_UP)
    try:
        first = tp.wait_sample(status, time.monotonic() + 120)  # the world is ticking: drones fly
        assert first is not None
        cli.send_signal(sig)
        said, _ = cli.communicate(timeout=180)
        assert cli.returncode == 1, said  # not the scenario's end
        assert LANDING_BANNER in said and LANDING_NOW in said
        assert "| stop_reason | landed on request |" in said and "…" not in said  # markdown, nothing cut
        m = json.loads((out / "metrics.json").read_text())
        assert m["stop_reason"] == LANDED and m["complete"] is True
        assert m["collisions"] == 0
        heights = _last_heights(out)
        cfg = load(out / "config.yaml")
        down_m = {a.id: landing_height_m(a) + DOWN_ABOVE_M for a in cfg.agents}  # (simulated: the filter's floor)
        assert len(heights) == 8 and all(z <= down_m[a] for a, z in heights.items()), heights
        assert _processes_mentioning(run_id) == []
    finally:
        if cli.poll() is None:
            os.killpg(cli.pid, signal.SIGKILL)
        for pid in _processes_mentioning(run_id):
            os.kill(pid, signal.SIGKILL)


def _wait_sim_time(status: Any, run_id: str, t_s: float, timeout_s: float = 120.0) -> None:
    """Until a status message of the run says sim time ``t_s`` [s] or later."""
    from swarm.net.messages import decode

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        s = tp.wait_sample(status, deadline)
        if s is not None and decode(tp.payload(s), run_id, ("status",)).t >= t_s:
            return
    raise AssertionError(f"the run did not reach t = {t_s} s")


def test_a_stop_signal_lands_real_drones_by_their_flight_plan(tmp_path):
    """mixed_sitl: two software-in-the-loop Crazyflies through cflib, and two simulated drones.
    Ctrl-C once they fly: the real ones land by their flight plans (motors off on the ground),
    the simulated ones descend to their floor, and the run ends as landed."""
    from swarm.landing import LANDED

    cli, status, out, run_id, _session = _swarm_run(
        tmp_path, {"duration_s": 60.0, "stop_when_all_reached": False}, config="mixed_sitl.yaml"
    )
    try:
        _wait_sim_time(status, run_id, 3.0)  # the real drones have taken off
        cli.send_signal(signal.SIGINT)
        said, _ = cli.communicate(timeout=180)
        assert cli.returncode == 1, said
        m = json.loads((out / "metrics.json").read_text())
        assert m["stop_reason"] == LANDED and m["collisions"] == 0
        for real in ("real1", "real2"):
            log = (out / "logs" / f"agent-{real}.log").read_text()
            assert "landing at t=" in log and "landed, motors off" in log, log[-2000:]
            assert "emergency" not in log.lower(), log[-2000:]
        assert _processes_mentioning(run_id) == []
    finally:
        if cli.poll() is None:
            os.killpg(cli.pid, signal.SIGKILL)
        for pid in _processes_mentioning(run_id):
            os.kill(pid, signal.SIGKILL)


def test_a_second_stop_signal_is_the_emergency_stop(tmp_path):
    """Realtime: landing from 1 m at 0.3 m/s takes 3 s of wall clock, whatever the machine's
    pace, and the second Ctrl-C comes as soon as the first is answered."""
    from swarm.landing import LANDING_NOW

    cli, status, out, run_id, _session = _swarm_run(tmp_path, _STAY_UP, "--mode", "realtime")
    try:
        first = tp.wait_sample(status, time.monotonic() + 120)
        assert first is not None
        cli.send_signal(signal.SIGINT)
        assert cli.stdout is not None
        for line in cli.stdout:  # until the launcher says it lands them
            if LANDING_NOW in line:
                break
        cli.send_signal(signal.SIGINT)
        cli.communicate(timeout=60)
        assert cli.returncode == 1
        assert json.loads((out / "metrics.json").read_text())["stop_reason"] == "interrupted"
        heights = _last_heights(out)
        assert len(heights) == 8 and all(z > 0.5 for z in heights.values()), heights  # stopped in the air
        assert _processes_mentioning(run_id) == []
    finally:
        if cli.poll() is None:
            os.killpg(cli.pid, signal.SIGKILL)
        for pid in _processes_mentioning(run_id):
            os.kill(pid, signal.SIGKILL)


def test_report_writes_plots_and_a_summary(start_run):
    from swarm.runs.report import make_report

    h = start_run(scenario("single_static_sphere.yaml", duration_s=4.0))
    assert h.wait() == "completed"
    out = make_report(h.out)
    for name in ("trajectory_3d", "views", "clearance", "h", "speed", "intervention"):
        png = (out / f"{name}.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
        assert f"({name}.png)" in (out / "summary.md").read_text()
    summary = (out / "summary.md").read_text()
    assert "| collisions | 0 |" in summary and "| cf1 |" in summary
    commands = [r for r in read_records(h.out / "run.mcap") if r["kind"] == "command"]
    assert any(r["row_ids"] == ["ball"] and len(r["h_rows"]) == 1 for r in commands)  # h of each row is recorded


def test_compare_runs_each_filter_and_saves_the_table(tmp_path):
    from swarm.runs.compare import compare

    rows = compare(scenario("single_static_sphere.yaml", duration_s=8.0), ["c3bf", "hocbf"], tmp_path)
    assert [r["filter"] for r in rows] == ["c3bf", "hocbf"]
    ball = scenario("single_static_sphere.yaml").obstacles[0]
    # to pass the ball the path must leave the line by its radius plus the body's and the margin, less the
    # ball's offset from the line (and the 14 mm the body centre sits above the centre of mass)
    around = ball.radius_m + BODY + MARGIN - abs(ball.center[1]) - 0.014 - 0.005
    for r in rows:
        assert r["collisions"] == 0 and r["max_path_deviation_m"] >= around, r
    c3bf, hocbf = rows
    assert c3bf["min_clearance_m"] >= BODY + MARGIN - CLEAR_TOL  # C3BF keeps its margin
    assert hocbf["min_clearance_m"] >= BODY  # HO-CBF on the attitude level eats into it (measured 0.088 m)
    cfgs = [(tmp_path / f / "config.yaml").read_text() for f in ("c3bf", "hocbf")]
    assert "kind: c3bf" in cfgs[0] and "kind: hocbf" in cfgs[1]
    table = (tmp_path / "compare.md").read_text()
    assert "| c3bf |" in table and "| hocbf |" in table


def test_compare_over_seeds_flies_each_seed_and_tabulates_the_spread(tmp_path):
    """The lab's world draws its imperfections from the seed: two seeds, two runs, one row."""
    from swarm.runs.compare import compare

    cfg = scenario("single_static_sphere.yaml", duration_s=6.0, world={"realism": "crazyflie_lab"})
    rows = compare(cfg, ["c3bf"], tmp_path, seeds=2)
    assert len(rows) == 1 and rows[0]["seeds"] == 2
    clear = rows[0]["min_clearance_m"]
    assert clear["n"] == 2 and clear["min"] <= clear["mean"] <= clear["max"]
    seeds = sorted(p.name for p in (tmp_path / "c3bf").iterdir())
    assert seeds == [f"seed{cfg.seed}", f"seed{cfg.seed + 1}"]
    assert [load(tmp_path / "c3bf" / s / "config.yaml").seed for s in seeds] == [cfg.seed, cfg.seed + 1]
    table = (tmp_path / "compare.md").read_text()
    assert "| filter | seeds |" in table and "mean [min, max]" in table


def _brakes_and_stays_short(a: dict) -> bool:
    # at the paper's rotor level it then drifts back, slower than 0.1 m/s (measured 0.095 at most;
    # the attitude level holds still: EXPERIMENTS.md section 1)
    return a["final_speed_mps"] < 0.1 and a["path_length_m"] < 1.5 and a["min_along_speed_mps"] > -0.1


def _follows_at_0p1(a: dict) -> bool:
    return abs(a["final_along_speed_mps"] - 0.1) < 0.03 and a["min_along_speed_mps"] > 0.0


def _backs_away(a: dict) -> bool:
    return a["backward_time_s"] > 2.0 and a["final_along_speed_mps"] < -0.05


def _slows_then_passes(a: dict) -> bool:
    # past a 0.3 m sphere on its line: the path leaves the line by the sphere's radius, the body's and the
    # margin (less the 14 mm the body centre sits above the centre of mass, and 5 mm)
    went_around = a["max_path_deviation_m"] >= 0.3 + BODY + MARGIN - 0.014 - 0.005
    return a["reached_goal"] and went_around and a["min_along_speed_mps"] < 0.9


# What each paper scenario must show (EXPERIMENTS.md); every other one reaches its goal.
BEHAVIOUR = {
    "static_brake_pole": _brakes_and_stays_short,
    "moving_slow_behind_pole": _follows_at_0p1,
    "moving_reverse_pole": _backs_away,
    "static_brake": _slows_then_passes,
    "moving_slow_behind": _slows_then_passes,
    "moving_reverse": _slows_then_passes,
}


# the scenarios with a behaviour of their own, and the two-drone crossing (all fourteen fly in
# `python -m tools.experiments --only paper`; each reaching its goal is also checked there)
@pytest.mark.parametrize("name", [*sorted(BEHAVIOUR), "two_both_cross"])
def test_paper_scenarios_show_their_behaviour_without_collision(start_run, name):
    h = start_run(scenario(f"paper/{name}.yaml"), name)
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["collisions"] == 0
    if m["min_obstacle_clearance_m"] is not None:  # the airframe and the margin stay clear
        assert m["min_obstacle_clearance_m"] >= BODY + MARGIN - CLEAR_TOL
    behaviour = BEHAVIOUR.get(name, lambda a: a["reached_goal"])
    for aid, a in m["agents"].items():
        assert behaviour(a), (aid, a)


def test_sweep_runs_its_grid_in_parallel_and_writes_table_and_plots(tmp_path):
    out = tmp_path / "sweep"
    cmd = [
        sys.executable,
        "-m",
        "swarm.cli",
        "sweep",
        str(CONFIGS / "sweeps/head_on.yaml"),
        "--axis",
        "filter=c3bf,hocbf",
        "--axis",
        "obstacle_speed=1",
        "--jobs",
        "2",
        "--out",
        str(out),
    ]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert sorted(r["filter"] for r in rows) == ["c3bf", "hocbf"]
    # progress: a line per finished run, then the bar's last state (both done, none failed or running)
    lines = res.stdout.splitlines()
    assert sum(ln.startswith(("[1/2, 0 failed] p00", "[2/2, 0 failed] p00")) for ln in lines) == 2, res.stdout
    assert any("2/2" in ln and "0 failed, 0 running" in ln for ln in lines), res.stdout
    c3bf = next(r for r in rows if r["filter"] == "c3bf")
    assert c3bf["success"] == "1" and c3bf["collisions"] == "0"
    for r in rows:  # each row is its own run, with its own metrics
        assert (out / r["run"] / "metrics.json").exists()
    assert {"success.png", "mean_time_to_goal_s.png", "max_path_deviation_m.png"} <= {p.name for p in out.glob("*.png")}


@pytest.mark.parametrize("kind", ["circle", "sphere"])
def test_four_agent_swap_ends_with_success(start_run, kind):
    from swarm.config import resolve
    from swarm.offline.scenario import circle_swap, sphere_swap

    gen = circle_swap if kind == "circle" else sphere_swap
    h = start_run(resolve(gen(4, 2.0)), kind)
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["all_reached_goal"] and not m["deadlocked_agents"], m
    assert m["min_separation_m"] >= 2 * BODY
