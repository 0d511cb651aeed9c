"""The run's status channel counts the agents whose safety monitor acts, and the progress line
shows it."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.cli import _status_info
from swarm.net.messages import decode, encode
from swarm.safety.monitor import Action
from swarm.world.main import AgentSlot, monitor_acting

pytestmark = pytest.mark.unit


def test_the_status_counts_the_live_agents_whose_monitor_slows_holds_or_lands_them():
    slots = [AgentSlot(goal=np.zeros(3), monitor=int(a)) for a in Action]  # none, warn, slow, hold, land
    assert monitor_acting(slots) == 3
    slots[-1].dead = True  # a dead agent's drone is the world's, whatever it last said
    assert monitor_acting(slots) == 2
    assert monitor_acting([AgentSlot(goal=np.zeros(3))]) == 0


def test_the_progress_line_says_how_many_monitors_act():
    body = dict(rtf=1.0, min_sep=0.5, min_clear=1.0, collisions=0, late=0, dropped=0, live=["a", "b"], done=False,
                infeasible=0, stalls=0, dead=[], acting=2, fallback_ids=[], fallback_ticks=[])  # fmt: skip
    st = decode(encode("status", "r", "world", 1, 1.0, 100, **body), "r", ("status",)).body
    assert st["acting"] == 2 and "monitor: 2 acting" in _status_info(st)
    assert "monitor" not in _status_info({**st, "acting": 0})


def test_the_progress_line_counts_plugin_fallbacks():
    body = dict(rtf=1.0, min_sep=0.5, min_clear=1.0, collisions=0, late=0, dropped=0, live=["a", "b"], done=False,
                infeasible=0, stalls=0, dead=[], acting=0, fallback_ids=["b"], fallback_ticks=[7.0])  # fmt: skip
    st = decode(encode("status", "r", "world", 1, 1.0, 100, **body), "r", ("status",)).body
    assert st["fallback_ids"] == ["b"] and "plugin fallbacks 7" in _status_info(st)
    assert "plugin" not in _status_info({**st, "fallback_ids": [], "fallback_ticks": []})
