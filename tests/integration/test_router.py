"""Agents' states through a real Zenoh router or a star's bundle relay, each agent hearing
only the states near it (``neighbours.interest: bundle``, the relay's bundles, swarm.net.bundle,
or ``cells`` through the router, swarm.net.cells).

* a lockstep run by bundles or by cells flies bit for bit what the same run flies when every
  agent hears every other (``interest: all``), so lockstep repeats, and no neighbour that
  the filter would have used is ever missing, including for agents that cross many cell
  borders at full speed (a same-config repeat: tests/integration/test_determinism.py);
* realtime through the router flies the circle without collision;
* the router's and the relay's access control accept from each sender only its own keys;
* a killed router (or relay) stops the run with the cause in one line.
"""

from __future__ import annotations

import json
import signal
import time

import numpy as np
import pytest

from swarm.net import statewire
from swarm.net import transport as tp
from swarm.net.cells import cell_of
from swarm.net.messages import encode
from tools.bench_swarm import summaries

from .conftest import scenario, wait_linked
from .test_runtime import trajectories


def _run(start_run, cfg, name):
    h = start_run(cfg, name)
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    _, agents = summaries(h.out)
    silent = {a.id for a in cfg.agents} - {a["id"] for a in agents}
    tails = {i: (h.out / "logs" / f"agent-{i}.log").read_text()[-1500:] for i in sorted(silent)}
    assert not silent, (m["exit_codes"], tails)  # each agent's log ends with its summary
    return h, m, {a["id"]: a for a in agents}


def _crossing(network=None, **over):
    """Two columns of four drones flying through each other at 1.5 m/s along x, through
    1 m cells: each crosses six or seven cell borders, meeting the other column on the way."""
    agents = []
    for i in range(4):
        y = -1.5 + i
        agents.append({"id": f"e{i}", "start": [0.0, y, 1.0], "goal": [6.0, y + 0.3, 1.0]})
        agents.append({"id": f"w{i}", "start": [6.0, y + 0.3, 1.2], "goal": [0.0, y, 1.2]})
    net = {"network": network} if network else {}
    return scenario(
        "swap_2.yaml",
        name="crossing",
        duration_s=10.0,
        agents=agents,
        defaults={"speed_mps": 1.5, "filter": {"sensing_radius_m": 2.0}},
        world={"realism": "ideal"},  # (in the lab world a bundled state is two link delays late, a direct one one)
        **{"neighbours": {"source": "agents", "cell_m": 1.0, **over}, **net},
    )


def test_crossing_cell_borders_at_full_speed_misses_no_neighbour_and_flies_as_hearing_everyone(start_run):
    """By cells and by the router's bundles the agents fly bit for bit what they fly when
    every agent hears every other, and hear less."""
    everyone = _crossing(interest="all")
    _, m_all, agents_all = _run(start_run, everyone, "all")
    # (bundles through the router: the netns, access and realtime tests)
    for interest, topology in (("cells", "router"), ("bundle", "star")):
        cfg = _crossing(interest=interest, **({"network": {"topology": topology}} if topology == "router" else {}))
        assert cfg.topology == topology and cfg.interest == interest
        h, m, agents = _run(start_run, cfg, f"{interest}_{topology}")
        assert m["collisions"] == 0 and m["all_reached_goal"], m
        assert m["dropped_messages"] == 0 and m["late_ticks"] == 0
        for a in agents.values():
            assert a["missed_neighbours"] == 0 and a["dropped"] == 0, a
            if interest == "cells":
                assert a["cells_declared"] > 100, a  # it followed its cells along the way (about 150 at the start)
        a, b = trajectories(h.out), trajectories(h.out.parent / "all")
        assert a.keys() == b.keys() == {x.id for x in cfg.agents}
        for agent in a:  # the same rows, so the same flight, bit for bit: lockstep through the router repeats
            assert a[agent].keys() == b[agent].keys()
            for k in a[agent]:
                np.testing.assert_array_equal(a[agent][k], b[agent][k])
        # and each agent heard fewer bytes than with everyone's states
        rx = np.mean([x["rx_bytes"] / x["ticks"] for x in agents.values()])
        rx_all = np.mean([x["rx_bytes"] / x["ticks"] for x in agents_all.values()])
        assert rx < rx_all, (interest, rx, rx_all)


def test_realtime_circle_8_through_the_router_flies_without_collision(start_run):
    cfg = scenario(
        "circle_8.yaml",
        neighbours={"source": "agents"},
        network={"topology": "router"},
        time={"mode": "realtime", "late_command": "brake"},
    )
    assert cfg.topology == "router" and cfg.uses_bundles
    h, m, agents = _run(start_run, cfg, "realtime")
    assert m["collisions"] == 0 and m["all_reached_goal"], m
    assert m["min_separation_m"] > 2 * 0.07
    world, _ = summaries(h.out)
    for a in agents.values():  # every agent acted on most of the world's ticks (realtime skips a late one)
        assert a["ticks"] >= 0.5 * world["ticks"], (a, world["ticks"])


@pytest.mark.parametrize("topology", ["router", "star"])
def test_the_router_accepts_from_each_client_only_its_own_keys(start_run, topology):
    """A session with cf2's credentials publishes cf1's state (on cf1's key and in cf1's
    cell), a bundle for cf1, a command for cf1, and the world's clock (all marked), and a
    probe under its own keys; another session counts what the router forwards (in a star,
    what the hubs publish: no hub forwards), and no bundle holds the forged state."""
    cfg = scenario(
        "swap_2.yaml",
        name="routed",
        duration_s=8.0,
        stop_when_all_reached=False,
        network={"topology": topology},
        time={"mode": "realtime", "late_command": "brake"},
    )
    assert cfg.topology == topology and cfg.uses_bundles
    h = start_run(cfg, f"routed_{topology}")
    h.wait_sim_time(0.3)
    keys = tp.Keys(h.run)
    forger = tp.open_session(tp.process_config(h.cfg, tp.Role.AGENT, h.access(tp.Role.AGENT, "cf2")))
    observer = tp.open_session(tp.process_config(h.cfg, tp.Role.OBSERVER, h.access(tp.Role.OBSERVER)))
    heard = tp.open_channel(observer, f"{keys.root}/**", 1 << 16)
    cell = cell_of([0.0, 0.0, 1.0], h.cfg.cell_m)
    fake = encode("state", h.run, "cf1", 7, 0.0, 0, x=[0.0, 0.0, 1.0], v=[0.0, 0.0, 0.0], r=0.07, solo=False)
    fake2 = encode("state", h.run, "cf2", 7, 0.0, 0, x=[0.0, 0.0, 1.0], v=[0.0, 0.0, 0.0], r=0.07, solo=False)
    forgeries = {
        keys.cell_state(cell, "cf1"): fake,
        keys.state("cf1"): fake,
        keys.bundle("cf1"): statewire.encode_bundle(h.run, "cf1", 1, 0.0, 0, [fake2]),
        keys.command("cf1"): b"forged command",
        keys.clock: b"forged clock",
        keys.tick("cf1"): b"forged tick",
    }
    probe = keys.cell_state(cell, "cf2")
    if topology == "router":
        wait_linked(h, forger, heard, probe, "the router")  # (its probes under its own keys arrive)
    else:  # linked to the relay and the world once it hears what they publish
        own = tp.open_channel(forger, keys.bundle("cf2"))
        clock = tp.open_channel(forger, keys.clock)
        for channel in (own, clock):
            assert tp.wait_sample(channel, time.monotonic() + 30.0) is not None
    for _ in range(20):
        h.wait_sim_time(h.progress.t_s + 0.05)
        for key, data in forgeries.items():
            forger.put(key, data)
        forger.put(probe, b"probe")
    assert h.wait() == "completed"
    counts = {"real cf1 states": 0, "forged": 0, "probes": 0, "bundles for cf1": 0, "cf1 states bundled": 0}
    for smp in tp.drain(heard):
        data, key = tp.payload(smp), str(smp.key_expr)
        if data in forgeries.values():
            counts["forged"] += 1
        elif data == b"probe":
            counts["probes"] += 1
        elif key == keys.state("cf1"):
            counts["real cf1 states"] += 1
        elif key.startswith(f"{keys.root}/router/bundle/"):
            counts["bundles for cf1"] += key == keys.bundle("cf1")
            records = statewire.read_bundle(data, h.run).states.records
            senders = records["src"].tolist()
            counts["cf1 states bundled"] += senders.count(b"cf1")
            counts["forged"] += sum(r.tobytes() == fake for r in records)  # the relay took the forged state
    forger.close()
    observer.close()
    if topology == "router":  # the router forwards what it accepted; a star's hubs forward nothing
        assert counts["probes"] == 20 and counts["real cf1 states"] > 100, counts
    assert counts["forged"] == 0, counts
    assert counts["bundles for cf1"] > 100 and counts["cf1 states bundled"] > 100, counts
    _, agents = summaries(h.out)
    assert all(a["dropped"] == 0 for a in agents), agents  # no forgery reached an agent
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["all_reached_goal"]


@pytest.mark.parametrize("topology", ["router", "star"])
def test_a_killed_router_stops_the_run_with_its_cause(start_run, topology):
    """Through a router the run has lost every link; in a star the agents their neighbours."""
    cfg = scenario(
        "swap_2.yaml",
        name="router_kill",
        network={"topology": topology},
        time={"mode": "realtime", "late_command": "brake"},
    )
    assert cfg.uses_bundles
    h = start_run(cfg, f"router_kill_{topology}")
    h.wait_sim_time(1.0)
    h.kill("router", signal.SIGKILL)
    t0 = time.monotonic()
    reason = h.wait(timeout_s=60.0)
    assert time.monotonic() - t0 < 30.0
    why = "every link of the run" if topology == "router" else "it bundled the neighbours"
    assert reason.startswith("router killed by SIGKILL at t = ") and why in reason, reason
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["stop_reason"] == reason
    if topology == "router":  # the recorder lost its link too
        assert m["complete"] is False
