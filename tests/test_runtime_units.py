"""Pure pieces of the runtime: config, messages, neighbour table, metrics."""

import json
import math
from pathlib import Path

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.config import ConfigError, dump, load, resolve
from swarm.messages import VERSION, DecodeError, clock_measurement, decode, encode, expand_record, to_json
from swarm.metrics import compute
from swarm.neighbours import NeighbourTable, roster_arrays
from swarm.scenario import circle_swap

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@pytest.mark.parametrize("name", ["single_static_sphere.yaml", "swap_2.yaml", "circle_8.yaml"])
def test_shipped_configs_validate_and_round_trip(name, tmp_path):
    cfg = load(CONFIGS / name)
    (tmp_path / "c.yaml").write_text(dump(cfg))
    assert load(tmp_path / "c.yaml") == cfg


def test_layers_defaults_then_type_then_agent():
    cfg = resolve({
        "version": 1, "name": "t", "duration_s": 1.0,
        "defaults": {"speed_mps": 0.5, "filter": {"gamma": 2.0, "rho": 0.5}},
        "agent_types": {"fast": {"speed_mps": 2.0, "filter": {"gamma": 3.0}}},
        "agents": [{"id": "a", "start": [0, 0, 1], "type": "fast", "filter": {"rho": 1.0}},
                   {"id": "b", "start": [1, 0, 1]}],
    })  # fmt: skip
    a, b = cfg.agents
    assert (a.speed_mps, a.filter.gamma, a.filter.rho) == (2.0, 3.0, 1.0)
    assert (b.speed_mps, b.filter.gamma, b.filter.rho) == (0.5, 2.0, 0.5)


@pytest.mark.parametrize(
    "patch, field",
    [
        ({"agents": [{"id": "a", "start": [0, 0]}]}, "agents.0.start"),
        ({"agents": [{"id": "a", "start": [0, 0, 1], "speed_mps": -1}]}, "agents.0.speed_mps"),
        ({"agents": [{"id": "a", "start": [0, 0, 1], "filter": {"rho": 2}}]}, "agents.0.filter.rho"),
        ({"agents": [{"id": "a", "start": [0, 0, 1]}, {"id": "a", "start": [1, 0, 1]}]}, "duplicate agents id"),
        ({"agents": [{"id": "a", "start": [0, 0, 1], "type": "nope"}]}, "agents.0.type"),
        ({"time": {"physics_hz": 240, "control_hz": 100}}, "time"),
        ({"obstacles": [{"id": "o", "shape": "cylinder", "center": [0, 0, 0], "radius_m": 0.1}]}, "obstacles.0"),
        (
            {"obstacles": [{"id": "o", "shape": "sphere", "center": [0, 0, 0], "radius_m": -0.1}]},
            "obstacles.0.radius_m",
        ),
        ({"version": 2}, "version"),
        ({"surprise": 1}, "surprise"),
    ],
)
def test_config_errors_name_file_field_and_reason(patch, field):
    raw = {"version": 1, "name": "t", "duration_s": 1.0, "agents": [{"id": "a", "start": [0, 0, 1]}]}
    raw.update(patch)
    with pytest.raises(ConfigError) as err:
        resolve(raw, "my.yaml")
    assert str(err.value).startswith("my.yaml: ") and field in str(err.value)


def test_unreadable_and_invalid_yaml_files(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load(tmp_path / "missing.yaml")
    (tmp_path / "bad.yaml").write_text("agents: [\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load(tmp_path / "bad.yaml")


def test_generated_circle_is_antipodal_and_valid():
    cfg = resolve(circle_swap(6, 2.0))
    for a in cfg.agents:
        np.testing.assert_allclose(np.add(a.start[:2], a.goal[:2]), 0.0, atol=1e-9)
        assert math.hypot(*a.start[:2]) == pytest.approx(2.0)


def test_messages_round_trip():
    m = decode(encode("state", "r", "cf1", 7, 1.5, 3, x=np.array([1.0, 2, 3]), v=[0, 0, 0.5], r=0.07, solo=False), "r",
               ("state",))  # fmt: skip
    assert (m.kind, m.src, m.seq, m.t, m.k) == ("state", "cf1", 7, 1.5, 3)
    np.testing.assert_array_equal(m["x"], [1, 2, 3])
    body = dict(
        level="rotors", u=[0.1, 0.1, 0.1, 0.1], intervention=0.2, goal_reached=True, min_h=-0.1, status="ok",
        infeasible=2, solve_us=40.0, dropped=0, row_ids=["ball"], h_rows=[0.5],
    )  # fmt: skip
    m = decode(encode("command", "r", "cf1", 8, 1.5, 3, **body), "r", ("command",))
    assert m["goal_reached"] is True and m["infeasible"] == 2 and m["u"].tolist() == [0.1] * 4
    assert m["row_ids"] == ["ball"] and m["h_rows"].tolist() == [0.5]


def test_a_partial_decode_checks_the_fields_it_keeps_and_only_those():
    """The world decodes a command's level, input and status only: a malformed report is
    the recorder's to drop, a malformed input is still the world's."""
    fields = ("level", "u", "status")
    body = dict(level="rotors", u=[0.1] * 4, intervention=0.2, goal_reached=False, min_h=0.0, status="ok",
                infeasible=0, solve_us=40.0, dropped=0, row_ids=["ball", 3], h_rows=[0.5, float("nan")])  # fmt: skip
    with pytest.raises(DecodeError):
        decode(encode("command", "r", "cf1", 8, 1.5, 3, **body), "r", ("command",))
    m = decode(encode("command", "r", "cf1", 8, 1.5, 3, **body), "r", ("command",), fields)
    assert sorted(m.body) == sorted(fields) and m["u"].tolist() == [0.1] * 4 and (m.src, m.k) == ("cf1", 3)
    for bad in (dict(u=[0.1, float("inf"), 0.1, 0.1]), dict(status=1), dict(level=None)):
        with pytest.raises(DecodeError):
            decode(encode("command", "r", "cf1", 8, 1.5, 3, **{**body, **bad}), "r", ("command",), fields)
    with pytest.raises(DecodeError, match="missing field"):
        decode(encode("command", "r", "cf1", 8, 1.5, 3, **{k: v for k, v in body.items() if k != "u"}), "r",
               ("command",), fields)  # fmt: skip


def _clock(**over):
    body = dict(live=["a", "b"], done=False, ids=["a", "b"], xvr=np.arange(14.0), meas_ids=["b"],
                meas=np.arange(13.0), items=[{"id": "s", "shape": "sphere", "c": [1, 2, 3], "cd": [0, 0, 0],
                                              "r": 0.5, "a": [0, 0, 0]}], solo=[])  # fmt: skip
    return encode("clock", "r", "world", 4, 0.5, 50, **{**body, **over})


def test_the_clock_carries_each_measured_drone_and_the_obstacles():
    m = decode(_clock(), "r", ("clock",))
    mine = clock_measurement(m, "b")
    assert mine is not None and (mine.kind, mine.k, mine.t) == ("measurement", 50, 0.5)
    assert [mine[f].tolist() for f in ("x", "v", "q", "w")] == [[0, 1, 2], [3, 4, 5], [6, 7, 8, 9], [10, 11, 12]]
    assert clock_measurement(m, "a") is None  # in the roster, but not measured by the world (a real drone)
    recs = expand_record(to_json(m))
    assert [r["kind"] for r in recs] == ["clock", "measurement", "obstacles"]
    assert recs[1]["agent"] == "b" and recs[1]["q"] == [6, 7, 8, 9] and recs[1]["k"] == 50
    assert recs[2]["items"][0]["id"] == "s"


@pytest.mark.parametrize("over", [dict(xvr=np.arange(13.0)), dict(meas=np.arange(26.0)), dict(meas_ids=[])])
def test_a_clock_whose_arrays_do_not_match_its_ids_is_rejected(over):
    with pytest.raises(DecodeError, match="clock"):
        decode(_clock(**over), "r")


@pytest.mark.parametrize("over", [dict(live=["a", 2]), dict(ids="ab"), dict(meas_ids=[b"b"])])
def test_a_clock_with_a_bad_name_list_is_rejected(over):
    with pytest.raises(DecodeError, match="list of strings"):
        decode(_clock(**over), "r")


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_arbitrary_bytes_never_raise_anything_but_decode_error(data):
    try:
        decode(data, "r")
    except DecodeError:
        pass


@pytest.mark.parametrize(
    "mutate",
    [
        lambda m: m.update(ver=VERSION + 1),
        lambda m: m.update(run="other"),
        lambda m: m.update(kind="nope"),
        lambda m: m.pop("seq"),
        lambda m: m.update(x=np.array([1.0, 2.0]).tobytes()),  # too short
        lambda m: m.update(x=np.array([1.0, np.nan, 0.0]).tobytes()),
        lambda m: m.update(x=np.array([1.0, np.inf, 0.0]).tobytes()),
        lambda m: m.update(x=np.zeros(3).tobytes()[:-1]),  # not whole float64s
        lambda m: m.update(x=[1.0, 2.0, 3.0]),  # a list, not a float64 binary
        lambda m: m.update(q=np.zeros(4, dtype=np.float32).tobytes()),  # float32
        lambda m: m.update(t=float("inf")),
    ],
)
def test_bad_messages_are_rejected(mutate):
    m = msgpack.unpackb(encode("measurement", "r", "world", 1, 0.0, 0, x=[0, 0, 1.0], v=[0, 0, 0], q=[0, 0, 0, 1.0],
                               w=[0, 0, 0]))  # fmt: skip
    mutate(m)
    with pytest.raises(DecodeError):
        decode(msgpack.packb(m), "r")


def test_neighbours_extrapolate_grow_and_stop_when_lost():
    t = NeighbourTable(timeout_s=0.1, growth_mps=0.5, hard_limit_s=1.0, on_lost="keep_stopped")
    t.update("b", 0.0, 0, np.array([1.0, 0, 1]), np.array([-1.0, 0, 0]), 0.07)
    fresh = t.arrays(0.05)
    np.testing.assert_allclose(fresh.c_w[0], [0.95, 0, 1])  # constant-velocity extrapolation
    assert fresh.radius_m[0] == 0.07 and fresh.is_neighbour.all()
    stale = t.arrays(0.5)
    assert stale.radius_m[0] == pytest.approx(0.07 + 0.5 * 0.4)  # grows past the timeout
    lost = t.arrays(2.0)
    np.testing.assert_allclose(lost.c_w[0], [1.0, 0, 1])  # past the hard limit: stopped at last position
    np.testing.assert_array_equal(lost.c_dot_w[0], 0.0)
    t.mark_gone("b")
    np.testing.assert_array_equal(t.arrays(0.05).c_dot_w[0], 0.0)
    dropper = NeighbourTable(0.1, 0.5, 1.0, on_lost="drop")
    dropper.update("b", 0.0, 0, np.zeros(3), np.zeros(3), 0.07)
    dropper.mark_gone("b")
    assert len(dropper.arrays(0.0)) == 0


def test_neighbour_state_at_a_given_tick():
    t = NeighbourTable(0.1, 0.5, 1.0)
    for k in range(12):
        t.update("b", k * 0.01, k, np.array([k * 1.0, 0, 0]), np.zeros(3), 0.07)
    assert t.state("b", 5).k == 5 and t.state("b").k == 11
    assert t.state("b", 2) is None  # older than the kept history


def test_metrics_from_synthetic_records():
    cfg = resolve({
        "version": 1, "name": "m", "duration_s": 1.0, "goal_tolerance_m": 0.1,
        "agents": [{"id": "a", "start": [0, 0, 1], "goal": [1, 0, 1], "airframe": {"l_m": 0.0}},
                   {"id": "b", "start": [3, 0, 1], "goal": [5, 0, 1], "airframe": {"l_m": 0.0}}],
        "obstacles": [{"id": "s", "shape": "sphere", "center": [0.5, 1.0, 1.0], "radius_m": 0.5}],
    })  # fmt: skip
    recs = []
    for k in range(11):
        for aid, x in (("a", [0.1 * k, 0, 1]), ("b", [3.0 - 0.1 * k, 0, 1])):
            topic = f"/swarm/r/world/{aid}/measurement"
            recs.append(
                {"kind": "measurement", "topic": topic, "k": k, "t": 0.1 * k, "x": x, "q": [0, 0, 0, 1], "v": [0, 0, 0]}
            )
        sphere = {"id": "s", "shape": "sphere", "c": [0.5, 1.0, 1.0], "cd": [0, 0, 0], "r": 0.5, "a": [0, 0, 0]}
        recs.append({"kind": "obstacles", "k": k, "t": 0.1 * k, "items": [sphere]})
    recs.append({"kind": "collision", "a": "a", "b": "s", "k": 3, "t": 0.3})
    recs.append({"kind": "status", "t": 1.0, "k": 10, "rtf": 2.0, "late": 1, "dropped": 3, "live": ["a", "b"],
                 "min_sep": 1.0, "min_clear": 0.5, "collisions": 1, "done": True})  # fmt: skip
    m = compute(cfg, recs, recorder_dropped=2)
    assert m["collisions"] == 1 and m["late_ticks"] == 1 and m["dropped_messages"] == 5
    assert m["min_separation_m"] == pytest.approx(1.0)  # at k = 10: 1.0 vs 2.0
    assert m["min_obstacle_clearance_m"] == pytest.approx(0.5)  # (0.5, 0, 1) is 1.0 from the centre
    assert m["agents"]["a"]["reached_goal"] and m["agents"]["a"]["time_to_goal_s"] == pytest.approx(0.9)
    assert not m["agents"]["b"]["reached_goal"] and not m["all_reached_goal"]
    assert m["agents"]["a"]["path_length_m"] == pytest.approx(1.0)


def test_path_deviation_is_the_distance_to_the_polyline():
    from swarm.metrics import path_deviation

    path = np.array([[0.0, 0, 1], [2.0, 0, 1], [2.0, 2, 1]])
    pts = np.array([[1.0, 0.3, 1], [2.5, 1.0, 1], [0.0, 0, 1]])
    assert path_deviation(pts, path) == pytest.approx(0.5)
    assert path_deviation(pts[:1], path[:1]) == pytest.approx(np.hypot(1.0, 0.3))


@pytest.mark.parametrize("path", sorted(Path(__file__).resolve().parent.parent.glob("configs/**/*.yaml")), ids=str)
def test_every_shipped_config_validates(path):
    cfg = load(path)
    assert cfg.agents


def test_the_cpu_plan_spreads_agents_round_robin_around_world_and_recorder():
    from tools.launch import cpu_plan

    assert cpu_plan(3, [0]) == {}  # one CPU: nothing to choose
    assert cpu_plan(4, [0, 1]) == {"world": 0, "recorder": 1, 0: 1, 1: 0, 2: 1, 3: 0}
    plan = cpu_plan(16, [2, 3, 5, 7])  # the CPUs this process may use, whatever their numbers
    assert plan["world"] == 2 and plan["recorder"] == 7
    assert [plan[i] for i in range(16)].count(3) == 4 and set(plan.values()) == {2, 3, 5, 7}


def test_roster_rows_are_the_chosen_drones_centres_velocities_and_radii():
    xvr = np.arange(4 * 7, dtype=float)  # 4 drones: x (3), v (3), r
    rows = np.array([0, 2, 3], dtype=np.intp)
    arr = roster_arrays(xvr, rows, np.zeros((3, 3)), np.ones(3, dtype=bool))
    want = xvr.reshape(4, 7)[rows]
    np.testing.assert_array_equal(arr.c_w, want[:, 0:3])
    np.testing.assert_array_equal(arr.c_dot_w, want[:, 3:6])
    np.testing.assert_array_equal(arr.radius_m, want[:, 6])
    assert arr.is_neighbour.all() and not arr.axis_w.any() and not arr.c_ddot_w.any()


def _net(**over: object):
    raw = {"version": 1, "name": "t", "duration_s": 1.0, "agents": [{"id": "a", "start": [0, 0, 1]}]}
    return resolve({**raw, **over}, "my.yaml")


def test_auto_topology_is_a_star_only_where_one_can_carry_the_run_and_a_router_for_agents_states():
    world = {"source": "world"}
    assert _net(neighbours=world).topology == "star"  # loopback peers, neighbours from the world
    assert _net().topology == "router"  # agents hear each other's states through a router
    assert _net(network={"host": "192.168.1.5"}).topology == "router"
    assert _net(neighbours=world, network={"host": "192.168.1.5"}).topology == "mesh"  # other machines may join
    assert _net(neighbours=world, network={"connect": ["tcp/10.0.0.2:7447"]}).topology == "mesh"
    assert _net(neighbours=world, network={"mode": "client"}).topology == "mesh"
    assert _net(network={"topology": "mesh"}, neighbours=world).topology == "mesh"
    with pytest.raises(ConfigError, match=r"my.yaml: .*network.topology: star .*neighbours.source: agents"):
        _net(network={"topology": "star"})
    with pytest.raises(ConfigError, match=r"network.topology: star needs network.mode: peer"):
        _net(network={"topology": "star", "mode": "client"}, neighbours=world)
    with pytest.raises(ConfigError, match=r"network.topology: star needs network.port <= 65533"):
        _net(network={"topology": "star", "port": 65534}, neighbours=world)
    assert _net(neighbours=world, network={"port": 65534}).topology == "mesh"


def test_a_router_links_every_other_process_to_itself_alone():
    from swarm import transport as tp

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
    from swarm import transport as tp

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
    mesh = tp.process_config(_net(network={"port": 7000, "topology": "mesh"}), tp.Role.AGENT)
    assert get(mesh, "connect/endpoints") == [hub[0]] and get(mesh, "transport/unicast/lowlatency") is False


def test_free_port_leaves_room_for_the_hubs():
    import socket

    from tools.launch import free_port

    port = free_port()
    for p in range(port, port + 3):
        with socket.socket() as s:
            s.bind(("127.0.0.1", p))  # free
