"""Integration tests start real processes (world, agents, recorder) talking over Zenoh on
loopback with multicast scouting off and a free explicit port. They wait on messages
and exit codes with deadlines, never on fixed sleeps, and always stop the process
groups they started."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from swarm.config import ScenarioConfig, load
from swarm.runs.launch import RunHandle

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


def wait_linked(h: RunHandle, session: Any, heard: Any, probe_key: str, what: str = "the run") -> None:
    """Until a put of ``session`` on ``probe_key`` (its own keys) reaches the channel ``heard``
    of another session of the run: the first is linked. Raises after 100 tries, each one world
    status message apart."""
    from swarm.net import transport as tp

    for _ in range(100):
        session.put(probe_key, b"hello")
        h.wait_sim_time(h.progress.t_s + 0.02)
        if any(tp.payload(x) == b"hello" for x in tp.drain(heard)):
            return
    raise AssertionError(f"the session never linked to {what}")
