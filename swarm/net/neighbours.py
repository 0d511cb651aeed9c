"""What an agent knows of the other agents (docs/design.md, "Failures"): last published state,
extrapolated at constant velocity, with a radius that grows once the state is older
than the timeout; past the hard limit, or once the neighbour's liveliness is gone, it
is kept as a stopped obstacle at its last position or dropped, as configured.

It takes only what a neighbour can have meant (docs/design.md, "A run's own agents"): with
:attr:`NeighbourTable.limits` set, a plausible state (:class:`swarm.net.statewire.Plausible`),
one per neighbour and tick in order (a state or two late is taken), none ahead of the newest tick this
agent has heard of by more than ``limits.ahead_s`` (:meth:`NeighbourTable.at`). Anything
else is dropped and counted against its sender (:attr:`NeighbourTable.rejected`), and the
neighbour is kept as its last good state allows: a neighbour that goes silent or
implausible is extrapolated and grows, not forgotten."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from swarm.net import statewire
from swarm.realism.comms import LOST, CommsModel, DelayLine, MessageKind
from swarm.rotation import BoolArray, FloatArray, IntArray
from swarm.safety.obstacles import OBSTACLE, NamedObstacles, ObstacleArrays


@njit(cache=True)
def _roster_fill(xvr, rows, is_nb, out):
    """Fill ``out`` (k,) :data:`swarm.safety.obstacles.OBSTACLE` with the drones ``rows`` of a
    roster ``xvr`` (n * 7,): centre, velocity, radius; no acceleration, spheres."""
    for i in range(rows.shape[0]):
        o = 7 * rows[i]
        ob = out[i]
        for j in range(3):
            ob.c[j] = xvr[o + j]
            ob.cd[j] = xvr[o + 3 + j]
            ob.cdd[j] = 0.0
            ob.axis[j] = 0.0
        ob.r = xvr[o + 6]
        ob.is_nb = is_nb[i]
        ob.is_agent = True
        ob.grow = 0.0


def roster_arrays(xvr: FloatArray, rows: IntArray, is_neighbour: BoolArray) -> ObstacleArrays:
    """The drones ``rows`` of a world roster ``xvr`` (per drone: body centre [m, world],
    its velocity [m/s, world], radius [m]) as rows: no acceleration, spheres, neighbour
    rows where ``is_neighbour`` (k,) says so (the others take the whole pair)."""
    out = np.empty(rows.shape[0], dtype=OBSTACLE)
    _roster_fill(xvr, rows, is_neighbour, out)
    return ObstacleArrays.of_records(out)


@dataclass
class Neighbour:
    t_s: float  # sim time of the state [s]
    k: int  # tick of the state
    x_w: FloatArray  # (3,) m, world: body centre
    v_w: FloatArray  # (3,) m/s, world
    radius_m: float  # its own bounding radius
    solo: bool = False  # it said it is not doing its share of a pair's avoidance


@dataclass
class _Slots:
    """The table's arrays: per neighbour slot ``i`` and history place ``j`` (a state of
    tick k sits at ``j = k % HISTORY``)."""

    k: IntArray  # (S, H) tick of the state, -1: none
    t: FloatArray  # (S, H) sim time of the state [s]
    x: FloatArray  # (S, H, 3) body centre [m, world]
    v: FloatArray  # (S, H, 3) its velocity [m/s, world]
    r: FloatArray  # (S, H) bounding radius [m]
    solo: BoolArray  # (S, H) not doing its share
    sd: FloatArray  # (S, H, 2) its estimate's position [m] and velocity [m/s] standard deviations
    latest: IntArray  # (S,) newest tick held, -1: none
    gone: BoolArray  # (S,) its liveliness is gone

    @classmethod
    def empty(cls, n: int, h: int) -> _Slots:
        return cls(
            np.full((n, h), -1, dtype=np.int64),
            np.zeros((n, h)),
            np.zeros((n, h, 3)),
            np.zeros((n, h, 3)),
            np.zeros((n, h)),
            np.zeros((n, h), dtype=np.bool_),
            np.zeros((n, h, 2)),
            np.full(n, -1, dtype=np.int64),
            np.zeros(n, dtype=np.bool_),
        )

    def grown(self, n: int) -> _Slots:
        """The same slots and ``n`` more, empty."""
        more = _Slots.empty(n, self.k.shape[1])
        return _Slots(*(np.concatenate([a, b]) for a, b in zip(self.fields(), more.fields(), strict=True)))

    def fields(self) -> tuple[np.ndarray, ...]:
        return (self.k, self.t, self.x, self.v, self.r, self.solo, self.sd, self.latest, self.gone)


@njit(cache=True)
def _store(table, slots, states):
    """Write state ``n`` of ``states`` = (t, k, x, v, r, flags, sd): tick k[n], time t[n] [s],
    centre x[n] [m, world], velocity v[n] [m/s, world], radius r[n] [m], solo bit of
    flags[n], deviations sd[n] (m, m/s)) into slot slots[n] of ``table`` (:meth:`_Slots.fields`),
    unless that place holds a newer tick."""
    sl_k, sl_t, sl_x, sl_v, sl_r, sl_solo, sl_sd, sl_latest, _ = table
    t, k, x, v, r, flags, sd = states
    h = sl_k.shape[1]
    for n in range(slots.shape[0]):
        i, kk = slots[n], k[n]
        j = kk % h
        if sl_k[i, j] > kk:
            continue
        sl_k[i, j] = kk
        sl_t[i, j] = t[n]
        for d in range(3):
            sl_x[i, j, d] = x[n, d]
            sl_v[i, j, d] = v[n, d]
        sl_r[i, j] = r[n]
        sl_sd[i, j, 0] = sd[n, 0]
        sl_sd[i, j, 1] = sd[n, 1]
        sl_solo[i, j] = (flags[n] & 1) == 1
        if kk > sl_latest[i]:
            sl_latest[i] = kk


@njit(cache=True)
def _newest(sl_k, i, k_max):
    """History place of slot i's newest state with tick <= k_max, or -1."""
    best, at = -1, -1
    for j in range(sl_k.shape[1]):
        kk = sl_k[i, j]
        if kk >= 0 and kk <= k_max and kk > best:
            best, at = kk, j
    return at


@njit(cache=True)
def _rows(table, slots, k_max, t_now, lost, out, kept, sd_out, age_out):
    """The rows of ``slots`` of ``table`` (:meth:`_Slots.fields`) at sim time ``t_now`` [s]
    (see NeighbourTable.arrays) into ``out`` (OBSTACLE); kept[n]: slot n made a row.
    ``lost``: the table's (timeout_s, growth_mps, hard_limit_s, drop lost ones 1.0 / keep
    them stopped 0.0, accel_bound_mps2, velocity_error_mps, sigmas). A row's velocity error is
    the larger of velocity_error_mps and sigmas x the deviation its state carries; sd_out[m] the
    position deviation [m] row m's state carries, age_out[m] its age [s] (0 for a gone or lost
    neighbour's stopped row: no longer a prediction). Returns the number of rows."""
    sl_k, sl_t, sl_x, sl_v, sl_r, sl_solo, sl_sd, _, sl_gone = table
    timeout_s, growth_mps, hard_limit_s, drop = lost[0], lost[1], lost[2], lost[3] > 0.5
    accel, vel_err0, sigmas = lost[4], lost[5], lost[6]
    m = 0
    for n in range(slots.shape[0]):
        i = slots[n]
        kept[n] = False
        j = _newest(sl_k, i, k_max)
        if j < 0:
            continue
        age = max(0.0, t_now - sl_t[i, j])
        ob = out[m]
        lost_now = sl_gone[i] or age > hard_limit_s
        if lost_now:
            if drop:
                continue
            for d in range(3):
                ob.c[d] = sl_x[i, j, d]
                ob.cd[d] = 0.0
            ob.r = sl_r[i, j]
            ob.grow = 0.0
            ob.is_nb = False
        else:
            for d in range(3):
                ob.c[d] = sl_x[i, j, d] + sl_v[i, j, d] * age
                ob.cd[d] = sl_v[i, j, d]
            vel_err = max(vel_err0, sigmas * sl_sd[i, j, 1])
            ob.grow = growth_mps * max(0.0, age - timeout_s) + (0.5 * accel * age + vel_err) * age
            ob.r = sl_r[i, j] + ob.grow
            ob.is_nb = not sl_solo[i, j]
        for d in range(3):
            ob.cdd[d] = 0.0
            ob.axis[d] = 0.0
        ob.is_agent = True
        sd_out[m] = sl_sd[i, j, 0]
        age_out[m] = 0.0 if lost_now else age
        kept[n] = True
        m += 1
    return m


_ANY_TICK = np.iinfo(np.int64).max
_VERDICTS = (
    None,
    statewire.REPEATED,
    statewire.OUT_OF_ORDER,
    statewire.AHEAD,
    statewire.OUTSIDE,
    statewire.TOO_FAST,
    statewire.TOO_LARGE,
)  # _admit's codes 1..6


@njit(cache=True)
def _admit(last_t, last_seq, slots, seq, t, x, v, r, lim, horizon_s, out):
    """out[n] for record n (sequence number seq, sim time t [s], centre x [m, world],
    velocity v [m/s], radius r [m]) from slot slots[n], whose newest state taken has time
    last_t and sequence number last_seq: 0 take it, -1 a copy of that state (a relay bundles
    a late neighbour's state again: not an offence), else the index of its reason in
    ``_VERDICTS``. ``lim``: ``Plausible.as_array``; ``horizon_s``: no state is newer. A state
    up to ``lim[8]`` [s] older than last_t is taken (into the history) without moving it."""
    for n in range(slots.shape[0]):
        i = slots[n]
        if t[n] == last_t[i]:
            out[n] = -1 if seq[n] == last_seq[i] else 1
            continue
        if t[n] < last_t[i] - lim[8]:
            out[n] = 2
            continue
        if t[n] > horizon_s:
            out[n] = 3
            continue
        v2 = 0.0
        out[n] = 0
        for d in range(3):
            if not lim[d] <= x[n, d] <= lim[3 + d]:
                out[n] = 4
            v2 += v[n, d] * v[n, d]
        if out[n] == 0 and v2 > lim[6] * lim[6]:
            out[n] = 5
        elif out[n] == 0 and r[n] > lim[7]:
            out[n] = 6
        if out[n] == 0 and t[n] > last_t[i]:
            last_t[i], last_seq[i] = t[n], seq[n]


def known_records(records: np.ndarray, known: set[str], counter: Any) -> tuple[np.ndarray, list[str]]:
    """The :data:`swarm.net.statewire.STATE` records of ``records`` whose sender is one of
    ``known``, and their senders; any other is dropped and counted on ``counter``
    (:class:`swarm.net.transport.Counter`)."""
    names, keep = [], []
    for n, src in enumerate(records["src"].tolist()):
        name = src.decode()
        if name in known:
            names.append(name)
            keep.append(n)
        else:
            counter.drop("state: from an agent it does not know, or itself")
    return (records if len(keep) == len(records) else records[keep]), names


class HeldRecord(NamedTuple):
    """A neighbour's state record held until its fate's tick (:meth:`HeardNeighbours.take_records`)."""

    name: str
    record: bytes  # as its sender published it


class NeighbourTable:
    """Latest states per neighbour, with a short history by tick so that lockstep runs
    can use exactly the state of tick k-1 whatever else has arrived meanwhile. Held in
    arrays that compiled kernels write (:meth:`update_records`: all of a bundle at once)
    and read (:meth:`arrays`)."""

    HISTORY = 8  # ticks of history kept per neighbour

    def __init__(
        self,
        timeout_s: float,
        growth_mps: float,
        hard_limit_s: float,
        on_lost: str = "keep_stopped",
        accel_bound_mps2: float = 0.0,
        velocity_error_mps: float = 0.0,
        sigmas: float = 0.0,
    ) -> None:
        """``accel_bound_mps2``, ``velocity_error_mps``: a row's radius also grows by
        ``(a / 2 age + e) age`` with its state's age [s], what extrapolating it at constant
        velocity can miss when the neighbour accelerates at up to ``a`` and its velocity is off by
        up to ``e`` (``world.realism``: ``swarm.tuning.prediction_bounds``; 0: not at all), or by
        ``sigmas`` times the velocity deviation its state carries where that is larger."""
        self.timeout_s, self.growth_mps, self.hard_limit_s, self.on_lost = timeout_s, growth_mps, hard_limit_s, on_lost
        self.accel_bound_mps2, self.velocity_error_mps, self.sigmas = accel_bound_mps2, velocity_error_mps, sigmas
        self._lost = np.array(
            [
                timeout_s,
                growth_mps,
                hard_limit_s,
                1.0 if on_lost == "drop" else 0.0,
                accel_bound_mps2,
                velocity_error_mps,
                sigmas,
            ]
        )
        self.slot: dict[str, int] = {}  # name -> slot, in the order first heard
        self.names: list[str] = []  # slot -> name
        self.s = _Slots.empty(0, self.HISTORY)
        self.gone: set[str] = set()
        self.row_names: list[str] = []  # names of the rows the last arrays() built
        self.row_sd_m = np.zeros(0)  # (rows,) m: the position deviation each of those rows' states carries
        self.row_age_s = np.zeros(0)  # (rows,) s: their states' ages
        self._limits: statewire.Plausible | None = None
        self.now_s = -np.inf  # sim time [s] of the newest tick this agent has heard of (at(), arrays())
        self.last_t = np.zeros(0)  # (S,) sim time [s] of each slot's newest state taken (-inf: none)
        self.last_seq = np.zeros(0, dtype=np.uint64)  # (S,) and its sequence number
        self.rejected: dict[str, dict[str, int]] = {}  # sender -> reason -> states dropped

    def blank(self) -> NeighbourTable:
        """An empty table of the same settings and limits."""
        t = NeighbourTable(self.timeout_s, self.growth_mps, self.hard_limit_s, self.on_lost,
                           self.accel_bound_mps2, self.velocity_error_mps, self.sigmas)  # fmt: skip
        t.limits = self.limits
        return t

    @property
    def limits(self) -> statewire.Plausible | None:
        """What a neighbour's state may say (None: anything well-formed). Setting it loads
        the compiled check now, not on the first bundle of the flight."""
        return self._limits

    @limits.setter
    def limits(self, limits: statewire.Plausible | None) -> None:
        self._limits = limits
        if limits is not None:
            # two records (the fields of one are contiguous arrays, a type of their own to numba),
            # read-only as a bundle's records are
            rec = np.frombuffer(np.zeros(2, dtype=statewire.STATE).tobytes(), dtype=statewire.STATE)
            fields = (rec["seq"], rec["t"], rec["x"], rec["v"], rec["r"])
            scratch = (np.full(2, 1.0), np.zeros(2, np.uint64), np.zeros(2, np.int64))
            _admit(*scratch, *fields, limits.as_array(), 0.0, np.empty(2, np.int8))

    def at(self, t_s: float) -> None:
        """This agent has heard of sim time ``t_s`` [s] (a measurement, its tick): no
        neighbour's state is more than ``limits.ahead_s`` newer."""
        self.now_s = max(self.now_s, t_s)

    @property
    def history(self) -> list[str]:
        """The neighbours held now (some state of them), in the order first heard."""
        return [n for n, i in self.slot.items() if self.s.latest[i] >= 0]

    def _slot(self, name: str) -> int:
        i = self.slot.get(name)
        if i is None:
            if len(self.names) == self.s.k.shape[0]:
                self.s = self.s.grown(max(4, len(self.names)))
                more = max(4, len(self.names))
                self.last_t = np.concatenate([self.last_t, np.full(more, -np.inf)])
                self.last_seq = np.concatenate([self.last_seq, np.zeros(more, np.uint64)])
            i = self.slot[name] = len(self.names)
            self.names.append(name)
        return i

    def update(
        self,
        name: str,
        t_s: float,
        k: int,
        x_w: FloatArray,
        v_w: FloatArray,
        radius_m: float,
        solo: bool = False,
        seq: int | None = None,
        sd: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        """``name``'s state of tick ``k`` at ``t_s`` [s] (body centre ``x_w`` [m, world], its
        velocity ``v_w`` [m/s], radius [m]; ``seq``: its sequence number, which tells a copy of
        the newest state taken, as a relay bundles a late neighbour's state again, from a repeat;
        ``sd``: its estimate's position [m] and velocity [m/s] deviations)."""
        if name in self.gone:
            return
        i = self._slot(name)
        s, j = self.s, k % self.HISTORY
        if self.limits is not None:
            if t_s == self.last_t[i] and seq is not None and seq == self.last_seq[i]:
                return  # (the same state again: no offence)
            why = self._why(i, t_s, x_w, v_w, radius_m)
            if why is not None:
                self._reject(name, why)
                return
            if seq is not None and t_s == self.last_t[i]:
                self.last_seq[i] = seq
        if s.k[i, j] > k:
            return
        s.k[i, j], s.t[i, j], s.x[i, j], s.v[i, j], s.r[i, j], s.solo[i, j] = k, t_s, x_w, v_w, radius_m, solo
        s.sd[i, j] = sd
        s.latest[i] = max(s.latest[i], k)

    def update_records(self, records: np.ndarray, known: set[str], counter: Any) -> None:
        """Every checked :data:`swarm.net.statewire.STATE` record of ``records`` whose sender is
        one of ``known`` (and, with :attr:`limits`, that it may take: the module docstring);
        any other is dropped and counted on ``counter`` (:class:`swarm.net.transport.Counter`).
        Compiled calls check and write them all."""
        rec, names = known_records(records, known, counter)
        if names:
            for reason in self.store_records(rec, names):
                counter.drop(reason)

    def store_records(self, records: np.ndarray, names: list[str]) -> list[str]:
        """The checked :data:`swarm.net.statewire.STATE` records ``records`` of the neighbours
        ``names`` (one per record) into the table, each that :attr:`limits` allows (the module
        docstring; a gone neighbour's skipped); the reasons of the others, each noted in
        :attr:`rejected`. Compiled calls check and write them all."""
        slots, keep = [], []
        for n, name in enumerate(names):
            if name not in self.gone:
                slots.append(self._slot(name))
                keep.append(n)
        if not slots:
            return []
        rec = records if len(keep) == len(records) else records[keep]
        sl = np.array(slots, dtype=np.int64)
        dropped: list[str] = []
        if self.limits is not None:
            verdict = np.empty(len(sl), dtype=np.int8)
            fields = (rec["seq"], rec["t"], rec["x"], rec["v"], rec["r"])
            _admit(self.last_t, self.last_seq, sl, *fields, self.limits.as_array(), self._horizon_s(), verdict)
            if verdict.any():
                for n in np.flatnonzero(verdict > 0).tolist():
                    reason = _VERDICTS[verdict[n]]
                    assert reason is not None
                    dropped.append(reason)
                    self._reject(self.names[sl[n]], reason)
                ok = verdict == 0
                rec, sl = rec[ok], sl[ok]
        states = (rec["t"], rec["k"], rec["x"], rec["v"], rec["r"], rec["flags"], rec["sd"])
        _store(self.s.fields(), sl, states)
        return dropped

    def _horizon_s(self) -> float:
        """No neighbour's state is newer [s, sim time] (none known before the first tick heard of)."""
        assert self.limits is not None
        return self.now_s + self.limits.ahead_s if math.isfinite(self.now_s) else math.inf

    def _why(self, i: int, t_s: float, x_w: Any, v_w: Any, radius_m: float) -> str | None:
        """Why a state of slot ``i`` is not taken (:attr:`limits` set), or None; taken: noted."""
        assert self.limits is not None
        if t_s == self.last_t[i]:
            return statewire.REPEATED
        if t_s < self.last_t[i] - self.limits.behind_s:
            return statewire.OUT_OF_ORDER
        if t_s > self._horizon_s():
            return statewire.AHEAD
        why = self.limits.reason(tuple(x_w), tuple(v_w), radius_m)
        if why is None:
            self.last_t[i] = max(self.last_t[i], t_s)
        return why

    def _reject(self, name: str, reason: str) -> None:
        per = self.rejected.setdefault(name, {})
        per[reason] = per.get(reason, 0) + 1

    def mark_gone(self, name: str) -> None:
        self.gone.add(name)
        i = self.slot.get(name)
        if i is not None:
            self.s.gone[i] = True

    def latest_k(self, name: str) -> int:
        i = self.slot.get(name)
        return -1 if i is None else int(self.s.latest[i])

    def state(self, name: str, k_max: int | None = None) -> Neighbour | None:
        """Newest state of ``name`` with tick <= ``k_max`` (any tick when None)."""
        i = self.slot.get(name)
        if i is None:
            return None
        s = self.s
        j = _newest(s.k, i, _ANY_TICK if k_max is None else k_max)
        if j < 0:
            return None
        return Neighbour(float(s.t[i, j]), int(s.k[i, j]), s.x[i, j].copy(), s.v[i, j].copy(), float(s.r[i, j]),
                         bool(s.solo[i, j]))  # fmt: skip

    def forget_far(self, x_w: FloatArray, radius_m: float, t_now_s: float) -> None:
        """Forget the neighbours (not gone) last heard farther than ``radius_m`` [m] from
        ``x_w`` [m, world] and more than the timeout ago: they left the cells this agent
        listens to (``neighbours.interest: cells``), they are not lost."""
        s = self.s
        held = (s.latest >= 0) & ~s.gone
        if not held.any():
            return
        j = s.latest % self.HISTORY
        rows = np.arange(len(j))
        far = ((s.x[rows, j] - np.asarray(x_w)) ** 2).sum(axis=1) > radius_m * radius_m
        old = t_now_s - s.t[rows, j] > self.timeout_s
        for i in np.flatnonzero(held & far & old).tolist():
            s.k[i] = -1
            s.latest[i] = -1

    def arrays(self, t_now: float, k_max: int | None = None, names: list[str] | None = None) -> ObstacleArrays:
        """Neighbour rows at ``t_now`` [s], from states of tick <= ``k_max``; their
        names are left in :attr:`row_names`. A neighbour that is gone, past the hard limit
        or ``solo`` is an obstacle row (``is_neighbour`` false): it is not doing its share,
        so this agent takes all of the pair. ``names``: only these neighbours (in this
        order), and the gone ones."""
        self.now_s = max(self.now_s, t_now)
        if names is None:
            slots = list(range(len(self.names)))
        else:
            slots = list(dict.fromkeys([self.slot[n] for n in names if n in self.slot]))
            slots += [self.slot[n] for n in self.gone if n in self.slot and self.slot[n] not in slots]
        if not slots:
            self.row_names, self.row_sd_m, self.row_age_s = [], np.zeros(0), np.zeros(0)
            return ObstacleArrays.empty()
        sel = np.array(slots, dtype=np.int64)
        out = np.empty(len(slots), dtype=OBSTACLE)
        kept = np.empty(len(slots), dtype=np.bool_)
        k = _ANY_TICK if k_max is None else k_max
        sd, age = np.empty(len(slots)), np.empty(len(slots))
        m = _rows(self.s.fields(), sel, k, t_now, self._lost, out, kept, sd, age)
        self.row_names = [self.names[i] for i, ok in zip(slots, kept.tolist(), strict=True) if ok]
        self.row_sd_m, self.row_age_s = sd[:m], age[:m]
        if m == 0:
            return ObstacleArrays.empty()
        return ObstacleArrays.of_records(out[:m])


HELD_TICKS = 5
"""Ticks of the world's lists an agent keeps: lockstep acts on tick k while later ones may have
arrived."""


class HeardNeighbours:
    """The other agents as an agent hears them: their states (:meth:`take`) in a
    :class:`NeighbourTable`, and per tick the world's list of the agents that tick waits for
    (:meth:`on_list`). In lockstep tick k uses exactly their states of tick k-1. Pure: the
    neighbour sources (``swarm.net.sources``) feed it from the wire, ``fly_scenario`` directly.

    With a ``comms`` model (``world.realism.comms``) a state of tick k reaches the table at tick
    ``k + max(1, d)`` for its seeded fate ``d`` from its sender to ``agent_id`` (through the relay
    with ``bundled``: the state's and the bundle's delays added), or never; lockstep still waits
    for it to arrive on the wire (:attr:`heard`), then holds it until then.

    In lockstep a neighbour this agent went without at a tick's deadline (:meth:`late`) is not
    waited for again until a newer state of it is received: a neighbour gone silent, or whose
    every state the table drops (``NeighbourTable.limits``), costs one timeout, not one per tick."""

    def __init__(
        self, others: set[str], table: NeighbourTable, agent_id: str = "", comms: CommsModel | None = None
    ) -> None:
        self.others, self.table = others, table
        self.lists: dict[int, list[str]] = {}  # tick -> the agents tick k waits for (the world's list)
        self.missed = 0  # listed neighbours whose state was not there when used
        self.id, self.comms = agent_id, comms
        # a state held until its tick: as fields (take), or as its record (take_records)
        self.line: DelayLine[
            tuple[str, float, int, FloatArray, FloatArray, float, bool, int | None, tuple[float, float]] | HeldRecord
        ]
        self.line = DelayLine()
        self.heard: dict[str, int] = {}  # comms: neighbour -> the newest tick of its states on the wire
        self.states_lost = 0  # comms: states that never reach this agent
        self.delay_ticks = 0  # comms: ticks of delay beyond the next tick, summed over the states delivered
        self.behind: dict[str, int] = {}  # lockstep: neighbour -> its newest tick heard at a deadline without it

    def take(
        self,
        name: str,
        t_s: float,
        k: int,
        x_w: FloatArray,
        v_w: FloatArray,
        radius_m: float,
        solo: bool,
        bundled: bool = False,
        seq: int | None = None,
        sd: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        """A neighbour's state of tick ``k`` at ``t_s`` [s]: body centre ``x_w`` [m, world], its
        velocity ``v_w`` [m/s, world], radius [m], whether it is not doing its share; ``bundled``:
        it came in the relay's bundle; ``seq``: its sequence number (``NeighbourTable.update``);
        ``sd``: its estimate's position [m] and velocity [m/s] deviations."""
        comms = self.comms
        if comms is None:
            self.table.update(name, t_s, k, x_w, v_w, radius_m, solo, seq, sd)
            return
        self.heard[name] = max(self.heard.get(name, -1), k)
        d = comms.fate(name, self.id, MessageKind.STATE, k)
        if bundled and d != LOST:
            d_bundle = comms.fate("router", self.id, MessageKind.BUNDLE, k)
            d = LOST if d_bundle == LOST else d + d_bundle
        if d == LOST:
            self.states_lost += 1
            return
        self.delay_ticks += max(0, d - 1)
        self.line.put(k, max(1, d), (name, t_s, k, x_w, v_w, radius_m, solo, seq, sd))

    def take_records(self, records: np.ndarray, names: list[str], bundled: bool = False) -> None:
        """With a ``comms`` model: checked :data:`swarm.net.statewire.STATE` records, of the
        neighbours ``names`` (one per record, each known, in the order they came), as
        :meth:`take` takes each, their fates in one compiled pass."""
        comms = self.comms
        assert comms is not None, "take_records holds states for their fates: comms only"
        ks = records["k"]
        d = comms.fates(names, self.id, MessageKind.STATE, ks)
        if bundled:
            d_bundle = comms.fates(["router"] * len(names), self.id, MessageKind.BUNDLE, ks)
            d = np.where((d == LOST) | (d_bundle == LOST), LOST, d + d_bundle)
        heard, line = self.heard, self.line
        for i, (name, k, fate) in enumerate(zip(names, ks.tolist(), d.tolist(), strict=True)):
            heard[name] = max(heard.get(name, -1), k)
            if fate == LOST:
                self.states_lost += 1
                continue
            self.delay_ticks += max(0, fate - 1)
            line.put(k, max(1, fate), HeldRecord(name, records[i : i + 1].tobytes()))

    def _deliver(self, k: int) -> None:
        """The held states due by tick ``k`` into the table (comms), in order: fields one by
        one, runs of records in one compiled call."""
        if self.comms is None:
            return
        table, run = self.table, []
        for item in self.line.due(k):
            if isinstance(item, HeldRecord):
                run.append(item)
                continue
            self.deliver(run)
            run = []
            table.update(*item)
        self.deliver(run)

    def deliver(self, held: list[HeldRecord]) -> None:
        """Held state records, delivered now, into the table."""
        if held:
            rec = np.frombuffer(b"".join(h.record for h in held), dtype=statewire.STATE)
            self.table.store_records(rec, [h.name for h in held])

    def _latest_k(self, name: str) -> int:
        """The newest tick of ``name``'s states this agent has received (on the wire)."""
        return self.heard.get(name, -1) if self.comms is not None else self.table.latest_k(name)

    def on_list(self, k: int, names: list[str]) -> None:
        """The world's list of the agents tick ``k`` waits for."""
        self.lists[k] = names
        while len(self.lists) > HELD_TICKS:
            del self.lists[next(iter(self.lists))]

    def lost(self, name: str) -> None:
        """``name`` is gone: kept as a stopped obstacle or dropped (the table's ``on_lost``)."""
        self.table.mark_gone(name)

    def missing(self, k: int) -> int:
        """Lockstep: 1 without the world's list of tick k, else how many of the listed (live)
        agents have no state of tick k-1 yet. 0 for a tick older than every list held: the
        world has flown :data:`HELD_TICKS` ticks on without this agent (it went without its
        command at the timeout), which then acts on what it has rather than wait for each
        tick of its backlog in turn (the neighbours it still lacks are then passed over as at
        a deadline, :meth:`late`)."""
        names = self.lists.get(k)
        if names is None:
            if not self.lists or k >= min(self.lists):
                return 1
            self._pass_over(sorted(self.others), k)  # (as at a deadline: see late)
            return 0
        if k == 0:
            return 0  # no state before the first tick
        return len(self._missing(names, k))

    def _missing(self, names: list[str], k: int) -> list[str]:
        """Of the listed ``names``, the live neighbours without a state of tick k-1 yet that are
        still waited for (not :attr:`behind` since a deadline without a newer state)."""
        gone, behind = self.table.gone, self.behind
        out = []
        for n in names:
            if n in self.others and n not in gone:
                latest = self._latest_k(n)
                if latest < k - 1 and behind.get(n) != latest:
                    out.append(n)
        return out

    def late(self, k: int) -> None:
        """Lockstep: tick k is acted on at the deadline, incomplete: the neighbours it still
        waited for are :attr:`behind` until a newer state of theirs is received."""
        if k > 0 and k in self.lists:
            self._pass_over(self.lists[k], k)

    def _pass_over(self, names: list[str], k: int) -> None:
        """Of ``names``, those still waited for at tick ``k`` are :attr:`behind`."""
        for n in self._missing(names, k):
            self.behind[n] = self._latest_k(n)

    def warm_up(self) -> None:
        """Take two neighbours' states of three ticks (through this agent's comms model, if any)
        into a throwaway table and build their rows every way a tick does (by tick and names,
        the newest, a state by name, the far ones forgotten): the compiled kernels this calls
        load now, not at the first neighbour heard, where on a cold cache numba compiles them
        for seconds while a real drone flies on its last command."""
        names, z = ["warm-up-1", "warm-up-2"], np.zeros(3)
        heard = HeardNeighbours(set(names), self.table.blank(), self.id, self.comms)
        for k in range(3):
            for n in names:
                heard.take(n, 0.01 * k, k, z, z, 0.05, False)
            heard.rows(0.01 * k, k, z, lockstep=True)
        table = heard.table
        table.arrays(0.02, 1, names)
        table.arrays(0.02)
        table.state(names[0])
        table.forget_far(z, 1.0, 0.02)

    def at(self, t_s: float) -> None:
        """This agent has heard of sim time ``t_s`` [s] (a measurement): no neighbour's state is
        much newer (``NeighbourTable.at``)."""
        self.table.at(t_s)

    @property
    def rejected(self) -> dict[str, dict[str, int]]:
        """The neighbours' states the table dropped, per sender and reason."""
        return self.table.rejected

    def rows(self, t_s: float, k: int, x_b_w: FloatArray, lockstep: bool) -> NamedObstacles:
        """Every heard neighbour's row at ``t_s`` [s] (lockstep: from its state of tick k-1)."""
        self._deliver(k)
        table = self.table
        arr = table.arrays(t_s, k - 1 if lockstep else None)
        return NamedObstacles(arr, table.row_names[: len(arr)], table.row_sd_m, table.row_age_s)


class NearNeighbours(HeardNeighbours):
    """:class:`HeardNeighbours` of which the world names, with each agent's tick, the live ones
    near it (within its sensing radius and half the margin): lockstep uses exactly their states
    of tick k-1. In realtime the neighbours last heard beyond ``forget_m`` [m] and silent past the
    timeout are forgotten (they left), and a near one not heard within the timeout is counted
    missed."""

    def __init__(
        self,
        others: set[str],
        table: NeighbourTable,
        forget_m: float,
        agent_id: str = "",
        comms: CommsModel | None = None,
    ) -> None:
        super().__init__(others, table, agent_id, comms)
        self.forget_m = forget_m

    def late(self, k: int) -> None:
        if k in self.lists:
            self.missed += self.missing(k)
        super().late(k)

    def rows(self, t_s: float, k: int, x_b_w: FloatArray, lockstep: bool) -> NamedObstacles:
        table = self.table
        near = self.lists.get(k, [])
        self._deliver(k)
        if lockstep:
            arr = table.arrays(t_s, k - 1, sorted(near))
        else:
            table.forget_far(x_b_w, self.forget_m, t_s)
            if t_s > table.timeout_s:  # (before that, no neighbour can have been heard for long)
                timeout_s = table.timeout_s
                self.missed += sum(1 for n in near if (s := table.state(n)) is None or t_s - s.t_s > timeout_s)
            arr = table.arrays(t_s)
        return NamedObstacles(arr, table.row_names[: len(arr)], table.row_sd_m, table.row_age_s)
