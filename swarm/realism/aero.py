"""Aerodynamics the rigid-body model leaves out: downwash between drones, rotor drag, and
ground effect. Forces [N, world] at each drone's centre of mass, torques [N m, body].

All three are gym-pybullet-drones' models with the Crazyflie 2.x coefficients of its
``gym_pybullet_drones/assets/cf2x.urdf`` (``<properties>``), implemented in
``gym_pybullet_drones/envs/BaseAviary.py`` (``_downwash``, ``_drag``, ``_groundEffect``;
utiasDSL/gym-pybullet-drones at 90b178a, May 2026) and described in Panerati et al.,
"Learning to Fly", IROS 2021:

=====================  =============  =================================================
URDF attribute          value          here
=====================  =============  =================================================
``dw_coeff_1``          2267.18        :attr:`AeroParams.downwash_peak_N`
``dw_coeff_2``          0.16           :attr:`AeroParams.downwash_width_slope`
``dw_coeff_3``          -0.11          :attr:`AeroParams.downwash_width_offset_m`
``prop_radius``         2.31348e-2 m   :attr:`AeroParams.prop_radius_m`
``drag_coeff_xy``       9.1785e-7      :attr:`AeroParams.drag_xy_kg_per_rad`
``drag_coeff_z``        10.311e-7      :attr:`AeroParams.drag_z_kg_per_rad`
``gnd_eff_coeff``       11.36859       :attr:`AeroParams.ground_effect_coeff`
=====================  =============  =================================================

Where this module departs from upstream, it says so at the function.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numba import njit

from swarm.rotation import FloatArray

RPM_TO_RAD_S = 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class AeroParams:
    """Coefficients of the three models (defaults: gym-pybullet-drones' cf2x.urdf) and
    which of them act."""

    downwash: bool = True
    drag: bool = True
    ground_effect: bool = True
    prop_radius_m: float = 2.31348e-2
    downwash_peak_N: float = 2267.18
    """``dw_coeff_1``: the on-axis force is ``peak (r_p / (4 dz))^2`` [N]."""
    downwash_width_slope: float = 0.16
    """``dw_coeff_2``: the wake's lateral width is ``slope dz + offset`` [m]."""
    downwash_width_offset_m: float = -0.11
    """``dw_coeff_3`` [m]."""
    downwash_cap_thrust_fraction: float = 1.0
    """The force on a drone below is at most this fraction of the collective thrust of the
    drone above (:func:`downwash_force_w`); ``inf``: upstream's unbounded model."""
    downwash_range_xy_m: float = 10.0
    """Drones farther apart than this horizontally are ignored (upstream's 10 m)."""
    downwash_wake_radius_m: float = 0.0628
    """The wake's radius where it leaves the drone above, and the radius of the rotor discs of
    the drone below [m]: cf2x.urdf's ``arm`` (0.0397 m) plus ``prop_radius``, the rotor discs'
    outer extent (:func:`downwash_force_w`)."""
    downwash_wake_spread: float = 0.094
    """How fast the wake's radius grows with the distance below the drone [m/m]: the spreading
    rate of a turbulent round jet's half-velocity radius (Pope, *Turbulent Flows*, 2000, Table
    5.1; Hussein, Capp and George 1994: 0.094)."""
    downwash_model: Literal["gym_pybullet", "measured"] = "gym_pybullet"
    """Which downwash acts: ``"gym_pybullet"`` (upstream's fit, the coefficients above) or
    ``"measured"`` (a widening wake fitted to Neural-Swarm's Crazyflie flights, the
    ``downwash_measured_*`` coefficients below; :func:`downwash_force_w`)."""
    downwash_measured_area_m2: float = 4.19e-3
    """``measured``: the lower drone's effective area in the wake [m^2]: on the axis the force is
    this area times the wake's momentum flux per area, ``T A / (2 pi w^2)`` (fitted: 4.19e-3 +-
    0.18e-3, 64 % of a Crazyflie's four rotor discs)."""
    downwash_measured_width0_m: float = 0.0352
    """``measured``: the wake's Gaussian width extrapolated to the upper drone, ``w0`` [m]
    (fitted: 0.035 +- 0.004)."""
    downwash_measured_spread_m_per_m: float = 0.0439
    """``measured``: how fast the wake's width ``w = w0 + spread dz`` grows with depth [m/m]
    (fitted: 0.044 +- 0.013; a turbulent round jet's momentum-flux profile spreads by 0.056)."""
    downwash_measured_min_depth_m: float = 0.27
    """``measured``: the shallowest depth fitted [m]; above it the force on the axis is held at
    its value there while the width keeps narrowing towards ``w0``."""
    drag_xy_kg_per_rad: float = 9.1785e-7
    """Rotor drag per (rad/s of summed rotor speed) per (m/s of airspeed), body x and y
    [N / (rad/s) / (m/s) = kg/rad]; Forster 2015's identification of the Crazyflie 2.0."""
    drag_z_kg_per_rad: float = 10.311e-7
    """The same along body z [kg/rad]."""
    ground_effect_coeff: float = 11.36859
    """``gnd_eff_coeff``: each rotor's thrust grows by ``coeff (r_p / (4 h))^2`` of itself."""
    ground_z_m: float = 0.0
    """Height of the floor [m, world]."""

    @property
    def any(self) -> bool:
        return self.downwash or self.drag or self.ground_effect

    @property
    def ground_clip_m(self) -> float:
        """Upstream's ``GND_EFF_H_CLIP``: rotor heights below this count as this [m].

        ``0.25 r_p sqrt(15 MAX_RPM^2 kf coeff / MAX_THRUST)`` with ``MAX_THRUST = 4 kf
        MAX_RPM^2`` is ``0.25 r_p sqrt(15 coeff / 4)`` (3.78 cm for the Crazyflie): the
        height at which the gain reaches 4/15 of the rotor's thrust, its largest."""
        return 0.25 * self.prop_radius_m * math.sqrt(15.0 * self.ground_effect_coeff / 4.0)


@njit(cache=True)
def _inside_fraction(d, r_b, r_w):
    """The fraction of a disc of radius ``r_b`` that lies inside a disc of radius ``r_w`` whose
    centre is ``d`` away (the area of the two discs' lens over ``pi r_b^2``)."""
    if d >= r_b + r_w:
        return 0.0
    if d + r_b <= r_w:
        return 1.0
    if d <= abs(r_w - r_b):
        return 1.0 if r_w >= r_b else (r_w * r_w) / (r_b * r_b)
    c1 = min(1.0, max(-1.0, (d * d + r_b * r_b - r_w * r_w) / (2.0 * d * r_b)))
    c2 = min(1.0, max(-1.0, (d * d + r_w * r_w - r_b * r_b) / (2.0 * d * r_w)))
    k = (-d + r_b + r_w) * (d + r_b - r_w) * (d - r_b + r_w) * (d + r_b + r_w)
    lens = r_b * r_b * math.acos(c1) + r_w * r_w * math.acos(c2) - 0.5 * math.sqrt(max(k, 0.0))
    return min(1.0, max(0.0, lens / (math.pi * r_b * r_b)))


@njit(cache=True)
def _downwash(x_w, thrust_N, peak_N, slope, offset_m, r_p, cap_fraction, range_xy, wake_r, spread, out):
    n = x_w.shape[0]
    for i in range(n):
        fz = 0.0
        for j in range(n):
            dz = x_w[j, 2] - x_w[i, 2]
            if j == i or not dz > 0.0:
                continue
            dx = x_w[j, 0] - x_w[i, 0]
            dy = x_w[j, 1] - x_w[i, 1]
            dxy2 = dx * dx + dy * dy
            if not dxy2 < range_xy * range_xy:
                continue
            inside = _inside_fraction(math.sqrt(dxy2), wake_r, wake_r + spread * dz)
            if inside == 0.0:
                continue
            s = r_p / (4.0 * max(dz, 1e-6))  # finite: the cap binds long before 1 um
            alpha = peak_N * s * s
            beta = slope * dz + offset_m
            b2 = beta * beta
            if dxy2 == 0.0:
                e = 1.0
            elif b2 > 0.0:
                e = math.exp(-0.5 * dxy2 / b2)
            else:
                e = 0.0
            if e == 0.0:
                continue
            f = alpha * e
            cap = cap_fraction * max(thrust_N[j], 0.0) * inside
            if f > cap:
                f = cap
            fz -= f
        out[i, 0] = 0.0
        out[i, 1] = 0.0
        out[i, 2] = fz


@njit(cache=True)
def _downwash_measured(x_w, thrust_N, area_m2, w0_m, spread, min_dz_m, cap_fraction, range_xy, out):
    n = x_w.shape[0]
    for i in range(n):
        fz = 0.0
        for j in range(n):
            dz = x_w[j, 2] - x_w[i, 2]
            if j == i or not dz > 0.0:
                continue
            dx = x_w[j, 0] - x_w[i, 0]
            dy = x_w[j, 1] - x_w[i, 1]
            dxy2 = dx * dx + dy * dy
            if not dxy2 < range_xy * range_xy:
                continue
            t = max(thrust_N[j], 0.0)
            w = w0_m + spread * dz  # the profile's width at this depth
            w_peak = w0_m + spread * max(dz, min_dz_m)  # the axis value is held above the fitted range
            f = t * area_m2 / (2.0 * math.pi * w_peak * w_peak) * math.exp(-0.5 * dxy2 / (w * w))
            cap = cap_fraction * t
            if f > cap:
                f = cap
            fz -= f
        out[i, 0] = 0.0
        out[i, 1] = 0.0
        out[i, 2] = fz


def downwash_force_w(x_w: FloatArray, thrust_N: FloatArray, p: AeroParams) -> FloatArray:
    """Downwash on each drone from every drone above it: (n, 3) [N, world], straight down.

    Two models, :attr:`AeroParams.downwash_model`: ``"gym_pybullet"`` (the default, below) and
    ``"measured"`` (after it).

    ``x_w`` (n, 3) [m, world] are the centres of mass, ``thrust_N`` (n,) each drone's
    collective thrust. For a drone ``j`` above ``i`` (``dz = z_j - z_i > 0``, horizontal
    distance ``d``), upstream's model (``BaseAviary._downwash``, fitted by SiQi Zhou at
    UTIAS's Dynamic Systems Lab on Crazyflies)::

        F = alpha exp(-d^2 / (2 beta^2)),   alpha = c1 (r_p / (4 dz))^2,   beta = c2 dz + c3

    Fitted range: not published with the coefficients; upstream's own ``downwash.py``
    example flies the pair 0.5 m apart vertically. Where it departs from upstream:

    * **Bounded as dz -> 0.** ``alpha`` grows as ``1/dz^2`` (1.21 N, 4.6 Crazyflie
      weights, at 0.25 m; unbounded at contact). The force on a drone below is capped at
      ``downwash_cap_thrust_fraction`` times the collective thrust of the drone above: by
      momentum theory the rotor wake carries a momentum flux equal to that thrust, and a
      body that stops the whole wake feels at most that flux. The cap binds below
      ``dz = 0.54 m`` for two hovering Crazyflies, so close under another drone the lower
      one loses up to one weight of the upper drone (0.265 N).
    * **Only inside the wake.** Upstream's Gaussian keeps 7.5 % of ``alpha`` 0.25 m to the side
      as ``dz -> 0``, where ``alpha`` is unbounded: two drones side by side, one a millimetre
      higher, would push the lower one down by a whole weight. A wake is a jet below the rotors:
      its radius is the rotor discs' extent where it leaves the drone
      (``downwash_wake_radius_m``) and grows by ``downwash_wake_spread`` per metre below (a
      turbulent round jet's spreading rate), and the cap is scaled by the fraction of the lower
      drone's rotor discs (the same radius) inside that wake: no force on a drone whose rotors
      are outside it, the whole cap on one wholly inside. Upstream's value is unchanged wherever
      the lower drone is wholly inside the wake and below the cap (0.5 m under another, up to
      4.7 cm off the axis).
    * **Width.** ``beta`` changes sign at ``dz = -c3/c2 = 0.69 m``: upstream squares it (so
      the wake is 11 cm wide at contact, narrows to nothing at 0.69 m and widens again),
      and divides 0 by 0 on the axis at exactly 0.69 m. Kept as upstream, with the axis
      value there taken as its limit (``exp(0) = 1``), so no NaN.
    * **Direction.** Straight down in the world frame (the wake of a level drone above),
      where upstream applies it along the lower drone's body z; the two differ by the
      lower drone's tilt (at most 35 degrees here).

    Leaves out: the upper drone's tilt and thrust (the fit is at hover), the wake's travel
    time, and any torque (a drone half under a wake is rolled in reality).

    **measured**: a wake that widens with depth, fitted to Crazyflie flights. For a drone ``j``
    above ``i`` with collective thrust ``T``::

        F = T A / (2 pi w_p^2) exp(-d^2 / (2 w^2)),   w = w0 + s dz,   w_p = w0 + s max(dz, dz_min)

    a Gaussian whose width grows linearly with depth and whose peak falls as its area grows
    (``F`` integrated over the plane is ``T A`` at every depth: momentum conserved), scaled by
    the thrust above (a wake's momentum flux is the thrust that made it), zero for ``dz <= 0``,
    and capped at ``downwash_cap_thrust_fraction T`` (which never binds with the fitted values:
    0.30 T at most). ``A`` (:attr:`AeroParams.downwash_measured_area_m2`), ``w0`` and ``s`` are
    fitted (least squares, weighted by each bin's standard error plus 0.2 gf) to the residual
    vertical force on the lower of two small Crazyflie 2.1 (32 g) in the public flight logs of
    Shi et al., "Neural-Swarm2: Planning and Control of Heterogeneous Multirotor Swarms Using
    Learned Interactions", T-RO 2021 (Neural-Swarm, ICRA 2020), aerorobotics/neural-swarm,
    ``data/training/datacollection21_06_16_2020/swap_ss`` (11 flights) and ``swap_sss`` (8),
    and ``datacollection20_12_20_2019/swap_sss`` (1): drones 0.2-0.4 m apart vertically
    crossing under each other in 2-4 s. The force is the authors' own ``Fa`` (``learning/
    utils.py``: mass times the logged acceleration less the thrust of their PWM-and-voltage
    thrust map with its motor lag, ``fa_delay``), less each drone's median with no drone within
    0.4 m horizontally (its bias, -0.7 to -1.8 gf), on samples with exactly one drone above
    within 0.6 m and both higher than 0.3 m. Means [gf] (standard error 0.1-0.5 gf) in 5 cm
    depth bins, by horizontal offset ``d`` [m]:

    ======  ======  =====  =====  =====  =====  =====  =====  =====
    dz      d=0.01  0.03   0.05   0.07   0.09   0.11   0.13   0.15
    ======  ======  =====  =====  =====  =====  =====  =====  =====
    0.275   9.0     7.2    4.8    3.1    1.5    0.4    0.0    -0.4
    0.32    9.7     7.9    6.5    3.9    1.7    0.5    -0.4   -0.9
    0.375   7.7     6.4    5.4    3.5    1.9    0.9    0.3    0.0
    0.415   6.2     6.6    5.1    3.5    2.1    1.0    0.5    0.0
    ======  ======  =====  =====  =====  =====  =====  =====  =====

    Fitted range: ``dz`` 0.27-0.42 m (on the axis), ``d`` up to 0.15 m; RMS residual 0.49 gf
    (1.5 % of the weight), largest 1.2 gf. On the axis the fit gives 0.30 of the thrust above at
    0.27 m, 0.285 at 0.3 m, 0.24 at 0.4 m (9.6, 9.1 and 7.7 gf for 32 g), 0.20 at 0.5 m and 0.11
    at 1 m (upstream's: one weight, the cap, to 0.54 m; 0.29 at 1 m). Outside the range: deeper, the
    same law (a turbulent jet's, Bauersfeld et al., RA-L 2025, arXiv 2403.13321: a quadrotor's wake is a round jet
    from 2.5 drone diameters below it); shallower, the axis value is held at its 0.27 m value
    and the width narrows to ``w0`` at ``dz = 0``, so a drone beside another at its height (12
    cm apart) feels 0.09 % of the thrust. No sideways force: the logs show at most a 0.3 gf pull
    towards the axis 0.1-0.2 m off it (under 1 % of the weight) and no push outward. The
    flights were moving (0.1-0.5 m/s), so the profile is the wake as a drone crossing it feels
    it; the upper drone is a 32 g Crazyflie, and another drone's wake is scaled by its thrust."""
    x_w = np.ascontiguousarray(x_w, dtype=float)
    out = np.empty_like(x_w)
    if p.downwash_model == "measured":
        _downwash_measured(
            x_w,
            np.ascontiguousarray(thrust_N, dtype=float),
            p.downwash_measured_area_m2,
            p.downwash_measured_width0_m,
            p.downwash_measured_spread_m_per_m,
            p.downwash_measured_min_depth_m,
            p.downwash_cap_thrust_fraction,
            p.downwash_range_xy_m,
            out,
        )
        return out
    if p.downwash_model != "gym_pybullet":
        raise ValueError(f"downwash_model: {p.downwash_model!r} is neither 'gym_pybullet' nor 'measured'")
    _downwash(
        x_w,
        np.ascontiguousarray(thrust_N, dtype=float),
        p.downwash_peak_N,
        p.downwash_width_slope,
        p.downwash_width_offset_m,
        p.prop_radius_m,
        p.downwash_cap_thrust_fraction,
        p.downwash_range_xy_m,
        p.downwash_wake_radius_m,
        p.downwash_wake_spread,
        out,
    )
    return out


@njit(cache=True)
def _drag(R, v_rel_w, omega_sum, k_xy, k_z, out):
    for i in range(R.shape[0]):
        vb = np.empty(3)
        for a in range(3):  # R^T v
            vb[a] = R[i, 0, a] * v_rel_w[i, 0] + R[i, 1, a] * v_rel_w[i, 1] + R[i, 2, a] * v_rel_w[i, 2]
        w = omega_sum[i]
        fb0, fb1, fb2 = -k_xy * w * vb[0], -k_xy * w * vb[1], -k_z * w * vb[2]
        for a in range(3):
            out[i, a] = R[i, a, 0] * fb0 + R[i, a, 1] * fb1 + R[i, a, 2] * fb2


def drag_force_w(R: FloatArray, v_rel_w: FloatArray, omega_sum_rad_s: FloatArray, p: AeroParams) -> FloatArray:
    """Rotor drag (n, 3) [N, world]: ``F = -(sum_i omega_i) R K R^T v_rel``.

    ``R`` (n, 3, 3) body to world, ``v_rel_w`` (n, 3) [m/s, world] the velocity relative to
    the air (the drone's minus the wind's), ``omega_sum_rad_s`` (n,) the sum of the four
    rotor speeds [rad/s]; ``K = diag(k_xy, k_xy, k_z)`` in the body frame. Forster,
    *System Identification of the Crazyflie 2.0 Nano Quadrocopter*, ETH Zurich 2015,
    identified ``K`` in flight; upstream (``BaseAviary._drag``) multiplies ``K`` into
    the world-frame velocity before rotating, which equals this only when level; here
    ``K`` acts in the body frame, as identified. At hover (4 x 1516 rad/s) it is 5.6 mN
    per m/s (2.1 % of the weight).

    Fitted range: Forster's flights, at speeds up to about 1 m/s. Leaves out: the
    quadratic body drag that dominates at higher speeds, and the drag's moment."""
    R = np.ascontiguousarray(R, dtype=float)
    out = np.empty((R.shape[0], 3))
    _drag(
        R,
        np.ascontiguousarray(v_rel_w, dtype=float),
        np.ascontiguousarray(omega_sum_rad_s, dtype=float),
        p.drag_xy_kg_per_rad,
        p.drag_z_kg_per_rad,
        out,
    )
    return out


@njit(cache=True)
def _ground(x_w, R, f_N, rotor_xy_b, coeff, r_p, h_clip, ground_z, F_out, tau_out):
    for i in range(x_w.shape[0]):
        for a in range(3):
            F_out[i, a] = 0.0
            tau_out[i, a] = 0.0
        if not R[i, 2, 2] > 0.0:  # upstream: only while |roll| and |pitch| are below 90 degrees
            continue
        total = 0.0
        for j in range(f_N.shape[1]):
            px, py = rotor_xy_b[i, j, 0], rotor_xy_b[i, j, 1]
            h = x_w[i, 2] + R[i, 2, 0] * px + R[i, 2, 1] * py - ground_z
            if h < h_clip:
                h = h_clip
            s = r_p / (4.0 * h)
            g = max(f_N[i, j], 0.0) * coeff * s * s
            total += g
            tau_out[i, 0] += py * g  # r x (0, 0, g)
            tau_out[i, 1] -= px * g
        for a in range(3):
            F_out[i, a] = total * R[i, a, 2]


def ground_effect(
    x_w: FloatArray, R: FloatArray, f_N: FloatArray, rotor_xy_b: FloatArray, p: AeroParams
) -> tuple[FloatArray, FloatArray]:
    """Ground effect: (force (n, 3) [N, world], torque (n, 3) [N m, body]).

    Each rotor ``j`` of thrust ``f_j`` [N] at body position ``rotor_xy_b[i, j]`` (n, 4, 2)
    [m], at height ``h_j`` above the floor, pushes an extra ``f_j c (r_p / (4 h_j))^2``
    along body z (upstream's ``BaseAviary._groundEffect``, after the analytical model
    compared in Shi et al., "Neural Lander", ICRA 2019; ``h_j`` clipped below at
    :attr:`AeroParams.ground_clip_m`, so the gain is at most 4/15 of the thrust; off while
    upside down). Rotors at different heights (a tilted drone) give the torque.

    Fitted range: the coefficient is gym-pybullet-drones' (no range published); the
    ``(r/4h)^2`` form is Cheeseman and Bennett's (1955) image-rotor law, which holds for
    heights above about half a rotor radius. At 0.25 m (the filter's default floor) the
    gain is 0.6 % of the thrust; at the clip height it is 26.7 %."""
    x_w = np.ascontiguousarray(x_w, dtype=float)
    F = np.empty_like(x_w)
    tau = np.empty_like(x_w)
    _ground(
        x_w,
        np.ascontiguousarray(R, dtype=float),
        np.ascontiguousarray(f_N, dtype=float),
        np.ascontiguousarray(rotor_xy_b, dtype=float),
        p.ground_effect_coeff,
        p.prop_radius_m,
        p.ground_clip_m,
        p.ground_z_m,
        F,
        tau,
    )
    return F, tau
