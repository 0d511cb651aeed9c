"""Agents' states on the wire: one fixed little-endian record per state, and the bundle of
them that the run's router sends each agent once per tick (``neighbours.interest: bundle``).

A state is what a neighbour needs of an agent: its body centre ``x`` [m, world], velocity
``v`` [m/s, world], bounding radius ``r`` [m], the standard deviations ``sd`` of its position
[m] and velocity [m/s] (its estimate's, the largest axis: the receiver's live margins,
``swarm.step``), and ``solo`` (it is not doing its share of
a pair's avoidance now). It travels as one :data:`STATE` record of 144 bytes instead of a
msgpack map, so that a receiver reads all of a tick's states with one ``np.frombuffer``
and checks them as arrays (:func:`check_states`). A :data:`BUNDLE` is a 72-byte header
and the senders' records as they published them, byte for byte.

Checks: size, magic, schema version, the run (as :func:`run_tag`, a 64-bit hash of the
run id), the sender's id (ASCII, as the config allows), and finite numbers with a
non-negative radius and deviations no larger than :data:`MAX_STD_M` and
:data:`MAX_VEL_STD_MPS`. A record that fails is dropped and counted by the receiver.

What a well-formed state may say is :class:`Plausible`: a body centre inside the world's
bounds, a speed the airframe can reach there, a radius no larger than the run's largest
airframe's. A run's own agent that says otherwise (a bug, a crashed estimator) is dropped
and counted too, by the relay and by each receiving agent's neighbour table.
"""

from __future__ import annotations

import hashlib
import math
import re
import struct
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from swarm.errors import DecodeError

if TYPE_CHECKING:
    from swarm.config import ScenarioConfig

VERSION = 11  # the message schema version (swarm.net.messages.VERSION) these records belong to
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
        ("sd", "<f8", (2,)),  # standard deviation of its position [m] and velocity [m/s] (largest axis)
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
_STATE_PACK = struct.Struct("<3sBIQQqd3d3dd2d32s")
_BUNDLE_PACK = struct.Struct("<3sBIQQqd32s")
_ID = re.compile(rb"[A-Za-z0-9_-]{1,32}")
if _STATE_PACK.size != STATE.itemsize or _BUNDLE_PACK.size != BUNDLE.itemsize:  # pragma: no cover
    raise ImportError("swarm.net.statewire: record layouts disagree")


@lru_cache(maxsize=64)
def run_tag(run: str) -> int:
    """The run id as the 64-bit tag the records carry (BLAKE2b, little-endian)."""
    return int.from_bytes(hashlib.blake2b(run.encode(), digest_size=8).digest(), "little")


def encode_state(
    run: str,
    src: str,
    seq: int,
    t: float,
    k: int,
    x: object,
    v: object,
    r: float,
    solo: bool = False,
    sd: tuple[float, float] = (0.0, 0.0),
) -> bytes:
    """One state record (:data:`STATE`); ``sd``: the position [m] and velocity [m/s] standard
    deviations of the sender's estimate (0: exact)."""
    xs = [float(e) for e in np.asarray(x, float).reshape(3)]
    vs = [float(e) for e in np.asarray(v, float).reshape(3)]
    return _STATE_PACK.pack(
        STATE_MAGIC, VERSION, int(bool(solo)), seq, run_tag(run), k, float(t), *xs, *vs, float(r),
        float(sd[0]), float(sd[1]), src.encode(),
    )  # fmt: skip


def record_time(record: bytes) -> float:
    """Sim time [s] of one state record."""
    return float(struct.unpack_from("<d", record, 32)[0])


def encode_bundle(run: str, dst: str, seq: int, t: float, k: int, records: list[bytes]) -> bytes:
    """A bundle of ``records`` (each as :func:`encode_state` made it) for agent ``dst``."""
    head = _BUNDLE_PACK.pack(BUNDLE_MAGIC, VERSION, len(records), seq, run_tag(run), k, float(t), dst.encode())
    return head + b"".join(records)


_MV = int.from_bytes(STATE_MAGIC + bytes([VERSION]), "little")  # magic and version as one integer
_WORDS = STATE.itemsize // 8  # a record as 18 little-endian 64-bit words: 0 magic, version, flags;
# 1 seq; 2 run; 3 k; 4-13 the floats t, x, v, r, sd; 14-17 the sender id
MAX_STD_M = 1.0
"""The largest position deviation [m] a state may carry: an estimate worse than this is no
state to fly near (the monitor lands its own drone long before, ``swarm.safety.monitor``)."""
MAX_VEL_STD_MPS = 10.0
"""The largest velocity deviation [m/s] a state may carry."""
NOT_A_STATE, ANOTHER_RUN, BAD_FLAGS_OR_TICK, NOT_FINITE, BAD_DEVIATION = 1, 2, 3, 4, 5
REASONS = {
    NOT_A_STATE: f"not a state of schema version {VERSION}",
    ANOTHER_RUN: "another run",
    BAD_FLAGS_OR_TICK: "bad flags or tick",
    NOT_FINITE: "not finite, or a negative radius",
    BAD_DEVIATION: "a negative or implausible deviation",
}


@njit(cache=True)
def _verdicts(u, f, mv, tag, max_sd, max_sdv, out):
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
            for j in range(4, 14):
                if not np.isfinite(f[i, j]):
                    v = 4
            if v == 0 and f[i, 11] < 0.0:
                v = 4
            if v == 0 and not (0.0 <= f[i, 12] <= max_sd and 0.0 <= f[i, 13] <= max_sdv):
                v = 5
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
    _verdicts(u, u.view(np.float64), np.uint64(_MV), np.uint64(run_tag(run)), MAX_STD_M, MAX_VEL_STD_MPS, verdict)
    if not verdict.any():
        return States(records, {})
    codes, counts = np.unique(verdict[verdict != 0], return_counts=True)
    dropped = {REASONS[int(c)]: int(m) for c, m in zip(codes, counts, strict=True)}
    return States(records[verdict == 0], dropped)


def read_state(payload: bytes, run: str) -> tuple:
    """One state message, checked whole, as the fields of :data:`STATE` (magic, ver,
    flags, seq, run, k, t, x0, x1, x2, v0, v1, v2, r, sd_x, sd_v, src); DecodeError otherwise."""
    if len(payload) != STATE.itemsize:
        raise DecodeError(f"state: {len(payload)} bytes, expected {STATE.itemsize}")
    f = _STATE_PACK.unpack(payload)
    if f[0] != STATE_MAGIC or f[1] != VERSION:
        raise DecodeError(f"state: not a state of schema version {VERSION}")
    if f[4] != run_tag(run):
        raise DecodeError("state: another run")
    if f[2] > 1 or f[5] < 0:
        raise DecodeError("state: bad flags or tick")
    if not all(map(math.isfinite, f[6:16])) or f[13] < 0:
        raise DecodeError("state: not finite, or a negative radius")
    if not (0.0 <= f[14] <= MAX_STD_M and 0.0 <= f[15] <= MAX_VEL_STD_MPS):
        raise DecodeError("state: a negative or implausible deviation")
    if _ID.fullmatch(f[16].rstrip(b"\0")) is None:
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


REORDER_TICKS = 8  # (a neighbour table's history: swarm.net.neighbours.NeighbourTable.HISTORY)
BOUNDS_MARGIN_M = 5.0
"""How far beyond every start, goal and waypoint of the run a drone may plausibly be [m]."""
G_MPS2 = 9.81


@dataclass(frozen=True)
class Plausible:
    """What a state of one run may say (the receivers' plausibility checks).

    ``lo_w``/``hi_w`` [m, world]: the world's bounds, the box of every agent's start, goal
    and waypoints grown by :data:`BOUNDS_MARGIN_M` (below the floor only 1 m). ``max_speed_mps``:
    the airframe's limit there, the speed a drone reaches from its start speed accelerating
    flat out, every rotor at full thrust with gravity helping, ``(thrust_to_weight + 1) g``,
    in a straight line across the whole box: ``sqrt(v0^2 + 2 a D)`` for the box diagonal D
    (the world has no drag, so no lower top speed holds). ``max_radius_m``: the largest
    bounding radius among the run's airframes. ``ahead_s``: how far [s] a neighbour's state
    may be ahead of the newest tick the receiver has heard of: in lockstep two ticks (every
    agent acts on the tick the world sent, whose clock may reach one agent a little after
    another's state of it), in realtime a second (an agent acts on the newest measurement it
    has; none is a second ahead of the world). ``behind_s``: how much older than the newest
    state taken from its sender a state may come and still be taken (it fills a receiver's
    history by tick, never replaces a newer state): :data:`REORDER_TICKS` ticks, as the links of
    a mesh now and then hand a receiver a sender's state after its next one, plus the jitter of
    the states' and bundles' delays in ``world.realism.comms`` (a state delayed more reaches
    the table after a newer one); older is dropped."""

    lo_w: tuple[float, float, float]
    hi_w: tuple[float, float, float]
    max_speed_mps: float
    max_radius_m: float
    ahead_s: float = 1.0  # s
    behind_s: float = 0.0  # s

    @classmethod
    def of(cls, cfg: ScenarioConfig) -> Plausible:
        pts = np.array([p for a in cfg.agents for p in (*a.path(), a.final_goal)], dtype=float)
        lo, hi = pts.min(axis=0) - BOUNDS_MARGIN_M, pts.max(axis=0) + BOUNDS_MARGIN_M
        lo[2] = min(-1.0, float(pts[:, 2].min()) - 1.0)
        params = [a.airframe.params() for a in cfg.agents]
        a_max = (max(p.thrust_to_weight for p in params) + 1.0) * G_MPS2  # m/s^2
        v0 = max(math.hypot(*a.start_velocity) for a in cfg.agents)
        v_max = math.sqrt(v0 * v0 + 2.0 * a_max * float(np.linalg.norm(hi - lo)))
        r_max = max(p.body_radius_m for p in params)
        ahead_s = 2.0 / cfg.time.control_hz if cfg.time.mode.value == "lockstep" else 1.0
        lo_w, hi_w = (float(lo[0]), float(lo[1]), float(lo[2])), (float(hi[0]), float(hi[1]), float(hi[2]))
        comms = cfg.world.realism.comms
        behind_s = REORDER_TICKS / cfg.time.control_hz + comms.state.jitter_s + comms.bundle.jitter_s
        return cls(lo_w, hi_w, v_max, r_max, ahead_s, behind_s)

    def reason(self, x_w: tuple[float, ...], v_w: tuple[float, ...], r_m: float) -> str | None:
        """Why a finite state (body centre ``x_w`` [m, world], velocity ``v_w`` [m/s],
        radius ``r_m`` [m]) is implausible, or None."""
        lo, hi = self.lo_w, self.hi_w
        if not all(lo[i] <= x_w[i] <= hi[i] for i in range(3)):
            return OUTSIDE
        if v_w[0] * v_w[0] + v_w[1] * v_w[1] + v_w[2] * v_w[2] > self.max_speed_mps * self.max_speed_mps:
            return TOO_FAST
        if r_m > self.max_radius_m:
            return TOO_LARGE
        return None

    def as_array(self) -> np.ndarray:
        """(lo x, y, z, hi x, y, z, max speed, max radius, behind_s) for compiled checks."""
        return np.array([*self.lo_w, *self.hi_w, self.max_speed_mps, self.max_radius_m, self.behind_s])


OUTSIDE = "state: outside the world's bounds"
TOO_FAST = "state: faster than the airframe can fly"
TOO_LARGE = "state: larger than any airframe of the run"
REPEATED = "state: a tick it already sent"
OUT_OF_ORDER = "state: a tick well before one it sent"
AHEAD = "state: ahead of the run"
