"""What an agent knows of the other agents (docs/design.md, "Failures"): last published state,
extrapolated at constant velocity, with a radius that grows once the state is older
than the timeout; past the hard limit, or once the neighbour's liveliness is gone, it
is kept as a stopped obstacle at its last position or dropped, as configured."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from swarm.obstacles import OBSTACLE, ObstacleArrays
from swarm.rotation import BoolArray, FloatArray, IntArray


@njit(cache=True)
def _roster_fill(xvr, rows, is_nb, out):
    """Fill ``out`` (k,) :data:`swarm.obstacles.OBSTACLE` with the drones ``rows`` of a
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


class NeighbourTable:
    """Latest states per neighbour, with a short history by tick so that lockstep runs
    can use exactly the state of tick k-1 whatever else has arrived meanwhile."""

    HISTORY = 8  # ticks of history kept per neighbour

    def __init__(
        self,
        timeout_s: float,
        growth_mps: float,
        hard_limit_s: float,
        on_lost: str = "keep_stopped",
    ) -> None:
        self.timeout_s, self.growth_mps, self.hard_limit_s, self.on_lost = timeout_s, growth_mps, hard_limit_s, on_lost
        self.history: dict[str, dict[int, Neighbour]] = {}
        self.gone: set[str] = set()
        self.row_names: list[str] = []  # names of the rows the last arrays() built

    def update(
        self, name: str, t_s: float, k: int, x_w: FloatArray, v_w: FloatArray, radius_m: float, solo: bool = False
    ) -> None:
        if name in self.gone:
            return
        h = self.history.setdefault(name, {})
        h[k] = Neighbour(t_s, k, x_w, v_w, radius_m, solo)
        if len(h) > self.HISTORY:
            del h[min(h)]

    def update_records(self, records: np.ndarray, known: set[str], counter: Any) -> None:
        """Every checked :data:`swarm.statewire.STATE` record of ``records`` whose sender is
        one of ``known``; any other is dropped and counted on ``counter``
        (:class:`swarm.transport.Counter`)."""
        x, v = records["x"], records["v"]
        t, k, r = records["t"].tolist(), records["k"].tolist(), records["r"].tolist()
        solo = (records["flags"] & 1).tolist()
        for i, src in enumerate(records["src"].tolist()):
            name = src.decode()
            if name not in known:
                counter.drop("state: from an agent it does not know, or itself")
                continue
            self.update(name, t[i], k[i], x[i], v[i], r[i], solo[i] == 1)

    def mark_gone(self, name: str) -> None:
        self.gone.add(name)

    def latest_k(self, name: str) -> int:
        h = self.history.get(name)
        return max(h) if h else -1

    def state(self, name: str, k_max: int | None = None) -> Neighbour | None:
        """Newest state of ``name`` with tick <= ``k_max`` (any tick when None)."""
        h = self.history.get(name)
        if not h:
            return None
        ks = [k for k in h if k_max is None or k <= k_max]
        return h[max(ks)] if ks else None

    def forget_far(self, x_w: FloatArray, radius_m: float, t_now_s: float) -> None:
        """Forget the neighbours (not gone) last heard farther than ``radius_m`` [m] from
        ``x_w`` [m, world] and more than the timeout ago: they left the cells this agent
        listens to (``neighbours.interest: cells``), they are not lost."""
        for name in [n for n in self.history if n not in self.gone]:
            s = self.state(name)
            if s is not None and t_now_s - s.t_s > self.timeout_s and math.dist(s.x_w, x_w) > radius_m:
                del self.history[name]

    def arrays(self, t_now_s: float, k_max: int | None = None, names: list[str] | None = None) -> ObstacleArrays:
        """Neighbour rows at ``t_now_s`` [s], from states of tick <= ``k_max``; their
        names are left in :attr:`row_names`. A neighbour that is gone, past the hard limit
        or ``solo`` is an obstacle row (``is_neighbour`` false): it is not doing its share,
        so this agent takes all of the pair. ``names``: only these neighbours (in this
        order), and the gone ones."""
        self.row_names = []
        if not self.history:
            return ObstacleArrays.empty()
        c, cd, r, share = [], [], [], []
        if names is not None:
            names = [n for n in names if n in self.history] + [n for n in self.history if n in self.gone]
        for name in self.history if names is None else dict.fromkeys(names):
            n = self.state(name, k_max)
            if n is None:
                continue
            age = max(0.0, t_now_s - n.t_s)
            if name in self.gone or age > self.hard_limit_s:
                if self.on_lost == "drop":
                    continue
                c.append(n.x_w)
                cd.append(np.zeros(3))
                r.append(n.radius_m)
                share.append(False)
                self.row_names.append(name)
                continue
            self.row_names.append(name)
            c.append(n.x_w + n.v_w * age)
            cd.append(n.v_w)
            r.append(n.radius_m + self.growth_mps * max(0.0, age - self.timeout_s))
            share.append(not n.solo)
        if not c:
            return ObstacleArrays.empty()
        return ObstacleArrays.build(np.array(c), np.array(r), np.array(cd), is_neighbour=np.array(share, bool))
