"""swarm scenario keeps a generated scene inside a room (swarm.offline.scenario.fit_room)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from swarm.config import resolve
from swarm.offline.scenario import Room, SwapSettings, fit_room, generate

ROOT = Path(__file__).resolve().parents[2]


def _points(raw: dict) -> np.ndarray:
    return np.array([a[k] for a in raw["agents"] for k in ("start", "goal")])


@pytest.mark.parametrize("n", [2, 12, 32])
def test_a_sphere_swap_is_squeezed_under_the_default_labs_ceiling_and_still_valid(n):
    raw = generate("sphere", n, SwapSettings())
    fitted = fit_room(raw, Room())
    z = _points(fitted)[:, 2]
    assert z.max() <= 3.0 - 0.3 + 1e-9 and z.min() >= 0.5 - 1e-9
    assert np.allclose(_points(fitted)[:, :2], _points(raw)[:, :2])  # nothing moved sideways
    resolve(fitted, "fitted")  # every start and goal still a valid one (apart, above the floor)


def test_a_scene_that_fits_is_left_as_it_is_and_one_too_wide_says_how_to_fix_it():
    raw = generate("circle", 8, SwapSettings())
    assert fit_room(raw, Room()) == raw
    assert fit_room(generate("sphere", 12, SwapSettings()), Room(size_m=(20, 20, 8))) == generate(
        "sphere", 12, SwapSettings()
    )  # a larger room overrides the lab's
    with pytest.raises(ValueError, match="larger --room or a smaller --radius"):
        fit_room(generate("circle", 64, SwapSettings()), Room())


def test_swarm_scenario_writes_the_sphere_inside_the_room_it_names():
    p = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "scenario", "sphere", "--agents", "12"],
        capture_output=True, text=True, timeout=60, cwd=ROOT,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "--room 8,8,3" in p.stdout.splitlines()[0]
    z = _points(yaml.safe_load(p.stdout))[:, 2]
    assert 0.5 - 1e-9 <= z.min() and z.max() <= 2.7 + 1e-9
