"""Integration tests start real processes (world, agents, recorder) talking over Zenoh on
loopback with multicast scouting off and a free explicit port. They wait on messages
and exit codes with deadlines, never on fixed sleeps, and always stop the process
groups they started."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from swarm.config import ScenarioConfig, load
from tools.launch import RunHandle

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def scenario(file: str, **over: object) -> ScenarioConfig:
    """A shipped config with top-level fields replaced (dicts merge)."""
    return load(CONFIGS / file, dict(over))


@pytest.fixture
def start_run(tmp_path: Path) -> Iterator:
    handles: list[RunHandle] = []

    def start(cfg: ScenarioConfig, name: str = "run") -> RunHandle:
        h = RunHandle.start(cfg, tmp_path / name)
        handles.append(h)
        return h

    yield start
    for h in handles:
        if h.reason is None:
            h.finish("test teardown")
