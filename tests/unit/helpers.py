"""Shared test helpers (no fixtures with hidden behaviour)."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from swarm.build import agent_step
from swarm.config import ScenarioConfig
from swarm.model import QuadState
from swarm.planning import StaticObstacles
from swarm.rotation import euler_to_quat
from swarm.route import Route
from swarm.safety.barriers import BarrierKind, BarrierRows, evaluate_pw
from swarm.safety.filter import FilterConfig
from swarm.step import AgentStep

vec = arrays(np.float64, 3, elements=st.floats(-3, 3, allow_nan=False))
"""Hypothesis: a 3-vector with components in [-3, 3] (a position [m], velocity [m/s] or acceleration [m/s^2])."""
directions = arrays(np.float64, 3, elements=st.floats(-1, 1)).filter(lambda d: np.linalg.norm(d) > 0.1)
"""Hypothesis: a 3-vector in [-1, 1]^3 at least 0.1 long, to normalise into a direction."""


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


def proj(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v without its part along the unit axis a (zeros: v itself)."""
    return v - a * (a @ v)


def outside(p: np.ndarray, r: float, a: np.ndarray) -> np.ndarray | None:
    """p moved so that its projection is clear of the safety radius (or None)."""
    if np.linalg.norm(proj(a, p)) >= r + 0.05:
        return p
    p = p + (r + 0.2) * (np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0]))
    return p if np.linalg.norm(proj(a, p)) >= r + 0.05 else None


def satisfying(n_w: np.ndarray, c: float, acc: np.ndarray) -> np.ndarray:
    """``acc`` moved onto the half-space ``<n_w, a> + c >= 0`` if it is outside."""
    gap = n_w @ acc + c
    return acc if gap >= 0 else acc - gap * n_w / (n_w @ n_w)


def central_gradients(f: Callable[[np.ndarray, np.ndarray], float], p: np.ndarray, w: np.ndarray, e: float = 1e-6):
    """(df/dp, df/dw) of ``f(p, w)`` by central differences of step ``e``."""
    grads = []
    for which in (0, 1):
        num = np.zeros(3)
        for i in range(3):
            E = np.zeros(3)
            E[i] = e
            hi = f(p + E, w) if which == 0 else f(p, w + E)
            lo = f(p - E, w) if which == 0 else f(p, w - E)
            num[i] = (hi - lo) / (2 * e)
        grads.append(num)
    return grads[0], grads[1]


def closest_approach(
    row_at: Callable[[np.ndarray, np.ndarray, np.ndarray], BarrierRows],
    p: np.ndarray,
    w: np.ndarray,
    pull: Callable[[np.ndarray, np.ndarray], np.ndarray],
    gain: float,
    steps: int,
    dt: float = 0.005,
) -> float:
    """A pair in relative coordinates (``p`` obstacle minus agent [m], ``w = p'`` [m/s])
    flown on its row: every ``dt`` [s], the relative acceleration nearest to the reference
    ``pull(p, w)`` [m/s^2] that ``row_at(p, w, reference)`` admits at class-K gain ``gain``
    [1/s]. Returns the closest distance [m] over ``steps`` steps, or until the row is
    inside its safety radius."""
    closest = np.inf
    for _ in range(steps):
        rel_ref = pull(p, w)
        row = row_at(p, w, rel_ref)
        acc = satisfying(row.dh_dw[0], row.dh_dp[0] @ w + gain * row.h[0], rel_ref)
        p, w = p + dt * w + 0.5 * dt * dt * acc, w + dt * acc
        closest = min(closest, float(np.linalg.norm(p)))
        if row.inside[0]:
            break
    return closest


def live_rows(
    p: np.ndarray,
    w: np.ndarray,
    r: float,
    a: np.ndarray,
    a_ref: np.ndarray | None,
    nb: bool = False,
    horizon_s: float | None = None,
    reference_clear: bool = False,
    **settings: float | bool,
) -> BarrierRows:
    """One live C3BF row (``swarm.safety.barriers.evaluate_pw``) for relative ``p`` [m], ``w`` [m/s],
    safety radius ``r`` [m], cylinder axis ``a`` (zeros: a sphere), the reference's relative
    acceleration ``a_ref`` [m/s^2] (or None), a neighbour or not, with ``horizon_s`` [s] and
    the other row ``settings`` of ``evaluate`` (``contact_s``, ``free_braking``);
    ``reference_clear``: ``a_ref`` is the agent's own reference, clear of every cone."""
    return evaluate_pw(
        BarrierKind.C3BF,
        p[None],
        w[None],
        np.array([r]),
        a[None],
        live=True,
        a_ref=None if a_ref is None else a_ref[None],
        is_neighbour=np.array([nb]),
        horizon_s=horizon_s,
        reference_clear=reference_clear,
        **settings,
    )


class Planned(NamedTuple):
    """An agent as ``swarm agent`` builds it (``swarm.build.agent_step``): what the tests look at."""

    path_w: np.ndarray  # (k, 3) m, world: the path its tracker flies, from its start
    route: Route | None  # its route among walls, or None
    config: FilterConfig  # its filter's settings
    step: AgentStep


def planned(cfg: ScenarioConfig) -> list[Planned]:
    """Every agent of ``cfg`` built as its process builds it, in the config's order."""
    still = StaticObstacles.of(list(cfg.obstacles))
    out = []
    for a in cfg.agents:
        s = agent_step(cfg, a.id, still)
        out.append(Planned(s.tracker.W, s.route, s.config, s))
    return out
