"""Configs that cannot fly are refused before anything starts: ``swarm run`` exits 2 with
one line naming the file, the field and the reason, in under 2 s, and leaves no run folder."""

from __future__ import annotations

import copy
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from swarm.config import AGENTS_PER_CPU, ConfigError, load, machine_cpus, resolve

ROOT = Path(__file__).resolve().parents[2]
BASE = yaml.safe_load((ROOT / "configs" / "circle_8.yaml").read_text())


def _patched(change) -> dict:
    raw = copy.deepcopy(BASE)
    change(raw)
    return raw


def _ball(at: list[float]) -> list[dict]:
    return [{"id": "ball", "shape": "sphere", "center": at, "radius_m": 0.3}]


CASES = {
    "start_inside_obstacle": (lambda c: c.update(obstacles=_ball(c["agents"][3]["start"])), "agents.3.start"),
    "start_touching_obstacle": (
        lambda c: c.update(obstacles=_ball([c["agents"][3]["start"][0] + 0.38, *c["agents"][3]["start"][1:]])),
        "agents.3.start",
    ),
    "goal_inside_obstacle": (
        lambda c: c.update(obstacles=_ball([0.0, 0.0, 1.0])) or c["agents"][5].update(goal=[0.1, 0.0, 1.0]),
        "agents.5.goal",
    ),
    "goal_inside_pole": (
        lambda c: c.update(
            obstacles=[
                {
                    "id": "pole",
                    "shape": "cylinder",
                    "center": [c["agents"][2]["goal"][0], c["agents"][2]["goal"][1], 0.0],
                    "axis": [0, 0, 1],
                    "radius_m": 0.1,
                }
            ]
        ),
        "agents.2.goal",
    ),
    "same_start": (lambda c: c["agents"][1].update(start=c["agents"][0]["start"]), "agents.1.start"),
    "overlapping_starts": (
        lambda c: c["agents"][1].update(start=[c["agents"][0]["start"][0], c["agents"][0]["start"][1] + 0.1, 1.0]),
        "agents.1.start",
    ),
    "same_goal": (lambda c: c["agents"][4].update(goal=c["agents"][0]["goal"]), "agents.4.goal"),
    "start_underground": (lambda c: c["agents"][2].update(start=[0.0, 0.0, -3.0]), "agents.2.start"),
    "goal_below_filter_floor": (lambda c: c["agents"][2].update(goal=[0.0, -1.9975, 0.1]), "agents.2.goal"),
    "waypoint_underground": (
        lambda c: c["agents"][2].update(goal=None, waypoints=[[0.0, 0.0, -1.0], [0.0, 1.0, 1.0]]),
        "agents.2.waypoints.0",
    ),
    "real_drone_outside_geofence": (
        lambda c: (
            c.update(mocap={"type": "mock"}, time={"mode": "realtime"})
            or c["agents"][0].update(
                backend="crazyflie", crazyflie={"uri": "radio://0/80/2M/E7E7E7E701"}, goal=[9.0, 0.0, 1.0]
            )
        ),
        "geofence",
    ),
    "duration_true": (lambda c: c.update(duration_s=True), "duration_s"),
    "duration_string": (lambda c: c.update(duration_s="30"), "duration_s"),
    "duration_huge": (lambda c: c.update(duration_s=1e300), "duration_s"),
    "duration_nan": (lambda c: c.update(duration_s=float("nan")), "duration_s"),
    "timeout_true": (lambda c: c.update(time={"lockstep_timeout_s": True}), "time.lockstep_timeout_s"),
    "too_many_agents": (
        lambda c: c.update(
            agents=[{"id": f"a{i}", "start": [0.5 * i, 0.0, 1.0], "goal": [0.5 * i, 5.0, 1.0]} for i in range(5000)]
        ),
        "agents",
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_impossible_config_is_a_config_error_naming_the_field(case: str) -> None:
    change, field = CASES[case]
    with pytest.raises(ConfigError) as err:
        resolve(_patched(change), "bad.yaml")
    assert str(err.value).startswith("bad.yaml: ") and field in str(err.value), str(err.value)


def _write_bad_files(folder: Path) -> dict[str, tuple[Path, str]]:
    files = {}
    for case in (
        "start_inside_obstacle",
        "same_start",
        "duration_true",
        "duration_huge",
        "too_many_agents",
        "start_underground",
        "goal_inside_obstacle",
    ):
        p = folder / f"{case}.yaml"
        p.write_text(yaml.safe_dump(_patched(CASES[case][0])))
        files[case] = (p, CASES[case][1])
    big = folder / "big.yaml"
    big.write_text((ROOT / "configs" / "circle_8.yaml").read_text() + "\n# " + "x" * (10 << 20) + "\n")
    files["ten_megabytes"] = (big, "larger than")
    garbage = folder / "garbage.yaml"
    garbage.write_bytes(bytes(range(256)) * 16)
    files["binary_garbage"] = (garbage, "not a YAML text file")
    nul = folder / "nul.yaml"
    nul.write_bytes(b"version: 1\x00\x00\n")
    files["nul_bytes"] = (nul, "not a YAML text file")
    return files


def test_swarm_run_refuses_each_bad_file_with_exit_2_fast_and_starts_nothing(tmp_path: Path) -> None:
    slowest = 0.0
    t0 = time.monotonic()  # the pace of this run: the command line's own start-up, refusing nothing
    subprocess.run([sys.executable, "-m", "swarm.cli", "--help"], capture_output=True, timeout=60, cwd=ROOT, check=True)
    start_up = time.monotonic() - t0
    for case, (path, needle) in _write_bad_files(tmp_path).items():
        out = tmp_path / f"run-{case}"
        t0 = time.monotonic()
        p = subprocess.run(
            [sys.executable, "-m", "swarm.cli", "run", str(path), "--out", str(out)],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=ROOT,
        )
        took = time.monotonic() - t0
        slowest = max(slowest, took)
        assert p.returncode == 2, (case, p.returncode, p.stderr[-2000:])
        lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
        assert lines == [lines[0]] and re.match(rf"config error: {re.escape(str(path))}(:\d+)?: ", lines[0]), (
            case,
            p.stderr,
        )  # the file, and the line where the key is written
        assert needle in lines[0], (case, lines[0])
        assert "Traceback" not in p.stderr
        assert not out.exists(), f"{case}: a run folder was made"
    # a refusal costs about the command line's start-up (no world, no simulator, no session), at any pace
    assert slowest < 3.0 * start_up + 0.5, (slowest, start_up)


def test_the_agent_limit_can_be_raised_knowingly() -> None:
    n = AGENTS_PER_CPU * machine_cpus() + 1
    agents = [{"id": f"a{i}", "start": [0.5 * i, 0.0, 1.0], "goal": [0.5 * i, 5.0, 1.0]} for i in range(n)]
    raw = {"version": 1, "name": "many", "duration_s": 1.0, "agents": agents}
    with pytest.raises(ConfigError, match=f"limits.max_agents: {n}"):
        resolve(copy.deepcopy(raw), "many.yaml")
    assert len(resolve({**raw, "limits": {"max_agents": n}}, "many.yaml").agents) == n


def test_shipped_configs_still_load() -> None:
    for p in sorted((ROOT / "configs").rglob("*.yaml")):
        load(p)
