"""Communication: the delay and loss of each message between processes, seeded.

A message's fate is a pure function of ``(seed, sender, receiver, kind, tick)``: lost, or
delivered ``d >= 0`` ticks after the tick it was sent in (used at the first tick at or
after its arrival: ``d = ceil((delay + jitter u) / tick)``, ``u`` uniform in [0, 1)).
Derived with a counter-based hash (:mod:`swarm.realism.rng`), never a shared random
stream, so a lockstep run repeats bit for bit however its processes are scheduled, and
each process can compute the fates of its own messages alone.

Kinds: an agent's ``state`` to another agent, the relay's ``bundle`` to an agent, an
agent's ``command`` to its drone (through the world). For a message to many (a state
published to every neighbour), each receiver has its own fate.

Burst loss (off by default, :class:`LinkParams`): a link may lose in bursts, a
Gilbert-Elliott chain (Gilbert 1960, Elliott 1963) of two states stepped once per tick (a
link carries one message a tick): good, losing ``loss_fraction``, and bad, losing
``burst_loss_fraction``; from good to bad with ``burst_enter_probability`` ``p`` a tick,
back with ``burst_exit_probability`` ``r`` (a bad spell lasts ``1 / r`` ticks on average). The
mean loss is ``(r loss + p burst_loss) / (p + r)``. The chain is a pure function of (seed,
sender, receiver, kind, tick) as every fate is: its transitions are hashed draws
(:attr:`Stream.COMMS_BURST`), and it restarts from its stationary law every
:data:`BURST_BLOCK_TICKS` ticks (34 s at 120 Hz), so a tick's state is found from the last
restart (a model keeps each link's last state to step on from; the result does not depend
on it). The loss draw within a state is the link's own (:attr:`Stream.COMMS`), so the delays
do not move. Leaves out: bursts shared by the drones of one radio (each link its own chain).

A shared radio (off by default, :class:`RadioParams`): ``drones_per_radio`` drones on one
Crazyradio lengthen the command link's delay by ``s (n - 1) f / 100 Hz`` (``n`` drones, ``f``
their command rate, the control rate unless set) and add a loss ``l (n - 1) f / 100 Hz``. The
slope ``s`` is fitted to the median latencies of Crazyswarm2's JOSS paper draft
(IMRCLab/crazyswarm2 ``docs2/paper/paper.md`` at 283675e; its text gives the method, an echo
service's round trip while motion capture goes to every drone at 100 Hz, and its figure
``latency.png`` the values, as issue 64 reports them): about 3 ms for 1 drone and 27 ms for 8
with the C++ backend (broadcasts), about 52 ms for 8 with cflib (unicasts), so ``s`` = 24/7
= 3.4 ms (cpp) and 49/7 = 7.0 ms (cflib, taking its one drone at
3 ms too: the figure's one-drone cflib value was not read). The link's own ``delay_s``
stands for the one-drone latency (the lab preset's 10 ms is Crazyswarm2's warning limit, so a
lab at 8 drones on cpp sits at 34 ms). Assumed: latency beyond one drone is queueing behind
the others' packets, so it grows with the offered load ``n f`` (linear in ``f`` through the
100 Hz point; the paper measured one rate). ``l`` has no published source (default 0).
Fitted range: 1 to 8 drones a radio at 100 Hz; Bitcraze reports Crazyswarm's driver with 15
a radio and cflib's trouble past 4 (crazyflie-firmware issue 434).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from enum import IntEnum
from typing import Generic, TypeVar

import numpy as np
from numba import njit

from swarm.realism.rng import Stream, hash5, name_word, uniform, word
from swarm.rotation import IntArray

LOST = -1
"""The fate of a message that never arrives."""


class MessageKind(IntEnum):
    STATE = 1
    BUNDLE = 2
    COMMAND = 3


BURST_BLOCK_TICKS = 4096
"""A burst chain restarts from its stationary law at every multiple of this many ticks."""

RADIO_REFERENCE_HZ = 100.0
"""The rate Crazyswarm2's latencies were measured at (motion capture to every drone)."""
RADIO_SLOPE_S = {"cpp": (0.027 - 0.003) / 7.0, "cflib": (0.052 - 0.003) / 7.0}
"""The median latency each further drone on a radio adds at 100 Hz [s] (module docstring)."""


@dataclass(frozen=True)
class LinkParams:
    delay_s: float = 0.0
    jitter_s: float = 0.0
    """A message's delay is ``delay_s`` plus up to this, uniformly [s]."""
    loss_fraction: float = 0.0
    """The loss (in the chain's good state, when bursts are on)."""
    burst_enter_probability: float = 0.0
    """Gilbert-Elliott: the chance a tick of going from good to bad; 0: no bursts."""
    burst_exit_probability: float = 0.2
    """The chance a tick of going from bad back to good (a bad spell: 1 / this ticks)."""
    burst_loss_fraction: float = 0.0
    """The loss in the bad state."""

    @property
    def bursts(self) -> bool:
        return self.burst_enter_probability > 0.0 and self.burst_loss_fraction != self.loss_fraction

    @property
    def bad_fraction(self) -> float:
        """The chain's stationary chance of the bad state (0 without bursts)."""
        if not self.bursts:
            return 0.0
        return self.burst_enter_probability / (self.burst_enter_probability + self.burst_exit_probability)

    @property
    def mean_loss(self) -> float:
        b = self.bad_fraction
        return (1.0 - b) * self.loss_fraction + b * self.burst_loss_fraction

    @property
    def perfect(self) -> bool:
        return self.delay_s == 0.0 and self.jitter_s == 0.0 and self.mean_loss == 0.0


@dataclass(frozen=True)
class RadioParams:
    drones_per_radio: int = 1
    backend: str = "cpp"
    """``cpp`` (Crazyswarm2's C++ backend) or ``cflib``."""
    command_rate_hz: float | None = None
    """Each drone's command rate [Hz]; None: the control rate."""
    loss_per_extra_drone: float = 0.0
    """The loss each further drone adds at 100 Hz (assumed; no published source)."""

    @property
    def shared(self) -> bool:
        return self.drones_per_radio > 1

    def extra_delay_s(self, rate_hz: float) -> float:
        """The median latency the other drones add [s] at a command rate ``rate_hz``."""
        load = (self.drones_per_radio - 1) * rate_hz / RADIO_REFERENCE_HZ
        return RADIO_SLOPE_S[self.backend] * load

    def extra_loss(self, rate_hz: float) -> float:
        load = (self.drones_per_radio - 1) * rate_hz / RADIO_REFERENCE_HZ
        return min(self.loss_per_extra_drone * load, 0.99)

    def command_link(self, link: LinkParams, tick_s: float) -> LinkParams:
        """The command link ``link`` (its one-drone values) with this radio's drones on it."""
        if not self.shared:
            return link
        rate_hz = self.command_rate_hz if self.command_rate_hz is not None else 1.0 / tick_s
        extra = self.extra_loss(rate_hz)

        def lose(loss: float) -> float:
            return min(1.0 - (1.0 - loss) * (1.0 - extra), 0.99)

        return replace(
            link,
            delay_s=link.delay_s + self.extra_delay_s(rate_hz),
            loss_fraction=lose(link.loss_fraction),
            burst_loss_fraction=lose(link.burst_loss_fraction) if link.bursts else link.burst_loss_fraction,
        )


@dataclass(frozen=True)
class CommsParams:
    state: LinkParams = LinkParams()
    bundle: LinkParams = LinkParams()
    command: LinkParams = LinkParams()
    shared_radio: RadioParams = RadioParams()

    def link(self, kind: MessageKind) -> LinkParams:
        """The link of ``kind`` as set (the command link without the radio's drones:
        :meth:`CommsModel.link` has them)."""
        return (self.state, self.bundle, self.command)[int(kind) - 1]

    @property
    def perfect(self) -> bool:
        return self.state.perfect and self.bundle.perfect and self.command.perfect and not self.shared_radio.shared


_TWO53_INV = 1.0 / 9007199254740992.0


@njit(cache=True)
def _fate(seed, stream, pair, kind_tick, delay_s, jitter_s, loss, tick_s):
    h = hash5(seed, stream, pair, kind_tick, np.uint64(0))
    u_loss = (float(h >> np.uint64(11)) + 1.0) * _TWO53_INV  # (0, 1]
    if u_loss <= loss:
        return -1
    u_jit = float(hash5(seed, stream, pair, kind_tick, np.uint64(1)) >> np.uint64(11)) * _TWO53_INV  # [0, 1)
    d = (delay_s + jitter_s * u_jit) / tick_s
    return max(0, math.ceil(d - 1e-9))


@njit(cache=True)
def _burst_bad(seed, stream, pair, kind_word, tick, p_enter, p_exit, block, from_tick, from_bad):
    """Whether the link's Gilbert-Elliott chain is in its bad state at ``tick``: stepped on
    from ``(from_tick, from_bad)`` if that is in the same block and not later, else from the
    block's start, drawn from the stationary law."""
    start = (tick // block) * block
    if from_tick < start or from_tick > tick:
        u0 = uniform(seed, stream, pair, kind_word ^ np.uint64(start), np.uint64(1))
        bad = u0 <= p_enter / (p_enter + p_exit)
        t = start
    else:
        bad = from_bad
        t = from_tick
    while t < tick:
        t += 1
        u = uniform(seed, stream, pair, kind_word ^ np.uint64(t), np.uint64(0))
        if bad:
            bad = not (u <= p_exit)
        else:
            bad = u <= p_enter
    return bad


@njit(cache=True)
def _fate_matrix(seed, stream, words, kind_tick, delay_s, jitter_s, loss, tick_s, out):
    n = words.shape[0]
    for i in range(n):
        for j in range(n):
            if i != j:
                pair = words[i] * np.uint64(0x9E3779B1) ^ words[j]
                out[i, j] = _fate(seed, stream, pair, kind_tick, delay_s, jitter_s, loss, tick_s)
            else:
                out[i, j] = 0


@njit(cache=True)
def _fates(seed, stream, words, receiver, kind, ticks, delay_s, jitter_s, loss, tick_s, out):
    for i in range(words.shape[0]):
        pair = words[i] * np.uint64(0x9E3779B1) ^ receiver
        kind_tick = (kind << np.uint64(56)) ^ np.uint64(ticks[i])
        out[i] = _fate(seed, stream, pair, kind_tick, delay_s, jitter_s, loss, tick_s)


class CommsModel:
    """The fates of a run's messages; ``tick_s`` is the control period [s]."""

    def __init__(self, p: CommsParams, seed: int, tick_s: float) -> None:
        self.p = p
        self.seed = word(seed)
        self.tick_s = tick_s
        self._names: dict[str, int] = {}
        self._links = (p.state, p.bundle, p.shared_radio.command_link(p.command, tick_s))
        self._burst_last: dict[tuple[int, int], tuple[int, bool]] = {}

    def link(self, kind: MessageKind) -> LinkParams:
        """The link of ``kind`` as the model draws it (the command link with the radio's drones)."""
        return self._links[int(kind) - 1]

    def burst_bad(self, sender: str, receiver: str, kind: MessageKind, tick: int) -> bool:
        """Whether the link from ``sender`` to ``receiver`` of ``kind`` is in its bad state at
        ``tick`` (False without bursts)."""
        link = self.link(kind)
        if not link.bursts:
            return False
        pair = int(word(self._word(sender) * 0x9E3779B1 ^ self._word(receiver)))
        return self._bad(pair, kind, tick, link)

    def _bad(self, pair: int, kind: MessageKind, tick: int, link: LinkParams) -> bool:
        key = (pair, int(kind))
        from_tick, from_bad = self._burst_last.get(key, (-1, False))
        bad = bool(
            _burst_bad(
                self.seed,
                _COMMS_BURST,
                np.uint64(pair),
                np.uint64(int(kind) << 56),
                tick,
                link.burst_enter_probability,
                link.burst_exit_probability,
                BURST_BLOCK_TICKS,
                from_tick,
                from_bad,
            )
        )
        self._burst_last[key] = (tick, bad)
        return bad

    def _word(self, name: str) -> int:
        w = self._names.get(name)
        if w is None:
            w = self._names[name] = name_word(name)
        return w

    def fate(self, sender: str, receiver: str, kind: MessageKind, tick: int) -> int:
        """Ticks after ``tick`` at which the message of ``kind`` that ``sender`` sent to
        ``receiver`` (agent ids; ``"world"`` for commands) at ``tick`` is delivered, or
        :data:`LOST`."""
        link = self.link(kind)
        if link.perfect:
            return 0
        pair = word(self._word(sender) * 0x9E3779B1 ^ self._word(receiver))
        delay_s, jitter_s, loss, tick_s = self._link(link)
        if link.bursts and self._bad(int(pair), kind, tick, link):
            loss = link.burst_loss_fraction
        return int(_fate(self.seed, _COMMS, pair, _kind_tick(kind, tick), delay_s, jitter_s, loss, tick_s))

    def fates(self, senders: Sequence[str], receiver: str, kind: MessageKind, ticks: IntArray) -> IntArray:
        """(n,): entry i is :meth:`fate` of ``senders[i]``'s message to ``receiver`` sent at
        ``ticks[i]`` (>= 0); one compiled pass, for a receiver that takes many at once (a bundle)."""
        out = np.zeros(len(senders), dtype=np.intp)
        link = self.link(kind)
        if link.perfect or not len(senders):
            return out
        if link.bursts:  # each link's chain: one at a time
            out[:] = [self.fate(s, receiver, kind, int(k)) for s, k in zip(senders, ticks, strict=True)]
            return out
        words = np.array([self._word(s) for s in senders], dtype=np.uint64)
        ks = np.ascontiguousarray(ticks, dtype=np.int64)
        receiver_word = np.uint64(self._word(receiver))
        _fates(self.seed, _COMMS, words, receiver_word, np.uint64(int(kind)), ks, *self._link(link), out)
        return out

    def fate_matrix(self, ids: Sequence[str], kind: MessageKind, tick: int) -> IntArray:
        """(n, n): entry (i, j) is :meth:`fate` of ``ids[i]``'s message to ``ids[j]`` (0 on
        the diagonal); one compiled pass, for a simulator that routes every pair's messages."""
        n = len(ids)
        out = np.zeros((n, n), dtype=np.intp)
        link = self.link(kind)
        if link.perfect:
            return out
        if link.bursts:  # each link's chain: one at a time
            for i, a in enumerate(ids):
                for j, b in enumerate(ids):
                    if i != j:
                        out[i, j] = self.fate(a, b, kind, tick)
            return out
        words = np.array([self._word(i) for i in ids], dtype=np.uint64)
        _fate_matrix(self.seed, _COMMS, words, _kind_tick(kind, tick), *self._link(link), out)
        return out

    def _link(self, link: LinkParams) -> tuple[float, float, float, float]:
        return link.delay_s, link.jitter_s, link.loss_fraction, self.tick_s


_COMMS = np.uint64(int(Stream.COMMS))
_COMMS_BURST = np.uint64(int(Stream.COMMS_BURST))


def _kind_tick(kind: MessageKind, tick: int) -> np.uint64:
    return word((int(kind) << 56) ^ tick)


T = TypeVar("T")


class DelayLine(Generic[T]):
    """Messages held until their tick: :meth:`put` with the fate, :meth:`due` each tick."""

    def __init__(self) -> None:
        self._heap: list[tuple[int, int, T]] = []
        self._n = 0

    def put(self, tick: int, fate: int, item: T) -> bool:
        """Hold ``item`` sent at ``tick`` with ``fate`` (from :meth:`CommsModel.fate`);
        False if it is lost."""
        if fate == LOST:
            return False
        heapq.heappush(self._heap, (tick + fate, self._n, item))
        self._n += 1
        return True

    def due(self, tick: int) -> list[T]:
        """The items delivered by ``tick``, in order of delivery, then of sending."""
        out = []
        while self._heap and self._heap[0][0] <= tick:
            out.append(heapq.heappop(self._heap)[2])
        return out

    def __len__(self) -> int:
        return len(self._heap)
