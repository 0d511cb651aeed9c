"""Configs that cannot fly, as the tests and the fault benchmark (``tools.bench_faults``) give
them to ``swarm``: each case a change to ``configs/circle_8.yaml`` and the field its error names."""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
BASE = yaml.safe_load((ROOT / "configs" / "circle_8.yaml").read_text())


def patched(change: Callable[[dict], object]) -> dict:
    """``configs/circle_8.yaml`` with ``change`` applied to a copy."""
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


def write_bad_files(folder: Path) -> dict[str, tuple[Path, str]]:
    """Write the malformed config files ``swarm run`` refuses into ``folder``: by case, the
    file and a piece of the one line it is refused with."""
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
        p.write_text(yaml.safe_dump(patched(CASES[case][0])))
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
