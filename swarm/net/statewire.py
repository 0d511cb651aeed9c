"""Agents' states on the wire: one fixed little-endian record per state, and the bundle of
them that the run's router sends each agent once per tick (``neighbours.interest: bundle``).

A state is what a neighbour needs of an agent: its body centre ``x`` [m, world], velocity
``v`` [m/s, world], bounding radius ``r`` [m], and ``solo`` (it is not doing its share of
a pair's avoidance now). It travels as one :data:`STATE` record of 128 bytes instead of a
msgpack map, so that a receiver reads all of a tick's states with one ``np.frombuffer``
and checks them as arrays (:func:`check_states`). A :data:`BUNDLE` is a 72-byte header
and the senders' records as they published them, byte for byte.

Checks: size, magic, schema version, the run (as :func:`run_tag`, a 64-bit hash of the
run id), the sender's id (ASCII, as the config allows), and finite numbers with a
non-negative radius. A record that fails is dropped and counted by the receiver.
"""

from __future__ import annotations

import hashlib
import math
import re
import struct
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from swarm.errors import DecodeError

VERSION = 8  # the message schema version (swarm.net.messages.VERSION) these records belong to
STATE_MAGIC = b"C3S"
BUNDLE_MAGIC = b"C3B"
ID_BYTES = 32  # agent ids are at most 32 ASCII characters (swarm.config)

STATE = np.dtype(
    [
        ("magic", "S3"),
        ("ver", "u1"),
        ("flags", "<u4"),  # bit 0: solo
        ("seq", "<u8"),  # the sender's sequence number
        ("run", "<u8"),  # run_tag(run id)
        ("k", "<i8"),  # control tick of the state
        ("t", "<f8"),  # sim time of the state [s]
        ("x", "<f8", (3,)),  # body centre [m, world]
        ("v", "<f8", (3,)),  # its velocity [m/s, world]
        ("r", "<f8"),  # bounding radius [m]
        ("src", f"S{ID_BYTES}"),  # sender id, NUL-padded ASCII
    ]
)
BUNDLE = np.dtype(
    [
        ("magic", "S3"),
        ("ver", "u1"),
        ("count", "<u4"),  # STATE records after the header
        ("seq", "<u8"),  # the router's sequence number
        ("run", "<u8"),
        ("k", "<i8"),  # the tick whose states it bundles
        ("t", "<f8"),  # sim time of that tick [s] (newest state's)
        ("dst", f"S{ID_BYTES}"),  # the agent it is for
    ]
)
_STATE_PACK = struct.Struct("<3sBIQQqd3d3dd32s")
_BUNDLE_PACK = struct.Struct("<3sBIQQqd32s")
_ID = re.compile(rb"[A-Za-z0-9_-]{1,32}")
if _STATE_PACK.size != STATE.itemsize or _BUNDLE_PACK.size != BUNDLE.itemsize:  # pragma: no cover
    raise ImportError("swarm.net.statewire: record layouts disagree")


@lru_cache(maxsize=64)
def run_tag(run: str) -> int:
    """The run id as the 64-bit tag the records carry (BLAKE2b, little-endian)."""
    return int.from_bytes(hashlib.blake2b(run.encode(), digest_size=8).digest(), "little")


def encode_state(
    run: str, src: str, seq: int, t: float, k: int, x: object, v: object, r: float, solo: bool = False
) -> bytes:
    """One state record (:data:`STATE`)."""
    xs = [float(e) for e in np.asarray(x, float).reshape(3)]
    vs = [float(e) for e in np.asarray(v, float).reshape(3)]
    return _STATE_PACK.pack(
        STATE_MAGIC, VERSION, int(bool(solo)), seq, run_tag(run), k, float(t), *xs, *vs, float(r), src.encode()
    )


def record_time(record: bytes) -> float:
    """Sim time [s] of one state record."""
    return float(struct.unpack_from("<d", record, 32)[0])


def encode_bundle(run: str, dst: str, seq: int, t: float, k: int, records: list[bytes]) -> bytes:
    """A bundle of ``records`` (each as :func:`encode_state` made it) for agent ``dst``."""
    head = _BUNDLE_PACK.pack(BUNDLE_MAGIC, VERSION, len(records), seq, run_tag(run), k, float(t), dst.encode())
    return head + b"".join(records)


_MV = int.from_bytes(STATE_MAGIC + bytes([VERSION]), "little")  # magic and version as one integer
_WORDS = STATE.itemsize // 8  # a record as 16 little-endian 64-bit words: 0 magic, version, flags;
# 1 seq; 2 run; 3 k; 4-11 the floats t, x, v, r; 12-15 the sender id
NOT_A_STATE, ANOTHER_RUN, BAD_FLAGS_OR_TICK, NOT_FINITE = 1, 2, 3, 4
REASONS = {
    NOT_A_STATE: f"not a state of schema version {VERSION}",
    ANOTHER_RUN: "another run",
    BAD_FLAGS_OR_TICK: "bad flags or tick",
    NOT_FINITE: "not finite, or a negative radius",
}


@njit(cache=True)
def _verdicts(u, f, mv, tag, out):
    """out[i]: 0 if record i passes, else the first check it fails (REASONS)."""
    for i in range(u.shape[0]):
        w0 = u[i, 0]
        v = 0
        if (w0 & np.uint64(0xFFFFFFFF)) != mv:
            v = 1
        elif u[i, 2] != tag:
            v = 2
        elif (w0 >> np.uint64(32)) > np.uint64(1) or u[i, 3] >= np.uint64(1 << 63):
            v = 3
        else:
            for j in range(4, 12):
                if not np.isfinite(f[i, j]):
                    v = 4
            if f[i, 11] < 0.0:
                v = 4
        out[i] = v


@dataclass(frozen=True)
class States:
    """Checked state records (:data:`STATE` array) and how many were dropped, by reason."""

    records: np.ndarray
    dropped: dict[str, int]

    @property
    def senders(self) -> list[str]:
        return [s.decode() for s in self.records["src"].tolist()]


def check_states(records: np.ndarray, run: str) -> States:
    """The records of ``run`` that pass every check but the sender's id (the receiver
    looks each id up among the agents it knows: see the module docstring)."""
    n = records.shape[0]
    if n == 0:
        return States(records, {})
    u = np.frombuffer(records.data, np.uint64).reshape(n, _WORDS)
    verdict = np.empty(n, dtype=np.int8)
    _verdicts(u, u.view(np.float64), np.uint64(_MV), np.uint64(run_tag(run)), verdict)
    if not verdict.any():
        return States(records, {})
    codes, counts = np.unique(verdict[verdict != 0], return_counts=True)
    dropped = {REASONS[int(c)]: int(m) for c, m in zip(codes, counts, strict=True)}
    return States(records[verdict == 0], dropped)


def read_state(payload: bytes, run: str) -> tuple:
    """One state message, checked whole, as the fields of :data:`STATE` (magic, ver,
    flags, seq, run, k, t, x0, x1, x2, v0, v1, v2, r, src); DecodeError otherwise."""
    if len(payload) != STATE.itemsize:
        raise DecodeError(f"state: {len(payload)} bytes, expected {STATE.itemsize}")
    f = _STATE_PACK.unpack(payload)
    if f[0] != STATE_MAGIC or f[1] != VERSION:
        raise DecodeError(f"state: not a state of schema version {VERSION}")
    if f[4] != run_tag(run):
        raise DecodeError("state: another run")
    if f[2] > 1 or f[5] < 0:
        raise DecodeError("state: bad flags or tick")
    if not all(map(math.isfinite, f[6:14])) or f[13] < 0:
        raise DecodeError("state: not finite, or a negative radius")
    if _ID.fullmatch(f[14].rstrip(b"\0")) is None:
        raise DecodeError("state: bad sender id")
    return f


@dataclass(frozen=True)
class Bundle:
    """A checked bundle: its header fields and its checked states."""

    dst: str
    seq: int
    t: float
    k: int
    states: States


def read_bundle(payload: bytes, run: str) -> Bundle:
    """A bundle message, its header checked whole (DecodeError otherwise) and its records
    one by one (:func:`check_states`: the bad ones are dropped and counted)."""
    n = len(payload) - BUNDLE.itemsize
    if n < 0 or n % STATE.itemsize:
        raise DecodeError(f"bundle: {len(payload)} bytes is not a header and whole states")
    magic, ver, count, seq, tag, k, t, dst = _BUNDLE_PACK.unpack_from(payload)
    if magic != BUNDLE_MAGIC or ver != VERSION:
        raise DecodeError(f"bundle: not a bundle of schema version {VERSION}")
    if tag != run_tag(run):
        raise DecodeError("bundle: another run")
    if count * STATE.itemsize != n:
        raise DecodeError(f"bundle: says {count} states, holds {n // STATE.itemsize}")
    if not math.isfinite(t) or k < 0:
        raise DecodeError("bundle: bad time or tick")
    dst = dst.rstrip(b"\0")
    if _ID.fullmatch(dst) is None:
        raise DecodeError("bundle: bad destination id")
    records = np.frombuffer(payload, STATE, offset=BUNDLE.itemsize)
    return Bundle(dst.decode(), seq, t, k, check_states(records, run))
