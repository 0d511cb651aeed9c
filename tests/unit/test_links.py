"""Which processes link to which (topologies), the CPU plan and free ports."""

import json

import pytest

from swarm.config import ConfigError, resolve


def test_the_cpu_plan_spreads_agents_round_robin_around_world_and_recorder():
    from swarm.runs.launch import cpu_plan

    assert cpu_plan(3, [0]) == {}  # one CPU: nothing to choose
    assert cpu_plan(4, [0, 1]) == {"world": 0, "recorder": 1, 0: 1, 1: 0, 2: 1, 3: 0}
    plan = cpu_plan(16, [2, 3, 5, 7])  # the CPUs this process may use, whatever their numbers
    assert plan["world"] == 2 and plan["recorder"] == 7
    assert [plan[i] for i in range(16)].count(3) == 4 and set(plan.values()) == {2, 3, 5, 7}


def _net(**over: object):
    raw = {"version": 1, "name": "t", "duration_s": 1.0, "agents": [{"id": "a", "start": [0, 0, 1]}]}
    return resolve({**raw, **over}, "my.yaml")


def test_auto_topology_is_a_star_only_where_one_can_carry_the_run_and_a_router_for_agents_states():
    world = {"source": "world"}
    assert _net(neighbours=world).topology == "star"  # loopback peers, neighbours from the world
    star = _net()  # agents hear each other's states in bundles from the star's relay
    assert star.topology == "star" and star.uses_bundles and star.star_hubs[-1] == "router"
    cells = _net(neighbours={"interest": "cells"})  # states by cell need links between agents
    assert cells.topology == "router" and cells.uses_cells
    assert _net(network={"host": "192.168.1.5"}).topology == "router"
    assert _net(network={"host": "192.168.1.5"}).uses_bundles
    from pathlib import Path

    from swarm.config import load

    mixed = load(Path(__file__).resolve().parents[2] / "configs" / "mixed_mock.yaml")  # real drones: by cells
    assert mixed.topology == "router" and mixed.uses_cells
    assert _net(neighbours=world, network={"host": "192.168.1.5"}).topology == "mesh"  # other machines may join
    assert _net(neighbours=world, network={"connect": ["tcp/10.0.0.2:7447"]}).topology == "mesh"
    assert _net(neighbours=world, network={"mode": "client"}).topology == "mesh"
    assert _net(network={"topology": "mesh"}, neighbours=world).topology == "mesh"
    with pytest.raises(ConfigError, match=r"my.yaml: .*network.topology: star .*neighbours.source: agents"):
        _net(network={"topology": "star"}, neighbours={"interest": "all"})
    with pytest.raises(ConfigError, match=r"my.yaml: .*interest: bundle needs the run's bundle relay"):
        _net(network={"topology": "mesh"}, neighbours={"interest": "bundle"})
    with pytest.raises(ConfigError, match=r"network.topology: star needs network.port <= 65532"):
        _net(network={"topology": "star", "port": 65533})  # four hubs with the relay
    with pytest.raises(ConfigError, match=r"network.topology: star needs network.mode: peer"):
        _net(network={"topology": "star", "mode": "client"}, neighbours=world)
    with pytest.raises(ConfigError, match=r"network.topology: star needs network.port <= 65533"):
        _net(network={"topology": "star", "port": 65534}, neighbours=world)
    assert _net(neighbours=world, network={"port": 65534}).topology == "mesh"


def test_a_router_links_every_other_process_to_itself_alone():
    from swarm.net import transport as tp

    cfg = _net(network={"port": 7000, "host": "10.0.0.1"})
    assert cfg.topology == "router"

    def get(conf, key):
        return json.loads(conf.get_json(key))

    router = tp.links(cfg, tp.Role.ROUTER)
    assert get(router, "mode") == "router" and get(router, "listen/endpoints") == ["tcp/10.0.0.1:7000"]
    for role in (tp.Role.WORLD, tp.Role.AGENT, tp.Role.RECORDER, tp.Role.LAUNCHER, tp.Role.OBSERVER):
        conf = tp.links(cfg, role)
        assert get(conf, "mode") == "client", role
        assert get(conf, "connect/endpoints") == ["tcp/10.0.0.1:7000"], role


def test_star_links_every_process_to_the_hubs_alone():
    from swarm.net import transport as tp

    cfg = _net(neighbours={"source": "world"}, network={"port": 7000})
    hub = [f"tcp/127.0.0.1:{p}" for p in (7000, 7001, 7002)]  # world, recorder, launcher

    def get(conf, key):
        return json.loads(conf.get_json(key))

    def links(role):
        c = tp.process_config(cfg, role)
        assert get(c, "scouting/gossip/enabled") is False and get(c, "transport/unicast/lowlatency") is True
        return get(c, "listen/endpoints"), get(c, "connect/endpoints")

    assert links(tp.Role.WORLD) == ([hub[0]], hub[1:])
    assert links(tp.Role.RECORDER) == ([hub[1]], hub[2:])
    assert links(tp.Role.LAUNCHER) == ([hub[2]], [])  # started first: it connects to nobody
    assert links(tp.Role.AGENT) == ([], hub)
    assert links(tp.Role.OBSERVER) == ([], hub)
    cfg = _net(network={"port": 7000})  # agents' states: the bundle relay is the fourth hub, started first
    hub.append("tcp/127.0.0.1:7003")
    assert links(tp.Role.ROUTER) == ([hub[3]], [])
    assert links(tp.Role.LAUNCHER) == ([hub[2]], hub[3:])
    assert links(tp.Role.WORLD) == ([hub[0]], hub[1:])
    assert links(tp.Role.AGENT) == ([], hub)
    launcher = tp.process_config(cfg, tp.Role.LAUNCHER)  # it waits for the relay it has just started
    assert get(launcher, "connect/exit_on_failure") == {"peer": True} and get(launcher, "connect/timeout_ms")
    mesh = tp.process_config(_net(network={"port": 7000, "topology": "mesh"}), tp.Role.AGENT)
    assert get(mesh, "connect/endpoints") == [hub[0]] and get(mesh, "transport/unicast/lowlatency") is False


def test_free_port_leaves_room_for_the_hubs():
    import socket

    from swarm.runs.launch import free_port

    port = free_port()
    for p in range(port, port + 4):
        with socket.socket() as s:
            s.bind(("127.0.0.1", p))  # free
