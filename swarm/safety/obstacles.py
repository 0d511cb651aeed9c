"""Obstacles as the filter sees them: arrays of centres, motion, radii and axes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.errors import InputError
from swarm.model import check_finite
from swarm.rotation import BoolArray, FloatArray, IntArray

OBSTACLE = np.dtype(
    [
        ("c", "f8", 3),  # m, world: centre (a point on the axis for a cylinder)
        ("cd", "f8", 3),  # m/s, world: its velocity
        ("cdd", "f8", 3),  # m/s^2, world: its acceleration
        ("r", "f8"),  # m: the obstacle's own radius
        ("axis", "f8", 3),  # unit axis of a cylinder [world], zeros for a sphere
        ("is_nb", "?"),  # another agent taking its share (a neighbour row)
        ("is_agent", "?"),  # another drone, with or without its share: its row keeps the keep-out ellipsoid
        ("grow", "f8"),  # m: what ``r`` grew by for its state's age (a drone's keep-out ellipsoid grows by it too)
    ],
    align=True,
)
"""One obstacle as the compiled kernels read it (``obs[o].c[k]``): the one order of the
obstacle fields everywhere."""


class ObstacleArrays:
    """``n`` obstacles (static, moving, or other agents), one filter row each, held as one
    (n,) :data:`OBSTACLE` structured array ``rec`` that the compiled kernels take as it is;
    the named fields below are views into it.

    ``radius_m`` is the obstacle's own radius; the filter adds the agent's bounding
    radius and margin. Neighbour rows get the responsibility share, obstacle rows do
    not. Rows of other drones (``is_agent``: every neighbour, and one taken whole) keep the
    airframe pair's keep-out ellipsoid (``swarm.safety.barriers``, "Keep-out ellipsoid").
    Build with :meth:`build`, which validates; the constructor trusts its input.
    """

    __slots__ = ("rec",)

    def __init__(
        self,
        c_w: FloatArray,
        c_dot_w: FloatArray,
        c_ddot_w: FloatArray,
        radius_m: FloatArray,
        axis_w: FloatArray,
        is_neighbour: BoolArray,
        is_agent: BoolArray | bool | None = None,
    ) -> None:
        """``is_agent``: the rows of other drones (None: the neighbour rows without an axis)."""
        rec = np.empty(len(radius_m), dtype=OBSTACLE)
        rec["c"] = c_w
        rec["cd"] = c_dot_w
        rec["cdd"] = c_ddot_w
        rec["r"] = radius_m
        rec["axis"] = axis_w
        rec["is_nb"] = is_neighbour
        rec["is_agent"] = (rec["is_nb"] & ~rec["axis"].any(axis=1)) if is_agent is None else is_agent
        rec["grow"] = 0.0
        self.rec = rec

    @staticmethod
    def of_records(rec: np.ndarray) -> ObstacleArrays:
        """Obstacles over an existing (n,) :data:`OBSTACLE` array (no copy)."""
        out = ObstacleArrays.__new__(ObstacleArrays)
        out.rec = rec
        return out

    @property
    def c_w(self) -> FloatArray:
        """(n, 3) m, world: centre (a point on the axis for a cylinder)."""
        return self.rec["c"]

    @property
    def c_dot_w(self) -> FloatArray:
        """(n, 3) m/s, world."""
        return self.rec["cd"]

    @property
    def c_ddot_w(self) -> FloatArray:
        """(n, 3) m/s^2, world."""
        return self.rec["cdd"]

    @property
    def radius_m(self) -> FloatArray:
        """(n,) m."""
        return self.rec["r"]

    @property
    def axis_w(self) -> FloatArray:
        """(n, 3) unit axis of a cylinder [world], zeros for a sphere."""
        return self.rec["axis"]

    @property
    def is_neighbour(self) -> BoolArray:
        """(n,) another agent taking its share of the pair (a neighbour row)."""
        return self.rec["is_nb"]

    @property
    def grow_m(self) -> FloatArray:
        """(n,) m: what each radius grew by for its state's age (``swarm.net.neighbours``)."""
        return self.rec["grow"]

    @property
    def is_agent(self) -> BoolArray:
        """(n,) another drone (a neighbour, or one taken whole): its row keeps the keep-out ellipsoid."""
        return self.rec["is_agent"]

    def __len__(self) -> int:
        return len(self.rec)

    def at(self, dt_s: float) -> ObstacleArrays:
        """These obstacles ``dt_s`` [s] later, each moving with its constant acceleration
        (these, when none moves or ``dt_s`` is 0)."""
        cd, cdd = self.c_dot_w, self.c_ddot_w
        if dt_s == 0.0 or not (cd.any() or cdd.any()):
            return self
        rec = self.rec.copy()
        rec["c"] = self.c_w + cd * dt_s + 0.5 * cdd * dt_s**2
        rec["cd"] = cd + cdd * dt_s
        return ObstacleArrays.of_records(rec)

    def widened(self, extra_m: FloatArray) -> ObstacleArrays:
        """A copy with each row's radius, and the growth its keep-out ellipsoid takes, larger by
        ``extra_m`` (n,) [m] (the live margins, ``swarm.step``)."""
        rec = self.rec.copy()
        rec["r"] += extra_m
        rec["grow"] += extra_m
        return ObstacleArrays.of_records(rec)

    @staticmethod
    def empty() -> ObstacleArrays:
        return _EMPTY

    @staticmethod
    def build(
        c_w: object,
        radius_m: object,
        c_dot_w: object | None = None,
        c_ddot_w: object | None = None,
        axis_w: object | None = None,
        is_neighbour: object | None = None,
        is_agent: object | None = None,
    ) -> ObstacleArrays:
        """Validated arrays; missing motion is zero, a missing axis means spheres, missing
        ``is_agent`` means the neighbours that are spheres. Raises :class:`InputError` naming the field on a
        bad shape, NaN or a negative radius, or on a drone with an axis."""
        c = check_finite("obstacles.c_w", c_w)
        if c.ndim == 1 and c.size == 3:
            c = c[None, :]
        n = c.shape[0] if c.ndim == 2 else -1
        if c.shape != (n, 3):
            raise InputError(f"obstacles.c_w: expected shape (n, 3), got {c.shape}")
        r = check_finite("obstacles.radius_m", np.atleast_1d(np.asarray(radius_m, dtype=float)), (n,))
        if np.any(r < 0):
            raise InputError(f"obstacles.radius_m: radius must be >= 0, got {r.min()}")

        def vec(name: str, v: object | None) -> FloatArray:
            if v is None:
                return np.zeros((n, 3))
            return check_finite(f"obstacles.{name}", np.asarray(v, dtype=float).reshape(-1, 3), (n, 3))

        a = vec("axis_w", axis_w)
        na = np.linalg.norm(a, axis=1)
        cyl = na > 0
        if np.any(na[cyl] < 1e-9):
            raise InputError("obstacles.axis_w: a cylinder axis must not be (nearly) zero")
        a[cyl] /= na[cyl, None]
        nb = np.zeros(n, dtype=bool) if is_neighbour is None else np.asarray(is_neighbour, dtype=bool).reshape(-1)
        if nb.shape != (n,):
            raise InputError(f"obstacles.is_neighbour: expected shape ({n},), got {nb.shape}")
        ag = nb & ~cyl if is_agent is None else np.asarray(is_agent, dtype=bool).reshape(-1)
        if ag.shape == (1,) and n != 1:
            ag = np.full(n, bool(ag[0]))
        if ag.shape != (n,):
            raise InputError(f"obstacles.is_agent: expected shape ({n},), got {ag.shape}")
        if np.any(cyl & ag):
            raise InputError("obstacles.is_agent: a drone is a sphere (no axis)")
        return ObstacleArrays(c, vec("c_dot_w", c_dot_w), vec("c_ddot_w", c_ddot_w), r, a, nb, ag)

    def subset(self, keep: IntArray | BoolArray) -> ObstacleArrays:
        return ObstacleArrays.of_records(self.rec[keep])

    @staticmethod
    def concat(parts: list[ObstacleArrays]) -> ObstacleArrays:
        parts = [p for p in parts if len(p)]
        if len(parts) <= 1:
            return parts[0] if parts else _EMPTY
        return ObstacleArrays.of_records(np.concatenate([o.rec for o in parts]))


_EMPTY = ObstacleArrays.of_records(np.zeros(0, dtype=OBSTACLE))


@dataclass(frozen=True)
class NamedObstacles:
    """Rows with their names: ``arrays`` (n rows) and ``ids`` (n,) (an obstacle's id, or the
    neighbour agent's), in the same order."""

    arrays: ObstacleArrays
    ids: list[str]
    sd_m: FloatArray | None = None  # (n,) m: each row's centre's position deviation its state carries (None: 0)
    age_s: FloatArray | None = None  # (n,) s: each row's state's age (None: 0, measured or fixed)

    @staticmethod
    def none() -> NamedObstacles:
        return NamedObstacles(_EMPTY, [])

    def __len__(self) -> int:
        return len(self.ids)
