"""Shared test helpers (no fixtures with hidden behaviour)."""

from __future__ import annotations

import numpy as np

from swarm.model import QuadState
from swarm.rotation import euler_to_quat


def random_state(rng: np.random.Generator, *, tilt: float = 0.4, rates: float = 3.0) -> QuadState:
    """A moving, tilted, rotating state near (0, 0, 1) m."""
    return QuadState(
        rng.uniform(-0.5, 0.5, 3) + np.array([0.0, 0.0, 1.0]),
        rng.uniform(-1.5, 1.5, 3),
        euler_to_quat(*rng.uniform(-tilt, tilt, 2), rng.uniform(-np.pi, np.pi)),
        rng.uniform(-rates, rates, 3),
    )
