"""Wire messages: round trips, partial decodes, the clock, and garbage that never raises."""

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.net.messages import VERSION, DecodeError, clock_measurement, decode, encode, expand_record, to_json


def test_messages_round_trip():
    m = decode(
        encode("state", "r", "cf1", 7, 1.5, 3, x=np.array([1.0, 2, 3]), v=[0, 0, 0.5], r=0.07, solo=False),
        "r",
        ("state",),
    )
    assert (m.kind, m.src, m.seq, m.t, m.k) == ("state", "cf1", 7, 1.5, 3)
    np.testing.assert_array_equal(m["x"], [1, 2, 3])
    body = dict(
        level="rotors",
        u=[0.1, 0.1, 0.1, 0.1],
        intervention=0.2,
        goal_reached=True,
        min_h=-0.1,
        status="ok",
        infeasible=2,
        solve_us=40.0,
        dropped=0,
        row_ids=["ball"],
        h_rows=[0.5],
        est=[],
        monitor=3,
        breaches=2,
        live_margin=0.012,
        fallback="raised",
        fallbacks=3,
        ctrl_fallback="overrun",
        ctrl_fallbacks=1,
    )
    m = decode(encode("command", "r", "cf1", 8, 1.5, 3, **body), "r", ("command",))
    assert m["goal_reached"] is True and m["infeasible"] == 2 and m["u"].tolist() == [0.1] * 4
    assert (m["monitor"], m["breaches"], m["live_margin"]) == (3, 2, 0.012)
    assert (m["fallback"], m["fallbacks"], m["ctrl_fallback"], m["ctrl_fallbacks"]) == ("raised", 3, "overrun", 1)
    assert m["row_ids"] == ["ball"] and m["h_rows"].tolist() == [0.5]


def test_a_partial_decode_checks_the_fields_it_keeps_and_only_those():
    """The world decodes a command's level, input and status only: a malformed report is
    the recorder's to drop, a malformed input is still the world's."""
    fields = ("level", "u", "status")
    body = dict(
        level="rotors",
        u=[0.1] * 4,
        intervention=0.2,
        goal_reached=False,
        min_h=0.0,
        status="ok",
        infeasible=0,
        solve_us=40.0,
        dropped=0,
        row_ids=["ball", 3],
        h_rows=[0.5, float("nan")],
        est=[],
    )
    with pytest.raises(DecodeError):
        decode(encode("command", "r", "cf1", 8, 1.5, 3, **body), "r", ("command",))
    m = decode(encode("command", "r", "cf1", 8, 1.5, 3, **body), "r", ("command",), fields)
    assert sorted(m.body) == sorted(fields) and m["u"].tolist() == [0.1] * 4 and (m.src, m.k) == ("cf1", 3)
    for bad in (dict(u=[0.1, float("inf"), 0.1, 0.1]), dict(status=1), dict(level=None)):
        with pytest.raises(DecodeError):
            decode(encode("command", "r", "cf1", 8, 1.5, 3, **{**body, **bad}), "r", ("command",), fields)
    with pytest.raises(DecodeError, match="missing field"):
        decode(
            encode("command", "r", "cf1", 8, 1.5, 3, **{k: v for k, v in body.items() if k != "u"}),
            "r",
            ("command",),
            fields,
        )


def _clock(**over):
    body = dict(
        live=["a", "b"],
        done=False,
        ids=["a", "b"],
        xvr=np.arange(14.0),
        meas_ids=["b"],
        meas=np.arange(13.0),
        items=[{"id": "s", "shape": "sphere", "c": [1, 2, 3], "cd": [0, 0, 0], "r": 0.5, "a": [0, 0, 0]}],
        solo=[],
        frames=[],
        skipped=0,
    )
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
    m = msgpack.unpackb(
        encode("measurement", "r", "world", 1, 0.0, 0, x=[0, 0, 1.0], v=[0, 0, 0], q=[0, 0, 0, 1.0], w=[0, 0, 0])
    )
    mutate(m)
    with pytest.raises(DecodeError):
        decode(msgpack.packb(m), "r")
