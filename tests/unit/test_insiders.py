"""A run's own agent that misbehaves: what its states may say (statewire.Plausible), what the
relay takes from it (bundle.Intake), what each neighbour table takes, and how the metrics
name it. Pure parts, by their definitions."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from swarm.config import load
from swarm.net import statewire
from swarm.net import transport as tp
from swarm.net.bundle import Bundler, Intake
from swarm.net.neighbours import HELD_TICKS, HeardNeighbours, NeighbourTable
from swarm.offline.metrics import Silence, offenders
from swarm.realism.settings import RealismSettings

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
RUN = "r1"
LIMITS = statewire.Plausible((-5.0, -5.0, -1.0), (5.0, 5.0, 4.0), 30.0, 0.1, ahead_s=1.0, behind_s=0.08)


def test_the_bounds_hold_every_start_and_goal_and_the_speed_is_flat_out_across_them():
    cfg = load(CONFIGS / "swap_2.yaml")
    p = statewire.Plausible.of(cfg)
    lo, hi = np.array(p.lo_w), np.array(p.hi_w)
    pts = np.array([p for a in cfg.agents for p in (a.start, a.final_goal)])
    np.testing.assert_allclose(lo[:2], pts[:, :2].min(axis=0) - statewire.BOUNDS_MARGIN_M)
    np.testing.assert_allclose(hi, pts.max(axis=0) + statewire.BOUNDS_MARGIN_M)
    assert lo[2] == -1.0  # below the floor: 1 m
    params = cfg.agents[0].airframe.params()
    a_max = (params.thrust_to_weight + 1.0) * 9.81  # all rotors flat out, gravity helping
    assert p.max_speed_mps == pytest.approx(math.sqrt(2.0 * a_max * float(np.linalg.norm(hi - lo))))
    assert p.max_radius_m == params.body_radius_m
    assert p.ahead_s == pytest.approx(2.0 / cfg.time.control_hz)  # lockstep: two ticks
    assert p.behind_s == pytest.approx(statewire.REORDER_TICKS / cfg.time.control_hz)
    assert p.reason((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), 0.07) is None
    assert p.reason((1000.0, 0.0, 1.0), (0.0, 0.0, 0.0), 0.07) == statewire.OUTSIDE  # a kilometre away
    assert p.reason((0.0, 0.0, 1.0), (0.0, 0.0, p.max_speed_mps + 0.1), 0.07) == statewire.TOO_FAST
    assert p.reason((0.0, 0.0, 1.0), (0.0, 0.0, 0.0), 5.0) == statewire.TOO_LARGE


def test_the_relay_takes_one_plausible_state_per_sender_and_tick_in_order():
    intake = Intake(LIMITS, ahead_s=1.0)
    x, v = (0.0, 0.0, 1.0), (0.0, 0.0, 0.0)
    assert intake.admit("cf3", 5.0, x, v, 0.07)  # (before the world's first status: no horizon yet)
    for _ in range(999):  # a thousand states for one tick: one taken
        assert not intake.admit("cf3", 5.0, x, v, 0.07)
    assert not intake.admit("cf3", 4.99, x, v, 0.07)  # an old tick again
    assert intake.admit("cf1", 4.99, x, v, 0.07)  # (another sender's ticks are its own)
    assert not intake.admit("cf3", 5.01, (0.0, 1000.0, 1.0), v, 0.07)
    assert not intake.admit("cf3", 5.01, x, (300.0, 0.0, 0.0), 0.07)
    intake.run_at(5.0)
    assert not intake.admit("cf3", 6.02, x, v, 0.07)  # more than a second ahead of the world
    assert intake.admit("cf3", 5.99, x, v, 0.07)
    assert intake.rejected == {
        "cf3": {
            statewire.REPEATED: 999,
            statewire.OUT_OF_ORDER: 1,
            statewire.OUTSIDE: 1,
            statewire.TOO_FAST: 1,
            statewire.AHEAD: 1,
        }
    }


def test_the_relay_waits_once_for_an_agent_whose_states_never_come():
    b = Bundler(["a", "b", "c"], [2.0, 2.0, 2.0], lockstep=True, wait_s=0.5)
    for n in "abc":
        b.set_live(n, True)
    z = np.zeros(3)
    for n in "ab":
        b.add(n, 0, z, b"", 10.0)
    assert not b.due(10.4) and b.due(10.5)  # c holds tick 0 up until the deadline
    b.take(10.5)
    for n in "ab":
        b.add(n, 1, z, b"", 10.6)
    assert b.due(10.6)  # not tick 1: the bundles went without it once
    b.take(10.6)
    b.add("c", 1, z, b"", 10.7)  # heard again: waited for again
    b.add("a", 2, z, b"", 10.8)
    assert b.waiting_for() == 2 and not b.due(10.8)


def _bundle(states: list[tuple]) -> np.ndarray:
    """The records a bundle carries, checked as an agent checks them (statewire.read_bundle)."""
    records = [statewire.encode_state(RUN, *s) for s in states]
    return statewire.read_bundle(statewire.encode_bundle(RUN, "cf1", 1, 0.0, 0, records), RUN).states.records


def _state(seq: int, k: int, x=(0.0, 0.0, 1.0), v=(0.0, 0.0, 0.0), r=0.07, src="cf3") -> tuple:
    """(src, seq, t, k, x, v, r) of :func:`statewire.encode_state`, at 100 Hz."""
    return (src, seq, k * 0.01, k, x, v, r)


def _table() -> NeighbourTable:
    t = NeighbourTable(timeout_s=0.1, growth_mps=0.5, hard_limit_s=1.0, on_lost="keep_stopped")
    t.limits = LIMITS
    t.at(0.0)
    return t


def test_a_neighbour_table_drops_and_counts_each_kind_of_bad_state_against_its_sender():
    t, counter = _table(), tp.Counter()
    good = _state(2, 0)
    t.update_records(_bundle([good]), {"cf2", "cf3"}, counter)
    t.update_records(_bundle([good]), {"cf2", "cf3"}, counter)  # the relay bundles a late state again: fine
    assert counter.dropped == 0 and t.state("cf3").k == 0
    bad = [
        _state(3, 0),  # the same tick, another state: a repeat
        _state(4, 1, x=(0.0, 1000.0, 1.0)),  # a kilometre away
        _state(5, 1, v=(0.0, 100.0, 0.0)),  # faster than any airframe
        _state(6, 1, r=3.0),  # a sphere of 3 m
        _state(7, 500),  # 5 s ahead of the newest tick heard of
    ]
    t.update_records(_bundle(bad), {"cf2", "cf3"}, counter)
    t.update_records(_bundle([_state(8, 20), _state(9, 1)]), {"cf2", "cf3"}, counter)  # the second: long before
    assert t.state("cf3").k == 20 and counter.dropped == 6
    assert t.rejected == {
        "cf3": {
            statewire.REPEATED: 1,
            statewire.OUTSIDE: 1,
            statewire.TOO_FAST: 1,
            statewire.TOO_LARGE: 1,
            statewire.AHEAD: 1,
            statewire.OUT_OF_ORDER: 1,
        }
    }
    # and through the other intake (a state message per neighbour: interest all, cells)
    t.update("cf2", 0.0, 0, np.zeros(3), np.zeros(3), 0.07)
    t.update("cf2", 0.0, 0, np.zeros(3), np.zeros(3), 0.07)
    t.update("cf2", 0.01, 1, np.array([0.0, 0.0, 900.0]), np.zeros(3), 0.07)
    assert t.rejected["cf2"] == {statewire.REPEATED: 1, statewire.OUTSIDE: 1}


def test_before_its_first_tick_an_agent_takes_any_plausible_time():
    t = NeighbourTable(timeout_s=0.1, growth_mps=0.5, hard_limit_s=1.0)
    t.limits = LIMITS
    t.update_records(_bundle([_state(1, 500)]), {"cf3"}, tp.Counter())
    assert t.state("cf3").k == 500 and t.rejected == {}


def test_a_state_a_tick_late_fills_the_history_and_is_no_offence():
    t, counter = _table(), tp.Counter()
    t.update_records(_bundle([_state(4, 2)]), {"cf3"}, counter)
    t.update_records(_bundle([_state(2, 1)]), {"cf3"}, counter)  # (a mesh's links reorder now and then)
    assert counter.dropped == 0 and t.state("cf3", 1).k == 1 and t.state("cf3").k == 2
    t.update("cf2", 0.02, 2, np.zeros(3), np.zeros(3), 0.07)
    t.update("cf2", 0.01, 1, np.zeros(3), np.zeros(3), 0.07)
    assert t.rejected == {} and t.state("cf2", 1).k == 1


def test_a_relays_copy_of_a_state_is_no_offence_through_every_intake():
    t = _table()
    z = np.zeros(3)
    t.update("cf3", 0.0, 0, z, z, 0.07, seq=5)
    t.update("cf3", 0.0, 0, z, z, 0.07, seq=5)  # bundled again (a late neighbour's newest state)
    assert t.rejected == {}
    t.update("cf3", 0.0, 0, z, z, 0.07, seq=6)  # another state of the same tick: a repeat
    assert t.rejected == {"cf3": {statewire.REPEATED: 1}}
    # with world.realism.comms each bundled state takes its own way to the table: the copy too
    lab = RealismSettings.model_validate({"preset": "ideal", "comms": {"state": {"delay_s": 0.015}}})
    heard = HeardNeighbours({"cf3"}, _table(), "cf1", lab.comms_model(seed=1, tick_s=0.01))
    for _ in range(2):
        heard.take("cf3", 0.0, 0, z, z, 0.07, False, bundled=True, seq=5)
    heard.rows(0.05, 5, z, lockstep=True)
    assert heard.table.latest_k("cf3") == 0 and heard.table.rejected == {}


def test_an_agent_waits_once_for_a_neighbour_whose_states_stop():
    t, counter = _table(), tp.Counter()
    heard = HeardNeighbours({"cf3"}, t, "cf1")
    for k in range(3):
        t.update_records(_bundle([_state(1 + k, k)]), {"cf3"}, counter)
    heard.on_list(3, ["cf3"])
    heard.on_list(4, ["cf3"])
    assert heard.missing(3) == 0 and heard.missing(4) == 1  # tick 4 needs its state of 3: wait
    heard.late(4)  # the deadline passed: tick 4 flown without it
    for k in (5, 6, 50):  # not waited for again ...
        heard.on_list(k, ["cf3"])
        assert heard.missing(k) == 0
    heard.at(0.05)
    t.update_records(_bundle([_state(9, 5)]), {"cf3"}, counter)
    heard.on_list(7, ["cf3"])
    assert heard.missing(7) == 1  # ... until a newer state of it is taken
    heard.late(7)
    t.update_records(_bundle([_state(10, 6, x=(0.0, 1000.0, 1.0))]), {"cf3"}, counter)  # dropped: not heard
    heard.on_list(8, ["cf3"])
    assert heard.missing(8) == 0 and t.rejected["cf3"] == {statewire.OUTSIDE: 1}
    heard.at(0.08)
    t.update_records(_bundle([_state(11, 8)]), {"cf3"}, counter)
    heard.on_list(10, ["cf3"])
    assert heard.missing(10) == 1 and heard.missing(60) == 1  # heard again: waited for; a list not yet come
    for k in range(100, 100 + HELD_TICKS):  # the world flew on without this agent
        heard.on_list(k, ["cf3"])
    assert heard.missing(10) == 0  # its backlog's ticks, older than every list held: no wait ...
    heard.on_list(11, ["cf3"])
    assert heard.missing(11) == 0  # ... and the neighbour it lacked then is passed over


def test_a_flood_of_one_tick_keeps_one_state():
    t, counter = _table(), tp.Counter()
    t.update_records(_bundle([_state(1 + i, 3) for i in range(1000)]), {"cf3"}, counter)
    assert counter.dropped == 999 and t.rejected["cf3"] == {statewire.REPEATED: 999}
    assert t.state("cf3").k == 3


def test_a_neighbour_gone_implausible_is_kept_as_its_last_good_state_allows():
    t, counter = _table(), tp.Counter()
    x0, v0 = (1.0, 0.0, 1.0), (-0.5, 0.0, 0.0)
    t.update_records(_bundle([_state(1, 0, x=x0, v=v0)]), {"cf3"}, counter)
    for k in range(1, 100):  # then only NaN (dropped as the bundle is read) and a kilometre away
        t.at(k * 0.01)
        t.update_records(_bundle([_state(1 + k, k, x=(1000.0, 0.0, 1.0))]), {"cf3"}, counter)
    rows = t.arrays(0.5)
    assert t.row_names == ["cf3"]  # not forgotten
    np.testing.assert_allclose(rows.c_w[0], [1.0 - 0.5 * 0.5, 0.0, 1.0])  # extrapolated from the last good state
    assert rows.radius_m[0] == pytest.approx(0.07 + 0.5 * (0.5 - 0.1))  # and grown past the timeout
    late = t.arrays(2.0)
    np.testing.assert_allclose(late.c_w[0], x0)  # past the hard limit: a stopped obstacle where it was last
    nan = statewire.encode_state(RUN, "cf3", 500, 1.0, 100, (math.nan, 0.0, 1.0), v0, 0.07)
    checked = statewire.read_bundle(statewire.encode_bundle(RUN, "cf1", 2, 1.0, 100, [nan]), RUN).states
    assert len(checked.records) == 0 and sum(checked.dropped.values()) == 1


def test_decode_failures_of_a_state_are_counted_against_its_keys_agent():
    assert tp.state_sender("swarm/r1/agent/cf3/state") == "cf3"
    assert tp.state_sender("swarm/r1/cell/1/-2/0/cf3") == "cf3"
    assert tp.state_sender("swarm/r1/world/clock") is None
    c = tp.Counter()
    c.drop("state: not finite", "cf3")
    c.drop("state: not finite", "cf3")
    assert tp.rejected(c.by_sender, {"cf3": {"x": 1}, "cf2": {"y": 2}}) == {
        "cf3": {"state: not finite": 2, "x": 1},
        "cf2": {"y": 2},
    }


def test_the_metrics_name_the_offenders_and_the_silent():
    silence = Silence()
    for k in range(300):  # cf1 answers every tick; cf3 is live and never commands
        silence.see({"kind": "clock", "t": k * 0.01, "live": ["cf1", "cf3"]})
    for k in range(300):  # (a batch's commands come after its clocks in the file)
        silence.see({"kind": "command", "src": "cf1", "t": k * 0.01})
    assert silence.longest_s["cf1"] == pytest.approx(0.01) and silence.longest_s["cf3"] == pytest.approx(2.99)
    said = {
        "agent-cf1": {"rejected": {"cf2": {statewire.OUTSIDE: 4}}},
        "router": {"rejected": {"cf2": {statewire.REPEATED: 999, statewire.OUTSIDE: 1}}},
        "world": {"ticks": 299},
    }
    out = offenders(said, silence.longest_s, silent_after_s=1.0)
    assert sorted(out) == ["cf2", "cf3"]
    assert out["cf2"]["dropped"] == 1004 and out["cf2"]["dropped_by"] == ["agent-cf1", "router"]
    assert out["cf2"]["reasons"][statewire.OUTSIDE] == 5
    assert out["cf3"]["dropped"] == 0 and out["cf3"]["longest_silence_s"] == pytest.approx(2.99)
