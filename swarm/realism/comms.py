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
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Generic, TypeVar

import numpy as np
from numba import njit

from swarm.realism.rng import Stream, hash5, name_word, word
from swarm.rotation import IntArray

LOST = -1
"""The fate of a message that never arrives."""


class MessageKind(IntEnum):
    STATE = 1
    BUNDLE = 2
    COMMAND = 3


@dataclass(frozen=True)
class LinkParams:
    delay_s: float = 0.0
    jitter_s: float = 0.0
    """A message's delay is ``delay_s`` plus up to this, uniformly [s]."""
    loss_fraction: float = 0.0

    @property
    def perfect(self) -> bool:
        return self.delay_s == 0.0 and self.jitter_s == 0.0 and self.loss_fraction == 0.0


@dataclass(frozen=True)
class CommsParams:
    state: LinkParams = LinkParams()
    bundle: LinkParams = LinkParams()
    command: LinkParams = LinkParams()

    def link(self, kind: MessageKind) -> LinkParams:
        return (self.state, self.bundle, self.command)[int(kind) - 1]

    @property
    def perfect(self) -> bool:
        return self.state.perfect and self.bundle.perfect and self.command.perfect


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

    def _word(self, name: str) -> int:
        w = self._names.get(name)
        if w is None:
            w = self._names[name] = name_word(name)
        return w

    def fate(self, sender: str, receiver: str, kind: MessageKind, tick: int) -> int:
        """Ticks after ``tick`` at which the message of ``kind`` that ``sender`` sent to
        ``receiver`` (agent ids; ``"world"`` for commands) at ``tick`` is delivered, or
        :data:`LOST`."""
        link = self.p.link(kind)
        if link.perfect:
            return 0
        pair = word(self._word(sender) * 0x9E3779B1 ^ self._word(receiver))
        return int(_fate(self.seed, _COMMS, pair, _kind_tick(kind, tick), *self._link(link)))

    def fates(self, senders: Sequence[str], receiver: str, kind: MessageKind, ticks: IntArray) -> IntArray:
        """(n,): entry i is :meth:`fate` of ``senders[i]``'s message to ``receiver`` sent at
        ``ticks[i]`` (>= 0); one compiled pass, for a receiver that takes many at once (a bundle)."""
        out = np.zeros(len(senders), dtype=np.intp)
        link = self.p.link(kind)
        if link.perfect or not len(senders):
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
        link = self.p.link(kind)
        if link.perfect:
            return out
        words = np.array([self._word(i) for i in ids], dtype=np.uint64)
        _fate_matrix(self.seed, _COMMS, words, _kind_tick(kind, tick), *self._link(link), out)
        return out

    def _link(self, link: LinkParams) -> tuple[float, float, float, float]:
        return link.delay_s, link.jitter_s, link.loss_fraction, self.tick_s


_COMMS = np.uint64(int(Stream.COMMS))


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
