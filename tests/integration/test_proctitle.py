"""Each process of a run names itself in ``ps`` and ``top``: its role, its drone and its run
(``swarm.proctitle``), forked from the fork server or started from scratch alike."""

from __future__ import annotations

from pathlib import Path

import pytest

from swarm.config import load
from swarm.proctitle import title
from swarm.runs.reaper import GROUPS_FILE

pytestmark = pytest.mark.integration

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _titles(groups: Path) -> dict[str, str]:
    """The command line and kernel name (``/proc/<pid>/cmdline``, ``comm``) of each process the
    run has listed, by command line."""
    out = {}
    for pid in groups.read_text().split() if groups.exists() else ():
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().strip()
            out[cmd] = Path(f"/proc/{pid}/comm").read_text().strip()
        except OSError:  # (ended)
            continue
    return out


def test_every_process_of_a_run_shows_its_role_drone_and_run(start_run):
    cfg = load(CONFIGS / "swap_2.yaml", {"name": "titled", "duration_s": 30.0})
    h = start_run(cfg)
    want = {title("world", h.run), title("recorder", h.run), *(title("agent", h.run, a.id) for a in cfg.agents)}
    h.wait_sim_time(0.05)  # the world ticks (lockstep): every agent, the recorder and the world are up
    seen = _titles(h.out / GROUPS_FILE)
    assert want <= set(seen), sorted(seen)
    name = title("agent", h.run, "cf1")
    assert seen[name] == name.removeprefix("swarm ")[:15]  # the kernel's name: 15 bytes of it
    h.finish("test done")
