"""What an agent knows of the other agents (DESIGN.md section 7): last published state,
extrapolated at constant velocity, with a radius that grows once the state is older
than the timeout; past the hard limit, or once the neighbour's liveliness is gone, it
is kept as a stopped obstacle at its last position or dropped, as configured."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.obstacles import ObstacleArrays
from swarm.rotation import FloatArray


@dataclass
class Neighbour:
    t_s: float  # sim time of the state [s]
    k: int  # tick of the state
    x_w: FloatArray  # (3,) m, world: body centre
    v_w: FloatArray  # (3,) m/s, world
    radius_m: float  # its own bounding radius
    gone: bool = False


class NeighbourTable:
    def __init__(
        self,
        timeout_s: float,
        growth_mps: float,
        hard_limit_s: float,
        on_lost: str = "keep_stopped",
    ) -> None:
        self.timeout_s, self.growth_mps, self.hard_limit_s, self.on_lost = timeout_s, growth_mps, hard_limit_s, on_lost
        self.table: dict[str, Neighbour] = {}

    def update(self, name: str, t_s: float, k: int, x_w: FloatArray, v_w: FloatArray, radius_m: float) -> None:
        old = self.table.get(name)
        if old is not None and (k < old.k or old.gone):
            return  # out of order, or already declared gone
        self.table[name] = Neighbour(t_s, k, x_w, v_w, radius_m)

    def mark_gone(self, name: str) -> None:
        if name in self.table:
            self.table[name].gone = True

    def latest_k(self, name: str) -> int:
        n = self.table.get(name)
        return -1 if n is None else n.k

    def lost(self, name: str, t_now_s: float) -> bool:
        n = self.table[name]
        return n.gone or t_now_s - n.t_s > self.hard_limit_s

    def arrays(self, t_now_s: float) -> ObstacleArrays:
        """Neighbour rows at ``t_now_s`` [s]."""
        if not self.table:
            return ObstacleArrays.empty()
        c, cd, r = [], [], []
        for name, n in self.table.items():
            age = max(0.0, t_now_s - n.t_s)
            if self.lost(name, t_now_s):
                if self.on_lost == "drop":
                    continue
                c.append(n.x_w)
                cd.append(np.zeros(3))
                r.append(n.radius_m)
                continue
            c.append(n.x_w + n.v_w * age)
            cd.append(n.v_w)
            r.append(n.radius_m + self.growth_mps * max(0.0, age - self.timeout_s))
        if not c:
            return ObstacleArrays.empty()
        return ObstacleArrays.build(np.array(c), np.array(r), np.array(cd), is_neighbour=np.ones(len(c), bool))
