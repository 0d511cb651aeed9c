"""Quadrotor model: parameters, mixer, rigid-body dynamics, thrust-vector model.

Frames: world is z up (``e3``), body is x forward, y left, z up along the thrust.
Quaternions are scalar-last, see :mod:`swarm.rotation`.

Rigid body (the paper's equation (1))::

    x' = v,   m v' = -m g e3 + T R e3,   J Omega' = tau - Omega x J Omega,   [T, tau] = B f
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from numba import njit

from swarm.errors import InputError
from swarm.rotation import E3, FloatArray, quat_derivative, quat_to_R, quat_to_R_into


class CommandLevel(StrEnum):
    """What an agent sends to its drone."""

    ROTORS = "rotors"
    """Four rotor thrusts ``f`` [N], applied by the world at physics rate."""
    ATTITUDE = "attitude"
    """Crazyflie commander setpoint (roll, pitch [rad], yaw rate [rad/s], thrust [N]);
    the filter then works on the thrust vector ``F`` [N, world]."""


class Layout(StrEnum):
    """Rotor arrangement seen from above, body x forward."""

    X = "x"
    """Crazyflie 2.1: rotors on the diagonals, M1 front-right, clockwise numbering."""
    PLUS = "+"
    """The paper's printed mixer: rotors on the body axes (+x, +y, -x, -y)."""


def check_finite(name: str, value: object, shape: tuple[int, ...] | None = None) -> FloatArray:
    """Return ``value`` as a float array, raising :class:`InputError` naming ``name``
    if it is not finite or not of ``shape``."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: not a number array ({exc})") from None
    if shape is not None and arr.shape != shape:
        raise InputError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: contains NaN or infinity")
    return arr


@njit(cache=True)
def all_finite(a):
    """True when every entry of a float array is finite (one compiled pass)."""
    for x in a.flat:
        if not math.isfinite(x):
            return False
    return True


Q_NORM2_MIN, Q_NORM2_MAX = 0.25, 2.25
"""A state's quaternion must have ``Q_NORM2_MIN < |q|^2 < Q_NORM2_MAX`` (else it is rejected)."""
Q_RENORM_TOL = 1e-12
"""A quaternion with ``||q|^2 - 1| >`` this is normalised before use."""


@njit(cache=True)
def state_check(x, v, q, Om):
    """0 if all finite, else 1 + index of the first bad field; and |q|^2."""
    for i, a in enumerate((x, v, q, Om)):
        for e in a:
            if not math.isfinite(e):
                return i + 1, 0.0
    return 0, q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]


@njit(cache=True)
def body_point_into(R, x, v, wx, wy, l, xv_b):  # noqa: E741
    """The body centre ``x + l R e3`` [m, world] (``l`` [m] above the centre of mass
    ``x``) and that point's velocity ``v + l R (Omega x e3)`` [m/s, world], with
    ``Omega x e3 = (wy, -wx, 0)`` [rad/s, body], into the rows of ``xv_b`` (2, 3)."""
    for i in range(3):
        xv_b[0, i] = x[i] + l * R[i, 2]
        xv_b[1, i] = v[i] + l * (R[i, 0] * wy - R[i, 1] * wx)


@njit(cache=True)
def body_centre(x, v, q, Om, l):  # noqa: E741
    """(x_b (3,) [m, world], v_b (3,) [m/s, world], yaw [rad]) of a state: its body centre
    and that point's velocity (:func:`body_point_into`) and the ZYX yaw of ``R``."""
    R = np.empty((3, 3))
    quat_to_R_into(q, R)
    xv_b = np.empty((2, 3))
    body_point_into(R, x, v, Om[0], Om[1], l, xv_b)
    return xv_b[0].copy(), xv_b[1].copy(), math.atan2(R[1, 0], R[0, 0])


@dataclass(frozen=True)
class QuadParams:
    """Physical parameters; defaults are the Crazyflie 2.1 of the paper's table."""

    mass_kg: float = 0.027
    g_mps2: float = 9.81
    Ixx_kgm2: float = 2.39e-5
    Iyy_kgm2: float = 2.39e-5
    Izz_kgm2: float = 3.23e-5
    kf: float = 3.16e-10
    """Thrust coefficient [N / rpm^2]."""
    km: float = 7.94e-12
    """Drag-torque coefficient [N m / rpm^2]; yaw torque per newton is ``km / kf``."""
    l_m: float = 0.014
    """Height of the body centre above the base (centre of mass) [m]; the barrier is
    taken at ``x + l R e3`` (``swarm.safety.barriers``)."""
    rotor_to_rotor_m: float = 0.130
    """Distance between two opposite rotors [m]; each rotor is half of it from the centre."""
    thrust_to_weight: float = 2.25
    """Sets the per-rotor limit ``f_max = thrust_to_weight * m g / 4`` (0.149 N default)."""
    layout: Layout = Layout.X
    body_radius_m: float = 0.07
    """Bounding-sphere radius of the airframe [m], added to every barrier radius."""
    keep_out_xy_m: float = 0.12
    keep_out_z_m: float = 0.30
    """The keep-out ellipsoid between this drone's centre and another's [m], across and up
    and down (downwash): Crazyswarm's between two Crazyflies (jpreiss/smoothener,
    examples/no_obstacles/main_no_obstacles.m: "robot-robot collision ellipsoid [0.12 0.12
    0.3]"). The filter's rows of other drones keep it, plus the margin, where it exceeds the
    bodies' sphere (``swarm.safety.barriers``, "Keep-out ellipsoid"); 0: none."""
    max_tilt_rad: float = math.radians(35.0)
    """Tilt limit of the attitude command level [rad]."""
    min_thrust_fraction: float = 0.1
    """Lowest collective thrust of the attitude level, as a fraction of ``m g``."""

    def __post_init__(self) -> None:
        positive = (
            "mass_kg",
            "g_mps2",
            "Ixx_kgm2",
            "Iyy_kgm2",
            "Izz_kgm2",
            "kf",
            "km",
            "rotor_to_rotor_m",
            "body_radius_m",
            "max_tilt_rad",
        )
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"QuadParams.{name}: must be a finite number > 0, got {v!r}")
        for name in ("l_m", "min_thrust_fraction", "keep_out_xy_m", "keep_out_z_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"QuadParams.{name}: must be a finite number >= 0, got {v!r}")
        if not (math.isfinite(self.thrust_to_weight) and self.thrust_to_weight > 1.0):
            raise InputError(f"QuadParams.thrust_to_weight: must be > 1 to hover, got {self.thrust_to_weight!r}")
        if self.max_tilt_rad >= math.pi / 2:
            raise InputError(f"QuadParams.max_tilt_rad: must be < pi/2, got {self.max_tilt_rad!r}")
        if self.min_thrust_fraction >= self.thrust_to_weight * math.cos(self.max_tilt_rad):
            raise InputError("QuadParams.min_thrust_fraction: above the largest usable thrust")
        object.__setattr__(self, "layout", Layout(self.layout))

    @property
    def weight_N(self) -> float:
        return self.mass_kg * self.g_mps2

    @property
    def f_max_N(self) -> float:
        """Per-rotor thrust limit [N]."""
        return self.thrust_to_weight * self.weight_N / 4.0

    @property
    def arm_m(self) -> float:
        """Rotor distance from the body z axis [m]."""
        return self.rotor_to_rotor_m / 2.0

    @property
    def c_tau_m(self) -> float:
        """Yaw torque per newton of rotor thrust [N m / N]."""
        return self.km / self.kf


def rotor_geometry(params: QuadParams) -> tuple[FloatArray, FloatArray]:
    """Rotor positions (4, 2) [m, body xy] and spin signs (4,) (+1: reaction torque +z)."""
    a = params.arm_m
    if params.layout is Layout.X:
        d = a / math.sqrt(2.0)
        # Crazyflie: M1 front-right, M2 back-right, M3 back-left, M4 front-left;
        # M1 and M3 spin clockwise (seen from above), so their reaction torque is +z.
        pos = np.array([[d, -d], [-d, -d], [-d, d], [d, d]])
        spin = np.array([1.0, -1.0, 1.0, -1.0])
    else:
        pos = np.array([[a, 0.0], [0.0, a], [-a, 0.0], [0.0, -a]])
        spin = np.array([1.0, -1.0, 1.0, -1.0])
    return pos, spin


def mixer(params: QuadParams) -> FloatArray:
    """The (4, 4) mixer ``B`` with ``[T, tau_x, tau_y, tau_z] = B f`` (N, N m)."""
    pos, spin = rotor_geometry(params)
    return np.vstack([np.ones(4), pos[:, 1], -pos[:, 0], spin * params.c_tau_m])


@dataclass(frozen=True)
class QuadModel:
    """Derived constant matrices of one airframe (built once, used every tick)."""

    params: QuadParams = field(default_factory=QuadParams)

    def __post_init__(self) -> None:
        B = mixer(self.params)
        J = np.diag([self.params.Ixx_kgm2, self.params.Iyy_kgm2, self.params.Izz_kgm2])
        object.__setattr__(self, "B", B)
        object.__setattr__(self, "B_inv", np.linalg.inv(B))
        object.__setattr__(self, "J", J)
        object.__setattr__(self, "J_inv", np.linalg.inv(J))

    B: FloatArray = field(init=False, repr=False)
    """Mixer (4, 4)."""
    B_inv: FloatArray = field(init=False, repr=False)
    J: FloatArray = field(init=False, repr=False)
    """Inertia (3, 3) [kg m^2, body]."""
    J_inv: FloatArray = field(init=False, repr=False)


@dataclass
class QuadState:
    """Rigid-body state. ``q`` is scalar-last (x, y, z, w), body to world."""

    x_w: FloatArray  # (3,) m, world, centre of mass
    v_w: FloatArray  # (3,) m/s, world
    q: FloatArray  # (4,) unit quaternion, scalar-last
    Omega_b: FloatArray  # (3,) rad/s, body

    @staticmethod
    def hover(x_w: object = (0.0, 0.0, 1.0)) -> QuadState:
        return QuadState(np.asarray(x_w, dtype=float).copy(), np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3))

    def validated(self, name: str = "state") -> QuadState:
        """Return a checked state with a unit quaternion; raises :class:`InputError`
        naming the field on NaN, infinity, a bad shape or a degenerate quaternion."""
        x, v, q, Om = self.x_w, self.v_w, self.q, self.Omega_b
        try:
            bad, nq2 = state_check(x, v, q, Om)
            ok = x.shape == (3,) and v.shape == (3,) and q.shape == (4,) and Om.shape == (3,)
        except Exception:  # wrong types: let check_finite name the field
            bad, nq2, ok = -1, 0.0, False
        if bad != 0 or not ok:
            fields = (("x_w", x, 3), ("v_w", v, 3), ("q", q, 4), ("Omega_b", Om, 3))
            x, v, q, Om = (check_finite(f"{name}.{f}", a, (k,)) for f, a, k in fields)
            nq2 = float(q @ q)
        if not Q_NORM2_MIN < nq2 < Q_NORM2_MAX:
            raise InputError(f"{name}.q: quaternion norm {math.sqrt(nq2):.3g} is far from 1")
        if abs(nq2 - 1.0) > Q_RENORM_TOL:
            q = q / math.sqrt(nq2)
        return QuadState(x, v, q, Om)

    def copy(self) -> QuadState:
        return QuadState(self.x_w.copy(), self.v_w.copy(), self.q.copy(), self.Omega_b.copy())


def rigid_body_accel(
    model: QuadModel,
    state: QuadState,
    f: FloatArray,
    force_w: FloatArray | None = None,
    torque_b: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Linear acceleration (3,) [m/s^2, world] and angular acceleration (3,) [rad/s^2,
    body] for rotor thrusts ``f`` (4,) [N], plus an extra force ``force_w`` (3,) [N,
    world] at the centre of mass and torque ``torque_b`` (3,) [N m, body] if given
    (``swarm.realism.plant``)."""
    p = model.params
    wrench = model.B @ f
    R = quat_to_R(state.q)
    v_dot = -p.g_mps2 * E3 + (wrench[0] / p.mass_kg) * (R @ E3)
    if force_w is not None:
        v_dot = v_dot + force_w / p.mass_kg
    Om = state.Omega_b
    tau = wrench[1:] if torque_b is None else wrench[1:] + torque_b
    Om_dot = model.J_inv @ (tau - np.cross(Om, model.J @ Om))
    return v_dot, Om_dot


def drift_and_input(model: QuadModel, state: QuadState) -> tuple[FloatArray, FloatArray]:
    """The control-affine form ``xi' = f(x) + g(x) f_rotors`` on the 12-dim tangent
    ``xi = (x [m], v [m/s], attitude [rad, body], Omega [rad/s, body])``.

    Returns ``f`` (12,) and ``g`` (12, 4). The attitude rate is ``Omega`` itself
    (the quaternion follows ``q' = q (x) (0, Omega) / 2``)."""
    p = model.params
    R = quat_to_R(state.q)
    Om = state.Omega_b
    f = np.zeros(12)
    f[0:3] = state.v_w
    f[3:6] = -p.g_mps2 * E3
    f[6:9] = Om
    f[9:12] = -model.J_inv @ np.cross(Om, model.J @ Om)
    g = np.zeros((12, 4))
    g[3:6] = np.outer(R @ E3, model.B[0]) / p.mass_kg
    g[9:12] = model.J_inv @ model.B[1:]
    return f, g


def step_rk4(
    model: QuadModel,
    state: QuadState,
    f_rotor: FloatArray,
    dt_s: float,
    force_w: FloatArray | None = None,
    torque_b: FloatArray | None = None,
) -> QuadState:
    """One RK4 step of the rigid body with rotor thrusts (and the extra force [N, world]
    and torque [N m, body] of :func:`rigid_body_accel`, if given) held constant over ``dt_s``."""

    def deriv(s: QuadState) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        v_dot, Om_dot = rigid_body_accel(model, s, f_rotor, force_w, torque_b)
        return s.v_w, v_dot, quat_derivative(s.q, s.Omega_b), Om_dot

    def add(s: QuadState, k: tuple[FloatArray, ...], h: float) -> QuadState:
        return QuadState(s.x_w + h * k[0], s.v_w + h * k[1], s.q + h * k[2], s.Omega_b + h * k[3])

    k1 = deriv(state)
    k2 = deriv(add(state, k1, dt_s / 2))
    k3 = deriv(add(state, k2, dt_s / 2))
    k4 = deriv(add(state, k3, dt_s))
    out = QuadState(
        *(
            a + dt_s / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4)
            for a, b1, b2, b3, b4 in zip((state.x_w, state.v_w, state.q, state.Omega_b), k1, k2, k3, k4, strict=True)
        )
    )
    out.q = out.q / np.linalg.norm(out.q)
    return out


# --- thrust-vector model (attitude command level) ---------------------------------


@dataclass(frozen=True)
class LinearInputSet:
    """Input set ``lb <= u <= ub`` and ``C u <= d`` (C may have zero rows)."""

    lb: FloatArray
    ub: FloatArray
    C: FloatArray
    d: FloatArray
    _mid: FloatArray = field(init=False, repr=False)
    _half: FloatArray = field(init=False, repr=False)

    def violation(self, u: FloatArray) -> float:
        """Largest violation of any bound or row (0 when inside)."""
        v = float(np.max(np.abs(u - self._mid) - self._half))
        if self.d.size:
            v = max(v, float(np.max(self.C @ u - self.d)))
        return max(v, 0.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_mid", (self.lb + self.ub) / 2.0)
        object.__setattr__(self, "_half", (self.ub - self.lb) / 2.0)

    def contains(self, u: FloatArray, tol: float = 0.0) -> bool:
        return self.violation(u) <= tol


def rotor_input_set(params: QuadParams) -> LinearInputSet:
    """``0 <= f_i <= f_max`` [N]."""
    return LinearInputSet(np.zeros(4), np.full(4, params.f_max_N), np.zeros((0, 4)), np.zeros(0))


def thrust_vector_input_set(
    params: QuadParams, facets: int = 8, accel_limit_mps2: float | None = None
) -> LinearInputSet:
    """Polyhedral inner approximation of the attitude level's input set for ``F`` [N,
    world]: ``T_min <= F_z <= T_max cos(tilt)`` and ``|F_xy| <= tan(tilt) F_z`` as
    ``facets`` half-planes inscribed in the tilt cone. Inside it, ``|F| <= T_max``. With
    ``accel_limit_mps2`` ``a`` also ``|F_z - m g| <= m a / sqrt 2`` and ``|F_xy| <= m a /
    sqrt 2`` (``facets`` more half-planes, inscribed), so the acceleration beyond gravity,
    ``F / m - g e3``, is at most ``a`` long."""
    t_max = 4.0 * params.f_max_N
    tan_t = math.tan(params.max_tilt_rad)
    fz_hi = t_max * math.cos(params.max_tilt_rad)
    fz_lo = params.min_thrust_fraction * params.weight_N
    k = np.arange(facets) * 2.0 * math.pi / facets
    inscribed = tan_t * math.cos(math.pi / facets)
    C = np.column_stack([np.cos(k), np.sin(k), np.full(facets, -inscribed)])
    d = np.zeros(facets)
    lim = tan_t * fz_hi
    if accel_limit_mps2 is not None:
        if not (math.isfinite(accel_limit_mps2) and accel_limit_mps2 > 0.0):
            raise InputError(
                f"thrust_vector_input_set: accel_limit_mps2 must be finite and > 0, got {accel_limit_mps2!r}"
            )
        f_a = params.mass_kg * accel_limit_mps2 / math.sqrt(2.0)  # N: each of |F_xy| and |F_z - m g|
        fz_lo, fz_hi = max(fz_lo, params.weight_N - f_a), min(fz_hi, params.weight_N + f_a)
        C = np.vstack([C, np.column_stack([np.cos(k), np.sin(k), np.zeros(facets)])])
        d = np.append(d, np.full(facets, f_a * math.cos(math.pi / facets)))
        lim = min(lim, f_a)
    return LinearInputSet(np.array([-lim, -lim, fz_lo]), np.array([lim, lim, fz_hi]), C, d)


def thrust_vector_accel(params: QuadParams, F_w: FloatArray) -> FloatArray:
    """``x'' = -g e3 + F / m`` [m/s^2, world] of the thrust-vector model."""
    return -params.g_mps2 * E3 + F_w / params.mass_kg


@njit(cache=True)
def thrust_vector_to_setpoint(F_w, yaw_rad):
    """Roll, pitch [rad] (ZYX, at the given yaw) and collective thrust [N] that point the
    body z axis along ``F_w`` (3,) [N, world]; the inverse of :func:`setpoint_to_thrust_vector`."""
    fx, fy, fz = F_w[0], F_w[1], F_w[2]
    thrust = math.sqrt(fx * fx + fy * fy + fz * fz)
    if thrust < 1e-9:
        return 0.0, 0.0, 0.0
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    # rotate into the yaw frame: z_b = F / |F| = Rz(yaw) Ry(pitch) Rx(roll) e3
    zx = (cy * fx + sy * fy) / thrust
    zy = (-sy * fx + cy * fy) / thrust
    zz = fz / thrust
    pitch = math.atan2(zx, zz)
    roll = math.atan2(-zy, math.hypot(zx, zz))
    return roll, pitch, thrust


def setpoint_to_thrust_vector(roll: float, pitch: float, yaw: float, thrust_N: float) -> FloatArray:
    """Thrust vector [N, world] of a body attitude given by ZYX angles and a collective."""
    from swarm.rotation import euler_to_quat

    return thrust_N * (quat_to_R(euler_to_quat(roll, pitch, yaw)) @ E3)
