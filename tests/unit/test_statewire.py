"""The state record and the router's bundle: round trips, every check, and garbage that
never raises (swarm.net.statewire)."""

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.errors import DecodeError
from swarm.net import statewire as w
from swarm.net.messages import decode, encode


def _state(src="cf1", k=3, x=(1.0, 2.0, 3.0), run="r", solo=False, seq=7, sd=(0.002, 0.01)):
    return w.encode_state(run, src, seq, 0.01 * k, k, x, (0.0, 0.5, 0.0), 0.07, solo, sd)


def test_a_state_is_one_fixed_little_endian_record_of_the_documented_layout():
    data = _state(solo=True)
    assert len(data) == w.STATE.itemsize == 144
    rec = np.frombuffer(data, w.STATE)[0]
    assert rec["magic"] == b"C3S" and rec["ver"] == w.VERSION and rec["flags"] == 1
    assert rec["src"] == b"cf1" and rec["k"] == 3 and rec["seq"] == 7 and rec["run"] == w.run_tag("r")
    assert rec["x"].tolist() == [1.0, 2.0, 3.0] and rec["v"].tolist() == [0.0, 0.5, 0.0] and rec["r"] == 0.07
    assert rec["sd"].tolist() == [0.002, 0.01]
    # read by hand, byte by byte, as a receiver in another language would
    assert struct.unpack_from("<3d", data, 40) == (1.0, 2.0, 3.0)
    assert struct.unpack_from("<2d", data, 96) == (0.002, 0.01)
    assert data[112:115] == b"cf1" and data[115:144] == bytes(29)


def test_the_generic_decoder_reads_a_state_record_as_a_message():
    m = decode(encode("state", "r", "cf1", 7, 1.5, 3, x=[1, 2, 3], v=[0, 0, 0.5], r=0.07, solo=True), "r")
    assert (m.kind, m.src, m.seq, m.t, m.k, m["r"], m["solo"]) == ("state", "cf1", 7, 1.5, 3, 0.07, True)
    assert m["sd"] == (0.0, 0.0)  # (none given: an exact state)
    m = decode(
        encode("state", "r", "cf1", 7, 1.5, 3, x=[1, 2, 3], v=[0, 0, 0.5], r=0.07, solo=False, sd=(0.003, 0.02)), "r"
    )
    assert m["sd"] == (0.003, 0.02)
    with pytest.raises(DecodeError, match="unexpected kind"):
        decode(_state(), "r", ("command",))


@pytest.mark.parametrize(
    "offset, value, reason",
    [
        (0, b"X", "schema version|not msgpack"),  # magic: not a state record at all
        (3, bytes([w.VERSION - 1]), "schema version"),
        (16, b"\x01", "another run"),
        (4, b"\x02", "bad flags"),
        (31, b"\x80", "bad flags or tick"),  # k < 0
        (40, struct.pack("<d", float("nan")), "not finite"),
        (88, struct.pack("<d", -0.1), "negative radius"),
        (96, struct.pack("<d", float("inf")), "not finite"),  # the position deviation
        (96, struct.pack("<d", -0.001), "negative or implausible deviation"),
        (104, struct.pack("<d", -0.001), "negative or implausible deviation"),  # the velocity deviation
        (96, struct.pack("<d", 2.0), "negative or implausible deviation"),  # beyond MAX_STD_M
        (104, struct.pack("<d", 11.0), "negative or implausible deviation"),  # beyond MAX_VEL_STD_MPS
        (112, b"c f", "bad sender id"),
    ],
)
def test_each_check_of_a_state_drops_it_with_its_reason(offset, value, reason):
    bad = bytearray(_state())
    bad[offset : offset + len(value)] = value
    with pytest.raises(DecodeError, match=reason):
        decode(bytes(bad), "r")


def test_a_state_of_the_wrong_size_is_dropped():
    for data in (_state()[:-1], _state() + b"\0"):
        with pytest.raises(DecodeError, match="expected 144"):
            decode(data, "r")


def test_a_bundle_carries_the_records_byte_for_byte_and_drops_only_the_bad_ones():
    good = [_state("cf2", x=(0, 0, 1)), _state("cf3", x=(1, 0, 1))]
    nan = bytearray(_state("cf4"))
    nan[64:72] = struct.pack("<d", float("inf"))
    other_run = _state("cf5", run="another")
    b = w.read_bundle(w.encode_bundle("r", "cf1", 9, 0.03, 3, [*good, bytes(nan), other_run]), "r")
    assert (b.dst, b.seq, b.k, b.t) == ("cf1", 9, 3, 0.03)
    assert b.states.senders == ["cf2", "cf3"]
    assert b.states.records.tobytes() == b"".join(good)
    assert b.states.dropped == {"not finite, or a negative radius": 1, "another run": 1}


@pytest.mark.parametrize(
    "mangle, reason",
    [
        (lambda b: b[:-1], "not a header and whole states"),
        (lambda b: b[:40], "not a header"),
        (lambda b: b"X" + b[1:], "not a bundle"),
        (lambda b: b[:4] + struct.pack("<I", 3) + b[8:], "says 3 states, holds 2"),
        (lambda b: b[:16] + bytes(8) + b[24:], "another run"),
        (lambda b: b[:40] + b"\x00" * 32 + b[72:], "bad destination"),
    ],
)
def test_a_bad_bundle_header_drops_the_whole_bundle(mangle, reason):
    data = w.encode_bundle("r", "cf1", 1, 0.0, 0, [_state("cf2"), _state("cf3")])
    with pytest.raises(DecodeError, match=reason):
        w.read_bundle(mangle(data), "r")


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600))
def test_garbage_never_raises_anything_but_a_decode_error(data):
    for read in (lambda d: w.read_bundle(d, "r"), lambda d: decode(d, "r")):
        try:
            read(data)
        except DecodeError:
            pass
    # the same bytes as the records of a bundle whose header is right: each is kept or
    # dropped with a reason, never both, never lost
    n = len(data) // 128
    records = [data[128 * i : 128 * (i + 1)] for i in range(n)]
    b = w.read_bundle(w.encode_bundle("r", "cf1", 1, 0.0, 0, records), "r")
    assert len(b.states.records) + sum(b.states.dropped.values()) == n
