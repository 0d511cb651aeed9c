"""Config errors at the line the user wrote (swarm.config_where): the file, the key path as
written, its line, a "did you mean" for an unknown key; "inside" an obstacle where it is."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from swarm.config import ConfigError, load
from swarm.config_where import key_lines

ROOT = Path(__file__).resolve().parents[2]

SWAP = """\
version: 1
name: typo
duration_s: 10.0
defaults:
  speed_mps: 1.0
  filter: {{kind: c3bf, {filter_key}: 1.0}}
agent_types:
  slow: {{speed_mps: {slow}}}
agents:
{agents}
"""


def _agents(n: int, extra: str = "") -> str:
    return "\n".join(
        f"  - {{id: cf{i}, start: [0.0, {0.5 * i}, 1.0], goal: [4.0, {0.5 * i}, 1.0]{extra}}}" for i in range(n)
    )


def _load(tmp_path: Path, text: str) -> str:
    path = tmp_path / "scene.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load(path)
    return str(err.value)


def test_a_typo_in_defaults_is_reported_once_at_its_line_with_the_key_it_meant(tmp_path):
    msg = _load(tmp_path, SWAP.format(filter_key="gama", slow=0.5, agents=_agents(12)))
    assert msg == f"{tmp_path / 'scene.yaml'}:6: defaults.filter.gama: unknown key 'gama'; did you mean 'gamma'?"


def test_an_error_in_an_agent_type_is_reported_where_the_type_is_written(tmp_path):
    agents = _agents(2, ", type: slow")
    msg = _load(tmp_path, SWAP.format(filter_key="gamma", slow="-1", agents=agents))
    assert msg.startswith(f"{tmp_path / 'scene.yaml'}:8: agent_types.slow.speed_mps: ")


def test_an_unknown_key_of_an_agent_is_reported_at_the_agents_line(tmp_path):
    text = SWAP.format(filter_key="gamma", slow=0.5, agents=_agents(2)).replace("goal:", "gaol:", 1)
    msg = _load(tmp_path, text)
    assert msg.startswith(f"{tmp_path / 'scene.yaml'}:10: agents.0.gaol: unknown key 'gaol'; did you mean 'goal'?")


def test_a_goal_inside_an_obstacle_says_inside_and_how_far_to_move_it(tmp_path):
    text = """\
version: 1
name: inside
duration_s: 10.0
obstacles:
  - {id: ball, shape: sphere, center: [2.0, 0.0, 1.0], radius_m: 0.3}
agents:
  - id: cf1
    start: [0.0, 0.0, 1.0]
    goal: [2.0, 0.0, 1.0]
"""
    msg = _load(tmp_path, text)
    assert msg.startswith(f"{tmp_path / 'scene.yaml'}:9: agents.0.goal: [2.0, 0.0, 1.0] is inside obstacle 'ball'")
    assert "move it at least 0.090 m outside" in msg
    near = _load(tmp_path, text.replace("goal: [2.0, 0.0, 1.0]", "goal: [2.0, 0.0, 1.35]"))
    assert "is 0.050 m from obstacle 'ball'" in near and "inside obstacle" not in near


def test_key_lines_maps_every_key_and_item_to_its_line():
    lines = key_lines("a:\n  b: 1\n  c: [1, 2]\nd:\n  - {e: 1}\n  - f: 2\n")
    assert lines[("a",)] == 1 and lines[("a", "b")] == 2 and lines[("a", "c")] == 3
    assert lines[("d", 0)] == 5 and lines[("d", 1, "f")] == 6
    assert key_lines("a: [") == {}  # (not YAML: the loader's own error is reported)


def test_swarm_run_prints_the_line_and_exits_2(tmp_path):
    path = tmp_path / "scene.yaml"
    path.write_text(SWAP.format(filter_key="gama", slow=0.5, agents=_agents(2)))
    p = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "run", str(path), "--out", str(tmp_path / "run")],
        capture_output=True, text=True, timeout=60, cwd=ROOT,
    )  # fmt: skip
    assert p.returncode == 2
    said = p.stderr.strip()
    assert said == f"config error: {path}:6: defaults.filter.gama: unknown key 'gama'; did you mean 'gamma'?"
