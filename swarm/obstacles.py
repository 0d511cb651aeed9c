"""Obstacles as the filter sees them: arrays of centres, motion, radii and axes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.errors import InputError
from swarm.model import check_finite
from swarm.rotation import BoolArray, FloatArray, IntArray

_FIELDS = ("c_w", "c_dot_w", "c_ddot_w", "radius_m", "axis_w", "is_neighbour")


@dataclass(frozen=True)
class ObstacleArrays:
    """``n`` obstacles (static, moving, or other agents), one filter row each.

    ``radius_m`` is the obstacle's own radius; the filter adds the agent's bounding
    radius and margin. Neighbour rows get the responsibility share, obstacle rows do
    not. Build with :meth:`build`, which validates; the constructor trusts its input.
    """

    c_w: FloatArray  # (n, 3) m, world: centre (a point on the axis for a cylinder)
    c_dot_w: FloatArray  # (n, 3) m/s, world
    c_ddot_w: FloatArray  # (n, 3) m/s^2, world
    radius_m: FloatArray  # (n,) m
    axis_w: FloatArray  # (n, 3) unit axis of a cylinder [world], zeros for a sphere
    is_neighbour: BoolArray  # (n,)

    def __len__(self) -> int:
        return len(self.radius_m)

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
    ) -> ObstacleArrays:
        """Validated arrays; missing motion is zero, a missing axis means spheres.
        Raises :class:`InputError` naming the field on a bad shape, NaN or a negative radius."""
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
        return ObstacleArrays(c, vec("c_dot_w", c_dot_w), vec("c_ddot_w", c_ddot_w), r, a, nb)

    def subset(self, keep: IntArray | BoolArray) -> ObstacleArrays:
        return ObstacleArrays(*(getattr(self, f)[keep] for f in _FIELDS))

    @staticmethod
    def concat(parts: list[ObstacleArrays]) -> ObstacleArrays:
        parts = [p for p in parts if len(p)]
        if len(parts) <= 1:
            return parts[0] if parts else _EMPTY
        return ObstacleArrays(*(np.concatenate([getattr(o, f) for o in parts]) for f in _FIELDS))


_Z = np.zeros((0, 3))
_EMPTY = ObstacleArrays(_Z, _Z, _Z, np.zeros(0), _Z, np.zeros(0, dtype=bool))
