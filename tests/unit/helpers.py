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


def real_drone_raw(**crazyflie: object) -> dict:
    """A raw config of one real Crazyflie (mock motion capture, realtime) with ``crazyflie``
    settings added to its ``udp://127.0.0.1:19850`` link."""
    return {
        "version": 1,
        "name": "real",
        "duration_s": 5,
        "time": {"mode": "realtime"},
        "mocap": {"type": "mock"},
        "agents": [
            {
                "id": "cf1",
                "backend": "crazyflie",
                "start": [0, 0, 1.0],
                "goal": [1.0, 0, 1.0],
                "crazyflie": {"uri": "udp://127.0.0.1:19850", **crazyflie},
            }
        ],
    }
