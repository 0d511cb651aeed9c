"""The installed distribution has one import root, ``swarm``: seen from outside the
checkout (so that the checkout's folders are not on the path), the agent and world
processes and the command line import under ``swarm``, and nothing answers to the
generic names other distributions install (``agents``, ``world``, ``tools``)."""

from __future__ import annotations

import json
import subprocess
import sys
from importlib.metadata import distribution
from pathlib import Path

PROBE = """
import importlib.util, json
names = ["swarm", "swarm.cli", "swarm.runs.launch", "swarm.agents.agent", "swarm.world.main",
         "swarm.world.sitl_cf", "agents", "world", "tools", "tools.bench_filter"]
print(json.dumps({n: importlib.util.find_spec(n) is not None for n in names}))
"""


def test_one_import_root_seen_from_outside_the_checkout(tmp_path: Path) -> None:
    p = subprocess.run([sys.executable, "-c", PROBE], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    found = json.loads(p.stdout)
    installed = (
        "swarm",
        "swarm.cli",
        "swarm.runs.launch",
        "swarm.agents.agent",
        "swarm.world.main",
        "swarm.world.sitl_cf",
    )
    for name in installed:
        assert found[name], name
    assert not found["agents"] and not found["world"] and not found["tools.bench_filter"], found


def test_the_swarm_command_is_swarm_cli() -> None:
    scripts = {ep.name: ep.value for ep in distribution("c3swarm").entry_points if ep.group == "console_scripts"}
    assert scripts == {"swarm": "swarm.cli:main"}
