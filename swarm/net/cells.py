"""Interest by distance: the grid cells an agent's state is published in, and the cells an
agent listens to (docs/design.md, "Neighbours by cells").

Space is cut into cubes of side ``cell_m`` [m, world]; cell (i, j, k) holds the points
``x`` with ``floor(x / cell_m) == (i, j, k)``. An agent publishes its state under the cell
of its body centre and subscribes to every cell that meets the ball of radius
``R + hysteresis`` around the position ``p0`` where it last declared them (its *anchor*).
While it stays within ``hysteresis / 2`` of the anchor, that set covers the ball of radius
``R + hysteresis / 2`` around it; it declares a new set once it is ``hysteresis / 4`` away,
so the new cells are declared while the old ones still cover a quarter of the hysteresis
of further motion (the time Zenoh takes to make the new subscriptions known).

``R`` is the *interest radius*: the sensing radius plus what a neighbour and the agent can
close between a state's time and its use (``neighbours.margin_m``;
``ScenarioConfig.interest_radius_m``). Pure functions; no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

Cell = tuple[int, int, int]


def cell_of(x_w: tuple[float, float, float] | list[float], cell_m: float) -> Cell:
    """The cell of the point ``x_w`` [m, world]."""
    return (math.floor(x_w[0] / cell_m), math.floor(x_w[1] / cell_m), math.floor(x_w[2] / cell_m))


def cells_meeting_ball(p_w: tuple[float, float, float] | list[float], radius_m: float, cell_m: float) -> set[Cell]:
    """Every cell that meets the closed ball of ``radius_m`` [m] around ``p_w`` [m, world]:
    the cells of the ball's bounding box whose nearest point to ``p_w`` is within
    ``radius_m``."""
    lo = [math.floor((p_w[a] - radius_m) / cell_m) for a in range(3)]
    hi = [math.floor((p_w[a] + radius_m) / cell_m) for a in range(3)]
    r2 = radius_m * radius_m
    out: set[Cell] = set()
    for i in range(lo[0], hi[0] + 1):
        dx = _gap(p_w[0], i, cell_m)
        for j in range(lo[1], hi[1] + 1):
            dy = _gap(p_w[1], j, cell_m)
            if dx * dx + dy * dy > r2:
                continue
            for k in range(lo[2], hi[2] + 1):
                dz = _gap(p_w[2], k, cell_m)
                if dx * dx + dy * dy + dz * dz <= r2:
                    out.add((i, j, k))
    return out


def _gap(x: float, i: int, cell_m: float) -> float:
    """Distance [m] along one axis from ``x`` to the slab of cell index ``i``."""
    lo, hi = i * cell_m, (i + 1) * cell_m
    return lo - x if x < lo else (x - hi if x > hi else 0.0)


@dataclass
class Interest:
    """The cells one agent subscribes to, with hysteresis (see the module docstring)."""

    radius_m: float  # interest radius R [m]
    cell_m: float  # cell side [m]
    hysteresis_m: float  # extra radius declared [m]
    anchor_w: tuple[float, float, float] | None = None  # where the current set was declared [m, world]
    cells: set[Cell] = field(default_factory=set)
    declared: int = 0  # cells declared so far

    def __post_init__(self) -> None:
        if not (self.radius_m > 0 and self.cell_m > 0 and self.hysteresis_m > 0):
            raise ValueError("Interest: radius_m, cell_m and hysteresis_m must be positive")

    def update(self, p_w: tuple[float, float, float] | list[float]) -> tuple[set[Cell], set[Cell]]:
        """The cells to declare and to undeclare now that the agent is at ``p_w``
        [m, world]; both empty while it is within ``hysteresis / 4`` of the anchor."""
        if self.anchor_w is not None and math.dist(p_w, self.anchor_w) <= self.hysteresis_m / 4:
            return set(), set()
        want = cells_meeting_ball(p_w, self.radius_m + self.hysteresis_m, self.cell_m)
        add, drop = want - self.cells, self.cells - want
        self.anchor_w, self.cells = (float(p_w[0]), float(p_w[1]), float(p_w[2])), want
        self.declared += len(add)
        return add, drop


def near_lists(x_w: np.ndarray, candidate: np.ndarray, radius_m: np.ndarray) -> list[list[int]]:
    """For each drone i, the indices j != i of the ``candidate`` (n,) bool drones whose
    point ``x_w[j]`` (n, 3) [m, world] is within ``radius_m[i]`` (n,) [m] of ``x_w[i]``,
    in index order."""
    d2 = np.sum((x_w[:, None, :] - x_w[None, :, :]) ** 2, axis=2)
    close = (d2 <= (radius_m**2)[:, None]) & candidate[None, :]
    np.fill_diagonal(close, False)
    return [np.flatnonzero(row).tolist() for row in close]
