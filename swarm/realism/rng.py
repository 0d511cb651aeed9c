"""Counter-based random numbers: every draw a pure function of its coordinates.

A draw is ``hash(seed, stream, a, b, c)``: the run's seed, the model that draws (a
``Stream``), and up to three integers naming the draw (a drone, an axis, a step or a
tick). No generator state is shared or carried, so a draw does not depend on how many
others were made before it, in which order, or in which process: the world and the
in-process closed loop make the same noise for the same seed, and a lockstep run repeats
bit for bit whatever the scheduling of its processes.

The hash is SplitMix64's finaliser (Steele, Lea and Flood, "Fast splittable pseudorandom
number generators", OOPSLA 2014; the output function of ``java.util.SplittableRandom``)
applied once per word, which passes BigCrush as a counter-based generator. Uniforms keep
the top 53 bits; normals are Box-Muller of two uniforms.
"""

from __future__ import annotations

import hashlib
import math
from enum import IntEnum

import numpy as np
from numba import njit

from swarm.rotation import FloatArray

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_TWO53_INV = 1.0 / 9007199254740992.0  # 2^-53
_MASK64 = (1 << 64) - 1


class Stream(IntEnum):
    """Which model draws: keeps the draws of different models independent."""

    THRUST_FACTOR = 1
    MASS_FACTOR = 2
    WIND = 3
    MOCAP_POSITION = 4
    MOCAP_ATTITUDE = 5
    MOCAP_DROP = 6
    COMMS = 7
    # 40-49: motion capture's failures (swarm.realism.sensing)
    MOCAP_OCCLUSION = 40  # a burst of occlusion starts (drone, frame)
    MOCAP_OCCLUSION_LENGTH = 41  # its length, drawn at its start (drone, frame)
    MOCAP_SWAP = 42  # two drones' identities swap (frame)
    MOCAP_OUTLIER = 43  # a frame jumps (drone, frame)
    MOCAP_OUTLIER_DIRECTION = 44  # the jump's direction (drone, frame)
    MOCAP_CENTROID = 45  # a drone's constant offset of the markers' centroid (drone)
    # 50-59: a bad day's plant and radio (battery sag, burst loss, per-drone gusts)
    BATTERY_START = 50
    COMMS_BURST = 51
    WIND_RELATIVE = 52


def word(value: int) -> np.uint64:
    """Any Python integer (a seed may be negative or large) as one 64-bit word."""
    return np.uint64(int(value) & _MASK64)


def name_word(name: str) -> int:
    """A stable 64-bit word for a name (an agent id): BLAKE2b, not Python's salted ``hash``."""
    return int.from_bytes(hashlib.blake2b(name.encode("utf-8"), digest_size=8).digest(), "little")


@njit(cache=True)
def _mix(h, w):
    """One SplitMix64 round of the state ``h`` with the word ``w`` (both uint64)."""
    z = (h ^ w) + _GOLDEN
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(cache=True)
def hash5(seed, stream, a, b, c):
    """The 64-bit hash of five uint64 words."""
    h = _mix(np.uint64(0), seed)
    h = _mix(h, stream)
    h = _mix(h, a)
    h = _mix(h, b)
    return _mix(h, c)


@njit(cache=True)
def uniform(seed, stream, a, b, c):
    """A uniform draw in (0, 1] of the coordinates (uint64 words)."""
    return (float(hash5(seed, stream, a, b, c) >> _S11) + 1.0) * _TWO53_INV


@njit(cache=True)
def normal(seed, stream, a, b, c):
    """A standard normal draw of the coordinates (Box-Muller of two uniforms that differ
    in the lowest bit of ``c``, so give ``c`` as ``2 k``)."""
    u1 = uniform(seed, stream, a, b, c)
    u2 = uniform(seed, stream, a, b, c ^ np.uint64(1))
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@njit(cache=True)
def normals_into(seed, stream, a, b, out):
    """Fill ``out`` (m, k) with standard normals: row i, column j is the draw of the
    coordinates ``(a[i], b, 2 j)`` (``a`` (m,) uint64, ``b`` uint64)."""
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = normal(seed, stream, a[i], b, np.uint64(2 * j))


def normals(seed: int, stream: Stream, a: object, b: int, k: int) -> FloatArray:
    """(m, k) standard normals of the coordinates ``(a[i], b, column)``."""
    a_w = np.asarray(a, dtype=np.int64).astype(np.uint64)
    out = np.empty((a_w.shape[0], k))
    normals_into(word(seed), np.uint64(int(stream)), a_w, word(b), out)
    return out
