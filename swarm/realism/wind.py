"""Wind: a steady part and Dryden gusts, as the air's velocity [m/s, world] at each drone.

The gusts are the Dryden model of MIL-F-8785C (section 3.7.2) as MIL-HDBK-1797 keeps it,
its low-altitude form: three components, ``u`` along the steady wind (world x when there
is none), ``v`` across it, ``w`` vertical, each white noise through its spectrum's shaping
filter, with ``T = L / V`` (Taylor's frozen turbulence: a spatial scale ``L`` [m] flown
through at the airspeed ``V`` [m/s])::

    H_u(s) = sigma_u sqrt(2 T_u) / (1 + T_u s)                 R_u(tau) = sigma_u^2 exp(-x)
    H_v(s) = sigma_v sqrt(T_v) (1 + sqrt(3) T_v s) / (1 + T_v s)^2
                                        R_v(tau) = sigma_v^2 (1 - x / 2) exp(-x),  x = |tau| / T

(``H_w`` as ``H_v``; unit white-noise input, so each component's variance is ``sigma^2``).
Discretised exactly for white noise: each filter's state-space form ``(A, B)`` becomes
``x' = A_d x + L_d n`` with ``A_d = exp(A dt)`` and ``L_d L_d^T = int_0^dt exp(A s) B B^T
exp(A^T s) ds`` (Van Loan's matrix exponential), and starts from its stationary
distribution, so the statistics hold from the first step.

Low-altitude scales (MIL-F-8785C, ``h`` in feet, 10 ft <= h <= 1000 ft)::

    L_w = h,   L_u = L_v = h / (0.177 + 0.000823 h)^1.2,   sigma_w / sigma_u = (0.177 + 0.000823 h)^0.4

An indoor lab flies below the spec's 10 ft and has no weather: the scales are evaluated
at ``max(h, 10 ft)`` and the intensity is a setting (``gust_std_mps``, sigma_u = sigma_v).
Leaves out: gusts' spatial variation within the swarm when ``shared`` (one field for all,
valid where the drones are closer than ``L``), or any correlation between drones when not
(each its own field: the worst case), and rotational turbulence (MIL's p, q, r).

Per-drone turbulence (off by default): ``relative_gust_std_mps`` adds to the shared field
each drone's own gust, three independent first-order Gauss-Markov (Ornstein-Uhlenbeck)
components of standard deviation ``sigma_r`` and correlation time ``T_r = L_r / V``
(``relative_gust_length_m`` over ``airspeed_mps``): Dryden's ``u`` form, isotropic as
turbulence at scales well below ``L`` is (Kolmogorov's local isotropy), discretised exactly
(``y' = a y + sigma_r sqrt(1 - a^2) n``, ``a = exp(-dt / T_r)``) and stationary from the
first step. It stands for the eddies smaller than the spacing, which the shared field (of
scale ``L``, metres to hundreds of metres) cannot make differ between neighbours: two
drones' winds correlate by ``sigma_s^2 / (sigma_s^2 + sigma_r^2)`` per horizontal
component. Assumed, no lab measurement: a lab that sees its drones buffeted apart sets
``sigma_r`` of the order of ``gust_std_mps`` and ``L_r`` of the order of its spacing.

Body drag (off by default): ``body_drag_area_m2`` is the body's ``C_d A``, and the air pushes
the body with ``-rho C_d A |v_rel| v_rel / 2`` (``rho`` 1.204 kg/m^3, dry air at 20 C and
sea level), a force of its own besides the rotors' linear drag (Forster 2015, in
:mod:`swarm.realism.aero`, whose constants were identified in flight below about 1 m/s and
so already hold the body's drag at those speeds). No published ``C_d A`` of a Crazyflie was
found; a bluff body's ``C_d`` of about 1 (Hoerner, *Fluid-Dynamic Drag*, 1965) on the
Crazyflie 2.1's 92 mm x 29 mm side (datasheet), half of it solid, gives about 1.3e-3 m^2
(0.8 mN at 1 m/s, 0.3 % of a 27 g drone's weight; at 5 m/s 20 mN, 7 %).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from swarm.realism.rng import Stream, normals
from swarm.rotation import FloatArray

FT_M = 0.3048
AIR_DENSITY_KG_M3 = 1.204  # dry air, 20 C, 101.325 kPa


def mil_f_8785c_low_altitude(height_m: float) -> tuple[float, float, float]:
    """(L_u = L_v [m], L_w [m], sigma_w / sigma_u) of the Dryden low-altitude model at
    ``height_m``, evaluated within the spec's 10-1000 ft."""
    h = min(max(height_m / FT_M, 10.0), 1000.0)
    k = 0.177 + 0.000823 * h
    return h / k**1.2 * FT_M, h * FT_M, k**0.4


@dataclass(frozen=True)
class WindParams:
    steady_w_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """The mean wind [m/s, world]."""
    gust_std_mps: float = 0.0
    """sigma_u = sigma_v [m/s]; 0: no gusts."""
    gust_vertical_std_mps: float | None = None
    """sigma_w [m/s]; None: sigma_u times MIL-F-8785C's low-altitude ratio."""
    gust_length_m: float | None = None
    """L_u = L_v [m]; None: MIL-F-8785C's at ``height_m``."""
    gust_vertical_length_m: float | None = None
    """L_w [m]; None: MIL-F-8785C's at ``height_m``."""
    height_m: float = 1.0
    """The flight height the MIL-F-8785C scales are taken at [m]."""
    airspeed_mps: float = 1.0
    """V [m/s]: the drones' speed through the air, turning lengths into times."""
    shared: bool = True
    """One gust field for every drone (True), or each drone its own."""
    relative_gust_std_mps: float = 0.0
    """sigma_r [m/s] of each drone's own gust, added to the field's (each component); 0: none."""
    relative_gust_length_m: float = 0.3
    """L_r [m]: each drone's own gust's correlation length (its time: L_r / V)."""
    body_drag_area_m2: float = 0.0
    """The body's C_d A [m^2]: a quadratic drag of the body in the air; 0: none."""

    def scales(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """((sigma_u, sigma_v, sigma_w) [m/s], (T_u, T_v, T_w) [s]) of the gusts."""
        L_uv, L_w, ratio = mil_f_8785c_low_altitude(self.height_m)
        L_uv = self.gust_length_m if self.gust_length_m is not None else L_uv
        L_w = self.gust_vertical_length_m if self.gust_vertical_length_m is not None else L_w
        s_w = self.gust_vertical_std_mps if self.gust_vertical_std_mps is not None else self.gust_std_mps * ratio
        V = self.airspeed_mps
        return (self.gust_std_mps, self.gust_std_mps, s_w), (L_uv / V, L_uv / V, L_w / V)

    @property
    def gusts(self) -> bool:
        sigma, _ = self.scales()
        return any(s > 0.0 for s in sigma)

    @property
    def relative(self) -> bool:
        return self.relative_gust_std_mps > 0.0

    @property
    def any(self) -> bool:
        return self.gusts or self.relative or any(c != 0.0 for c in self.steady_w_mps)


def body_drag_force_w(v_rel_w: FloatArray, cd_area_m2: float) -> FloatArray:
    """(n, 3) [N, world]: the body's quadratic drag ``-rho C_d A |v_rel| v_rel / 2`` for the
    velocities relative to the air ``v_rel_w`` (n, 3) [m/s, world] (the drone's less the wind's)."""
    speed = np.linalg.norm(v_rel_w, axis=1, keepdims=True)
    return -0.5 * AIR_DENSITY_KG_M3 * cd_area_m2 * speed * v_rel_w


def dryden_state_space(
    sigma_mps: tuple[float, float, float], T_s: tuple[float, float, float]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(A (5, 5), B (5, 3), C (3, 5)) of the three shaping filters (states: u; v, v'; w, w')
    driven by unit white noise, outputs (u, v, w) [m/s]."""
    A = np.zeros((5, 5))
    B = np.zeros((5, 3))
    C = np.zeros((3, 5))
    s_u, s_v, s_w = sigma_mps
    T_u, T_v, T_w = T_s
    A[0, 0] = -1.0 / T_u
    B[0, 0] = s_u * math.sqrt(2.0 * T_u) / T_u
    C[0, 0] = 1.0
    for out, (k, s, T) in enumerate(((1, s_v, T_v), (3, s_w, T_w)), start=1):
        a = 1.0 / T
        K = s * math.sqrt(T)
        A[k, k + 1] = 1.0
        A[k + 1, k] = -a * a
        A[k + 1, k + 1] = -2.0 * a
        B[k + 1, out] = 1.0
        C[out, k] = K / T**2
        C[out, k + 1] = math.sqrt(3.0) * K / T
    return A, B, C


def discretise(A: FloatArray, B: FloatArray, dt_s: float) -> tuple[FloatArray, FloatArray]:
    """(A_d, L_d): the exact discrete transition and a square root of the noise it gathers
    over ``dt_s`` (Van Loan, "Computing integrals involving the matrix exponential", 1978)."""
    m = A.shape[0]
    M = np.zeros((2 * m, 2 * m))
    M[:m, :m] = -A
    M[:m, m:] = B @ B.T
    M[m:, m:] = A.T
    E = sla.expm(M * dt_s)
    Ad = E[m:, m:].T
    Q = Ad @ E[:m, m:]
    return Ad, _psd_sqrt((Q + Q.T) / 2.0)


def _psd_sqrt(Q: FloatArray) -> FloatArray:
    w, V = np.linalg.eigh(Q)
    return V * np.sqrt(np.maximum(w, 0.0))


class Wind:
    """The air's velocity at n drones, advanced one step per :meth:`step`."""

    def __init__(self, p: WindParams, n: int, dt_s: float, seed: int) -> None:
        self.p = p
        self.n = n
        self.seed = seed
        self.k = 0
        self.steady_w = np.asarray(p.steady_w_mps, float)
        self.wind_w = np.tile(self.steady_w, (n, 1))
        """(n, 3) [m/s, world]: the wind at each drone now."""
        self._gusts = p.gusts
        self._relative = p.relative
        if self._relative:
            T_r = p.relative_gust_length_m / p.airspeed_mps
            self._a_r = math.exp(-dt_s / T_r)
            self._b_r = p.relative_gust_std_mps * math.sqrt(1.0 - self._a_r**2)
            self._drones = np.arange(n)
            self.y = p.relative_gust_std_mps * normals(seed, Stream.WIND_RELATIVE, self._drones, 0, 3)
            """(n, 3) [m/s, world]: each drone's own gust, stationary from the start."""
        if not self._gusts:
            if self._relative:
                self.wind_w = self.wind_w + self.y
            return
        self._fields = 1 if p.shared else n
        sigma, T = p.scales()
        A, B, C = dryden_state_space(sigma, T)
        Ad, Ld = discretise(A, B, dt_s)
        self._AdT, self._LdT = np.ascontiguousarray(Ad.T), np.ascontiguousarray(Ld.T)
        P = sla.solve_continuous_lyapunov(A, -B @ B.T)
        x0 = normals(seed, Stream.WIND, np.arange(self._fields), 0, 5)
        self.x = x0 @ _psd_sqrt((P + P.T) / 2.0).T  # (fields, 5), stationary from the start
        h = self.steady_w[:2]
        c, s = (h / np.linalg.norm(h)) if np.linalg.norm(h) > 0 else (1.0, 0.0)
        axes_w = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # columns: u, v, w
        self._out = C.T @ axes_w.T  # (5, 3): state -> world velocity
        self._update()

    def _update(self) -> None:
        w = self.steady_w + self.x @ self._out
        self.wind_w = np.repeat(w, self.n, axis=0) if self._fields == 1 else w
        if self._relative:
            self.wind_w = self.wind_w + self.y

    def step(self) -> FloatArray:
        """Advance one step; the wind (n, 3) [m/s, world] at each drone."""
        if not self._gusts and not self._relative:
            return self.wind_w
        self.k += 1
        if self._relative:
            noise_r = normals(self.seed, Stream.WIND_RELATIVE, self._drones, self.k, 3)
            self.y = self._a_r * self.y + self._b_r * noise_r
        if not self._gusts:
            self.wind_w = self.steady_w + self.y
            return self.wind_w
        noise = normals(self.seed, Stream.WIND, np.arange(self._fields), self.k, 5)
        self.x = self.x @ self._AdT + noise @ self._LdT
        self._update()
        return self.wind_w
