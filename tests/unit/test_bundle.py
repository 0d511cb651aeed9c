"""The bundles' rules (swarm.net.bundle.Bundler): who is in an agent's bundle, and when a
tick's bundles are due, in lockstep and in realtime, with stalled and dead agents."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.net.bundle import Bundler


def _rec(name: str, k: int) -> bytes:
    return f"{name}@{k}".encode()  # the Bundler passes records on byte for byte, whatever they hold


def _add(b: Bundler, name: str, k: int, x, now_s: float = 0.0) -> None:
    b.add(name, k, np.asarray(x, float), _rec(name, k), now_s)


def _lockstep(wait_s: float = 0.5) -> Bundler:
    b = Bundler(["a", "b", "c"], [2.0, 2.0, 2.0], lockstep=True, wait_s=wait_s)
    for n in "abc":
        b.set_live(n, True)
    return b


def test_lockstep_bundles_are_due_once_every_live_agent_sent_the_tick_and_hold_those_within_the_radius():
    b = _lockstep()
    assert not b.due(0.0) and b.deadline_s() is None  # nothing yet: nothing due, no deadline
    _add(b, "a", 0, [0, 0, 1])
    _add(b, "b", 0, [1.5, 0, 1])
    assert b.waiting_for() == 1 and not b.due(0.1)
    _add(b, "c", 0, [5, 0, 1], 0.1)  # far from both
    assert b.waiting_for() == 0 and b.due(0.1)
    k, out = b.take(0.1)
    assert k == 0
    assert dict(out) == {"a": [_rec("b", 0)], "b": [_rec("a", 0)], "c": []}  # c gets its (empty) bundle too
    assert not b.due(0.2) and b.next_k == 1


def test_a_stalled_agent_holds_the_others_up_only_until_the_deadline():
    b = _lockstep(wait_s=0.5)
    _add(b, "a", 0, [0, 0, 1], 10.0)
    _add(b, "b", 0, [1, 0, 1], 10.1)
    assert b.deadline_s() == 10.0 + 0.5
    assert not b.due(10.4) and b.due(10.5)
    k, out = b.take(10.5)
    assert k == 0 and dict(out) == {"a": [_rec("b", 0)], "b": [_rec("a", 0)]}  # c sent nothing: no bundle, in none
    _add(b, "c", 0, [0.5, 0, 1], 10.6)  # its late state of tick 0: the others' tick 1 waits for it
    assert b.due(10.6)
    k, out = b.take(10.6)  # tick 0's bundles again, with it, at once
    assert k == 0 and dict(out)["a"] == [_rec("b", 0), _rec("c", 0)] and b.next_k == 1
    assert b.waiting_for() == 3 and not b.due(10.6)  # tick 1's wait is as it was
    _add(b, "c", 0, [0.5, 0, 1], 10.65)  # (the same tick again: not sent a third time)
    assert not b.due(10.65)
    for n, x in (("a", [0, 0, 1]), ("b", [1, 0, 1])):
        _add(b, n, 1, x, 10.7)
    assert b.waiting_for() == 1  # still c, for tick 1
    k, out = b.take(11.2)
    assert k == 1 and dict(out)["a"] == [_rec("b", 1), _rec("c", 0)]  # c's newest state of tick <= 1


def test_a_dead_agent_is_not_waited_for_and_states_of_the_next_tick_start_its_wait():
    b = _lockstep()
    b.set_live("c", False)
    _add(b, "a", 0, [0, 0, 1])
    _add(b, "a", 1, [0, 0, 1])  # a is a tick ahead (its tick 1 came before b's tick 0)
    _add(b, "b", 0, [1, 0, 1], 0.2)
    assert b.due(0.2)
    b.take(0.3)
    assert b.deadline_s() == 0.3 + 0.5  # tick 1's wait started: a's state of it is here
    _add(b, "b", 1, [1, 0, 1], 0.4)
    assert b.due(0.4) and b.take(0.4)[0] == 1


def test_realtime_bundles_carry_each_agents_newest_state_once_all_live_sent_one():
    b = Bundler(["a", "b"], [2.0, 2.0], lockstep=False, wait_s=0.005)
    for n in "ab":
        b.set_live(n, True)
    _add(b, "a", 3, [0, 0, 1], 1.0)
    _add(b, "a", 4, [0, 0, 1], 1.001)
    assert not b.due(1.002) and b.due(1.006)  # b silent: the deadline
    _add(b, "b", 7, [1, 0, 1], 1.003)
    assert b.due(1.003)
    k, out = b.take(1.003)
    assert k == 7 and dict(out) == {"a": [_rec("b", 7)], "b": [_rec("a", 4)]}
    assert not b.due(2.0)  # nothing fresh since


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(-5, 5), st.floats(-5, 5), st.floats(0, 3), st.floats(0.1, 4)
        ),  # x, y, z [m], interest radius [m]
        min_size=1,
        max_size=12,
    )
)
def test_a_bundle_holds_exactly_the_other_agents_within_the_receivers_interest_radius(agents):
    ids = [f"a{i}" for i in range(len(agents))]
    b = Bundler(ids, [r for *_, r in agents], lockstep=True, wait_s=1.0)
    for i, (x, y, z, _) in enumerate(agents):
        b.set_live(ids[i], True)
        _add(b, ids[i], 0, [x, y, z])
    assert b.due(0.0)
    _, out = b.take(0.0)
    got = dict(out)
    assert set(got) == set(ids)
    p = np.array([a[:3] for a in agents])
    for i, name in enumerate(ids):
        r = agents[i][3]
        want = [_rec(ids[j], 0) for j in range(len(ids)) if j != i and np.sum((p[j] - p[i]) ** 2) <= r * r]
        assert got[name] == want, (name, got[name], want)
