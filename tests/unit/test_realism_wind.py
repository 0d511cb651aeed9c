"""Dryden gusts by their statistics: each component's variance and autocorrelation (the
spectra's exact forms), stationary from the first step; MIL-F-8785C's low-altitude scales."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.realism.wind import Wind, WindParams, mil_f_8785c_low_altitude

N = 4000  # independent gust fields (one per drone): an ensemble
DT = 0.05
# T_u = T_v = L / V = 2 m / 2 m/s = 1 s; T_w = 0.5 s
P = WindParams(
    gust_std_mps=0.5,
    gust_vertical_std_mps=0.3,
    gust_length_m=2.0,
    gust_vertical_length_m=1.0,
    airspeed_mps=2.0,
    shared=False,
)


def r_u(tau: float, T: float) -> float:
    return math.exp(-tau / T)


def r_v(tau: float, T: float) -> float:
    x = tau / T
    return (1 - x / 2) * math.exp(-x)


@pytest.fixture(scope="module")
def series() -> np.ndarray:
    w = Wind(P, N, DT, seed=11)
    out = [w.wind_w.copy()]
    for _ in range(40):
        out.append(w.step().copy())
    return np.array(out)  # (41, N, 3)


def test_each_component_has_its_variance_from_the_first_step(series):
    sigma = np.array([0.5, 0.5, 0.3])
    tol = 4 * math.sqrt(2 / N)  # 4 standard errors of a variance estimate
    for k in (0, 20, 40):
        var = series[k].var(axis=0)
        assert var / sigma**2 == pytest.approx(np.ones(3), abs=tol)
        assert np.all(np.abs(series[k].mean(axis=0)) <= 4 * sigma / math.sqrt(N))


@pytest.mark.parametrize("lag_steps", [5, 10, 20])
def test_each_component_has_its_drydens_autocorrelation(series, lag_steps):
    tau = lag_steps * DT
    want = [r_u(tau, 1.0), r_v(tau, 1.0), r_v(tau, 0.5)]
    for c in range(3):
        got = np.corrcoef(series[0, :, c], series[lag_steps, :, c])[0, 1]
        assert got == pytest.approx(want[c], abs=4 / math.sqrt(N)), (c, tau)


def test_the_components_are_independent(series):
    c = np.corrcoef(series[10].T)
    assert np.abs(c[np.triu_indices(3, 1)]) == pytest.approx(np.zeros(3), abs=4 / math.sqrt(N))


def test_u_runs_along_the_steady_wind():
    p = WindParams(steady_w_mps=(0.0, 2.0, 0.0), gust_std_mps=0.5, gust_length_m=2.0, airspeed_mps=2.0, shared=False)
    w = Wind(p, N, DT, seed=3)
    a = w.wind_w.copy()
    for _ in range(20):
        w.step()
    b = w.wind_w
    assert a.mean(axis=0)[1] == pytest.approx(2.0, abs=0.05)
    assert np.corrcoef(a[:, 1], b[:, 1])[0, 1] == pytest.approx(r_u(1.0, 1.0), abs=4 / math.sqrt(N))  # u: along y
    assert np.corrcoef(a[:, 0], b[:, 0])[0, 1] == pytest.approx(r_v(1.0, 1.0), abs=4 / math.sqrt(N))  # v: across


def test_gusts_are_seeded_and_shared_when_asked():
    p = WindParams(gust_std_mps=0.5)
    a, b, c = Wind(p, 3, DT, 5), Wind(p, 3, DT, 5), Wind(p, 3, DT, 6)
    for _ in range(10):
        wa, wb, wc = a.step(), b.step(), c.step()
    assert np.array_equal(wa, wb) and not np.array_equal(wa, wc)
    assert np.all(wa == wa[0])  # one field for all three drones


def test_no_gusts_leaves_the_steady_wind_exactly():
    w = Wind(WindParams(steady_w_mps=(0.3, -0.1, 0.0)), 2, DT, 0)
    for _ in range(5):
        assert np.array_equal(w.step(), [[0.3, -0.1, 0.0], [0.3, -0.1, 0.0]])


def test_mil_f_8785c_low_altitude_scales_by_hand():
    L_uv, L_w, ratio = mil_f_8785c_low_altitude(100 * 0.3048)  # h = 100 ft
    k = 0.177 + 0.000823 * 100
    assert L_w == pytest.approx(100 * 0.3048)
    assert L_uv == pytest.approx(100 / k**1.2 * 0.3048) and L_uv == pytest.approx(505.2 * 0.3048, rel=1e-3)
    assert ratio == pytest.approx(k**0.4) and ratio == pytest.approx(0.5828, rel=1e-3)
    assert mil_f_8785c_low_altitude(1.0) == mil_f_8785c_low_altitude(10 * 0.3048)  # below 10 ft: taken at 10 ft
