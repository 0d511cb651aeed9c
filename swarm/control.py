"""Reference control: PD tracking of a path at a constant target speed, a geometric SO(3)
attitude controller (Lee et al. 2010) and Crazyflie commander setpoints.

The tracker outputs a desired thrust vector ``F_ref`` [N, world]. At the attitude
command level that is the filter's ``u_ref``; at the rotor level the attitude controller
turns it into rotor thrusts ``f_ref`` [N]. The same attitude controller, fed with a
commander setpoint, emulates the Crazyflie's onboard controller in the world process.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from swarm.errors import InputError
from swarm.model import QuadModel, QuadState, check_finite, thrust_vector_to_setpoint
from swarm.rotation import E3, FloatArray, R_to_euler, quat_to_R, quat_to_R_into, vee


@dataclass(frozen=True)
class TrackingGains:
    """Outer-loop gains of the path tracker."""

    kp_per_s: float = 1.5
    """Position error to velocity command [1/s] (cross-track and final approach)."""
    kd_per_s: float = 3.0
    """Velocity error to acceleration command [1/s]."""
    max_horizontal_accel_mps2: float = 4.0
    max_vertical_accel_mps2: float = 3.0

    def __post_init__(self) -> None:
        for name in ("kp_per_s", "kd_per_s", "max_horizontal_accel_mps2", "max_vertical_accel_mps2"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"TrackingGains.{name}: must be a finite number > 0, got {v!r}")


TRACKING = np.dtype(
    [
        ("kp", "f8"),  # 1/s: position gain (cross-track, and the taper near the end)
        ("kd", "f8"),  # 1/s: velocity gain
        ("a_h", "f8"),  # m/s^2: largest horizontal acceleration
        ("a_v", "f8"),  # m/s^2: largest vertical acceleration
    ],
    align=True,
)
""":class:`TrackingGains` as the tracker's compiled kernels take them, a (1,) structured array."""


class PathTracker:
    """PD tracking of a polyline at a constant target speed.

    The commanded velocity is the target speed along the current segment (tapering as
    ``kp * remaining path length`` near the end) plus ``kp`` times the cross-track error;
    the commanded acceleration is ``kd`` times the velocity error, clipped. The segment
    index only moves forward, so a detour around an obstacle does not skip or repeat.
    """

    def __init__(self, waypoints_w: object, speed_mps: float, gains: TrackingGains | None = None) -> None:
        W = check_finite("waypoints_w", waypoints_w)
        if W.ndim != 2 or W.shape[1] != 3 or W.shape[0] < 1:
            raise InputError(f"waypoints_w: expected shape (k >= 1, 3), got {W.shape}")
        if not (math.isfinite(speed_mps) and speed_mps > 0):
            raise InputError(f"speed_mps: must be a finite number > 0, got {speed_mps!r}")
        if W.shape[0] == 1:
            W = np.vstack([W, W])
        self.W = W
        self.speed_mps = float(speed_mps)
        self.gains = gains or TrackingGains()
        seg_len = np.linalg.norm(np.diff(W, axis=0), axis=1)
        tail = np.concatenate([np.cumsum(seg_len[::-1])[::-1][1:], [0.0]])  # m of path after each segment
        # per segment (k-1, 3): its length [m], the path after it [m], the speed [m/s] at its end
        self._seg = np.column_stack([seg_len, tail, corner_speeds(W, self.speed_mps)])
        g = self.gains
        self._gains = np.zeros(1, dtype=TRACKING)  # the gains as the compiled kernels read them
        self._gains[0] = (g.kp_per_s, g.kd_per_s, g.max_horizontal_accel_mps2, g.max_vertical_accel_mps2)
        self.segment = 0

    @property
    def goal_w(self) -> FloatArray:
        return self.W[-1]

    def reference(self, x_w: FloatArray) -> tuple[FloatArray, FloatArray, float]:
        """Closest path point [m, world], path tangent, remaining path length [m]."""
        self.segment, c, tangent, remaining = _path_point(self.W, self._seg, self.segment, np.asarray(x_w, dtype=float))
        return c, tangent, remaining

    def desired_velocity(self, x_w: FloatArray) -> FloatArray:
        """Commanded velocity [m/s, world]: along the path plus cross-track correction."""
        self.segment, v_des = _desired_velocity(
            self.W, self._seg, self.segment, np.asarray(x_w, dtype=float), self.speed_mps, self._gains
        )
        return v_des

    def desired_accel(self, x_w: FloatArray, v_w: FloatArray, v_des_w: FloatArray | None = None) -> FloatArray:
        """Commanded acceleration [m/s^2, world] (without gravity compensation) towards the
        commanded velocity ``v_des_w`` [m/s, world] (default: :meth:`desired_velocity`)."""
        v_des = self.desired_velocity(x_w) if v_des_w is None else np.asarray(v_des_w, dtype=float)
        return _desired_accel(v_des, np.asarray(v_w, dtype=float), self._gains)

    def thrust_vector(
        self, model: QuadModel, x_w: FloatArray, v_w: FloatArray, v_des_w: FloatArray | None = None
    ) -> FloatArray:
        """Desired thrust vector ``F_ref = m (a_des + g e3)`` [N, world]; ``v_des_w`` as in
        :meth:`desired_accel`. Without ``v_des_w``, one compiled call does the whole tracker."""
        p = model.params
        if v_des_w is None:
            self.segment, F = _tracker_thrust(
                self.W,
                self._seg,
                self.segment,
                np.asarray(x_w, dtype=float),
                np.asarray(v_w, dtype=float),
                self.speed_mps,
                self._gains,
                p.mass_kg,
                p.g_mps2,
            )
            return F
        a = self.desired_accel(x_w, v_w, v_des_w)
        a[2] += p.g_mps2
        return p.mass_kg * a


CORNER_SPEED_MIN = 0.2
"""The slowest a tracker takes a corner, as a fraction of its target speed."""
SKIP_AHEAD_M = 1.0
"""A tracker moves on to a later segment that starts within this much path [m] ahead of
its closest point when that segment is nearer: an agent pushed past a replanned path's
first short legs does not fly back to them."""


def corner_speeds(W: FloatArray, speed_mps: float) -> FloatArray:
    """(k-1,) the speed [m/s] a tracker may have at the end of each segment of the path
    ``W`` (k, 3): ``speed cos^2(theta / 2)`` for a turn by ``theta`` there (the full speed
    on a straight, half at a right angle, at least ``CORNER_SPEED_MIN`` of it), 0 at the
    path's end. A straight path (two points) is unaffected: its only end is the goal."""
    d = np.diff(W, axis=0)
    n = np.linalg.norm(d, axis=1, keepdims=True)
    u = np.divide(d, n, out=np.zeros_like(d), where=n > 1e-9)
    cos = np.sum(u[:-1] * u[1:], axis=1)
    out = speed_mps * np.maximum(CORNER_SPEED_MIN, 0.5 * (1.0 + cos))
    return np.append(out, 0.0)


@njit(cache=True)
def _path_point(W, seg, segment, x):
    """(segment, closest path point (3,) [m, world], tangent (3,), remaining path [m]) of
    :class:`PathTracker`, starting the search at ``segment`` (it only moves forward);
    ``seg`` (k-1, 3): each segment's length, the path after it and its end speed."""
    seg_len, tail = seg[:, 0], seg[:, 1]
    last = seg_len.shape[0] - 1
    c = np.empty(3)
    tangent = np.zeros(3)
    while True:
        i = segment
        L = seg_len[i]
        t = _along(W, L, i, x)
        if t >= 1.0 and i < last:
            segment += 1
            continue
        # a later segment that starts within SKIP_AHEAD_M of path ahead and lies nearer
        best = _dist2_to(W, i, t, x)
        ahead = (1.0 - t) * L
        k = i + 1
        while k <= last and ahead <= SKIP_AHEAD_M:
            Lk = seg_len[k]
            tk = _along(W, Lk, k, x)
            dk = _dist2_to(W, k, tk, x)
            if dk < best:
                best, i, t, L, segment = dk, k, tk, Lk, k
            ahead += Lk
            k += 1
        for j in range(3):
            d = W[i + 1, j] - W[i, j]
            c[j] = W[i, j] + t * d
            if L > 1e-9:
                tangent[j] = d / L
        return segment, c, tangent, (1.0 - t) * L + tail[i]


@njit(cache=True)
def _along(W, L, i, x):
    """Where along segment ``i`` of ``W`` (length ``L`` [m]) the point nearest ``x`` lies,
    from 0 at its start to 1 at its end (1 for a segment of no length)."""
    if L <= 1e-9:
        return 1.0
    t = 0.0
    for j in range(3):
        t += (x[j] - W[i, j]) * (W[i + 1, j] - W[i, j])
    return min(max(t / (L * L), 0.0), 1.0)


@njit(cache=True)
def _dist2_to(W, i, t, x):
    """Squared distance [m^2] from ``x`` to the point ``t`` (0 to 1) along segment ``i`` of ``W``."""
    out = 0.0
    for j in range(3):
        d = W[i, j] + t * (W[i + 1, j] - W[i, j]) - x[j]
        out += d * d
    return out


@njit(cache=True)
def _desired_velocity(W, seg, segment, x, speed, gains):
    """(segment, v_des (3,) [m/s, world]): the target speed along the path (tapering as
    ``kp * remaining`` near the end, and as ``corner + kp * d`` at ``d`` [m] before a
    corner: :func:`corner_speeds`) plus ``kp`` times the cross-track error; ``gains`` a
    (1,) :data:`TRACKING` array. An agent carried back behind a leg it had reached (backing
    out of a passage, pushed back) corrects only across it: ``kp`` times its distance back
    along the path would add to the target speed (an agent that backed out 1.2 m asked for
    2.6 m/s at 0.8)."""
    segment, c, tangent, remaining = _path_point(W, seg, segment, x)
    kp = gains[0].kp
    to_end = remaining - seg[segment, 1]  # m to the current segment's end
    s = min(speed, kp * remaining, seg[segment, 2] + kp * to_end)
    back = 0.0  # m: how far behind the current leg's start, along it
    if segment > 0:
        for j in range(3):
            back += (c[j] - x[j]) * tangent[j]
        back = max(back, 0.0)
    v_des = np.empty(3)
    for j in range(3):
        v_des[j] = s * tangent[j] + kp * (c[j] - x[j] - back * tangent[j])
    return segment, v_des


@njit(cache=True)
def _desired_accel(v_des, v, gains):
    """``kd (v_des - v)`` [m/s^2, world], horizontal part clipped to its norm limit and
    vertical part to its limit (``gains`` a (1,) :data:`TRACKING` array)."""
    g = gains[0]
    kd, a_h, a_v = g.kd, g.a_h, g.a_v
    a = np.empty(3)
    for j in range(3):
        a[j] = kd * (v_des[j] - v[j])
    h = math.hypot(a[0], a[1])
    if h > a_h:
        a[0] *= a_h / h
        a[1] *= a_h / h
    a[2] = min(max(a[2], -a_v), a_v)
    return a


@njit(cache=True)
def _tracker_thrust(W, seg, segment, x, v, speed, gains, mass, g):
    """(segment, F_ref (3,) [N, world]) of :meth:`PathTracker.thrust_vector` in one call."""
    segment, v_des = _desired_velocity(W, seg, segment, x, speed, gains)
    a = _desired_accel(v_des, v, gains)
    a[2] += g
    for j in range(3):
        a[j] *= mass
    return segment, a


FOLLOW_FRACTION = 0.5
"""An agent ahead flying along this agent's commanded velocity at least this fraction of its
speed is followed, not turned from, by the right-hand tie-break."""


def right_hand_bias(
    x_w: FloatArray,
    heading_w: FloatArray,
    others_w: FloatArray,
    trigger_m: float,
    speed_mps: float,
    cruise_mps: float | None = None,
    others_v_w: FloatArray | None = None,
) -> FloatArray:
    """The right-hand rule, a deadlock tie-break [m/s, world].

    For every other agent ``others_w`` (k, 3) [m] closer than ``trigger_m`` and in front
    (positive along ``heading_w``, the commanded velocity), add a horizontal velocity to
    the right of the heading, ``heading x e3`` normalised, weighted ``1 - d / trigger_m``;
    the sum is capped at ``speed_mps``. With ``cruise_mps`` (the agent's target speed
    [m/s]) it is scaled by ``|heading| / cruise_mps`` (at most 1), so it fades out as the
    tracker slows down to the goal: an agent that has arrived is not pushed around its goal
    by its neighbours there. With ``others_v_w`` (k, 3) [m/s, world], the others'
    velocities, an agent in front flying this one's way (along ``heading_w`` at least
    :data:`FOLLOW_FRACTION` of its speed) does not count: it is followed, as a queue into a
    corridor's lane is, where turning right from the agent ahead pushed the followers out of
    the queue and into the wall beside the mouth. Every agent turning right is consistent:
    two agents head-on pass left shoulder to left shoulder, and a symmetric swap turns into a
    roundabout instead of a stall. It only changes the reference; the filter still
    guarantees safety (docs/design.md, "The barrier math").
    """
    out = np.zeros(3)
    hx, hy = float(heading_w[0]), float(heading_w[1])
    n = math.hypot(hx, hy)
    if n < 1e-9 or len(others_w) == 0:
        return out
    right = np.array([hy / n, -hx / n, 0.0])  # heading x e3
    d_w = others_w - x_w
    dist = np.linalg.norm(d_w, axis=1)
    ahead = (d_w[:, 0] * hx + d_w[:, 1] * hy > 0) & (dist < trigger_m)
    if others_v_w is not None:  # followed, not turned from: the agents ahead flying my way
        ahead &= (others_v_w[:, 0] * hx + others_v_w[:, 1] * hy) < FOLLOW_FRACTION * n * n
    weight = min(float(np.sum(1.0 - dist[ahead] / trigger_m)), 1.0)
    if cruise_mps is not None and cruise_mps > 0:
        weight *= min(1.0, n / cruise_mps)
    return right * (speed_mps * weight)


def reference_thrust(
    model: QuadModel,
    tracker: PathTracker,
    x_w: FloatArray,
    v_w: FloatArray,
    x_b_w: FloatArray,
    others_w: FloatArray,
    tiebreak: tuple[float, float] | None,
    others_v_w: FloatArray | None = None,
) -> FloatArray:
    """An agent's reference thrust vector [N, world]: the tracker's, with the right-hand
    tie-break (``tiebreak`` = (trigger [m], speed [m/s]); None: none) turning its
    commanded velocity (:func:`turned`) for the other agents' body centres ``others_w``
    (k, 3) [m] seen from the body centre ``x_b_w`` [m], moving at ``others_v_w`` (k, 3)
    [m/s] (None: not known, every agent in front counts)."""
    if tiebreak is None:
        return tracker.thrust_vector(model, x_w, v_w)  # (the whole tracker in one call)
    v_des = tracker.desired_velocity(x_w)
    bias = right_hand_bias(x_b_w, v_des, others_w, tiebreak[0], tiebreak[1], tracker.speed_mps, others_v_w)
    return tracker.thrust_vector(model, x_w, v_w, turned(v_des, bias))


def turned(v_w: FloatArray, bias_w: FloatArray) -> FloatArray:
    """The commanded velocity ``v_w`` [m/s, world] with the tie-break's ``bias_w`` [m/s,
    world] added, scaled back to ``|v_w|`` where the sum is faster: the tie-break turns the
    commanded velocity and never speeds it up, so an agent's target speed stays its top
    reference speed (as ORCA's maximum speed is), and times to goal compare fairly
    (docs/design.md, "The barrier math")."""
    out = v_w + bias_w
    speed, faster = float(np.linalg.norm(v_w)), float(np.linalg.norm(out))
    if faster > speed:
        out *= speed / faster
    return out


@dataclass(frozen=True)
class AttitudeGains:
    """Natural frequency [rad/s] and damping of the attitude loop, per axis."""

    wn_rp_radps: float = 20.0
    wn_yaw_radps: float = 6.0
    zeta: float = 0.9


class AttitudeController:
    """Geometric SO(3) attitude control: ``tau = -kR eR - kOm eOm + Omega x J Omega``,
    rotor thrusts from the inverse mixer, clipped to ``[0, f_max]``."""

    def __init__(self, model: QuadModel, gains: AttitudeGains | None = None) -> None:
        self.model = model
        g = gains or AttitudeGains()
        J = np.diag(model.J)
        wn = np.array([g.wn_rp_radps, g.wn_rp_radps, g.wn_yaw_radps])
        self.kR = J * wn**2
        self.kOm = J * 2.0 * g.zeta * wn
        self.f_max = model.params.f_max_N

    def rotor_thrusts(self, state: QuadState, R_des: FloatArray, thrust_N: float) -> FloatArray:
        """Rotor thrusts (4,) [N] that track ``R_des`` (body to world) with collective
        ``thrust_N`` (clipped to the rotor limits)."""
        R = quat_to_R(state.q)
        eR = vee(R_des.T @ R - R.T @ R_des) / 2.0
        Om = state.Omega_b
        tau = -self.kR * eR - self.kOm * Om + np.cross(Om, self.model.J @ Om)
        f = self.model.B_inv @ np.concatenate([[thrust_N], tau])
        return np.clip(f, 0.0, self.f_max)

    def from_thrust_vector(self, state: QuadState, F_w: FloatArray, yaw_des_rad: float = 0.0) -> FloatArray:
        """Rotor thrusts for a desired thrust vector ``F_w`` [N, world] and yaw [rad]."""
        R = quat_to_R(state.q)
        n = float(np.linalg.norm(F_w))
        b3 = F_w / n if n > 1e-9 else E3
        b1c = np.array([math.cos(yaw_des_rad), math.sin(yaw_des_rad), 0.0])
        b2 = np.cross(b3, b1c)
        nb2 = np.linalg.norm(b2)
        b2 = b2 / nb2 if nb2 > 1e-9 else R[:, 1]
        R_des = np.column_stack([np.cross(b2, b3), b2, b3])
        return self.rotor_thrusts(state, R_des, float(F_w @ R[:, 2]))


@dataclass(frozen=True)
class AttitudeSetpoint:
    """A Crazyflie commander setpoint, as cflib's ``send_setpoint`` carries it."""

    roll_rad: float
    pitch_rad: float
    yaw_rate_radps: float
    thrust_N: float


YAW_GAIN_PER_S = 2.0
"""Yaw-rate setpoint per radian of yaw error [1/s] of :func:`setpoint_from_thrust_vector`."""


def setpoint_from_thrust_vector(
    F_w: FloatArray, yaw_rad: float, yaw_des_rad: float = 0.0, k_yaw_per_s: float = YAW_GAIN_PER_S
) -> AttitudeSetpoint:
    """Setpoint that points the body z axis along ``F_w`` at the current yaw and turns
    toward ``yaw_des_rad`` at ``k_yaw_per_s`` times the (wrapped) yaw error."""
    return AttitudeSetpoint(*setpoint_vector(np.asarray(F_w, dtype=float), yaw_rad, yaw_des_rad, k_yaw_per_s).tolist())


@njit(cache=True)
def setpoint_vector(F_w, yaw_rad, yaw_des_rad, k_yaw_per_s):
    """:func:`setpoint_from_thrust_vector` as an array: (roll [rad], pitch [rad], yaw
    rate [rad/s], thrust [N]), the order a command at the attitude level carries."""
    roll, pitch, thrust = thrust_vector_to_setpoint(F_w, yaw_rad)
    err = (yaw_des_rad - yaw_rad + math.pi) % (2 * math.pi) - math.pi
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = roll, pitch, k_yaw_per_s * err, thrust
    return out


@njit(cache=True)
def onboard_rotor_thrusts(q, Omega_b, roll, pitch, yaw, thrust, kR, kOm, J, B_inv, f_max):
    """The geometric attitude law of :class:`AttitudeController` for ``n`` drones at once,
    tracking ``R_des = Rz(yaw) Ry(pitch) Rx(roll)`` with collective ``thrust`` [N].

    ``q`` (n, 4) scalar-last, ``Omega_b`` (n, 3) rad/s body; per-drone gains ``kR``,
    ``kOm``, inertia diagonal ``J`` (n, 3), inverse mixers ``B_inv`` (n, 4, 4), limits
    ``f_max`` (n,). Returns rotor thrusts (n, 4) [N] clipped to ``[0, f_max]``."""
    n = q.shape[0]
    out = np.empty((n, 4))
    R = np.empty((3, 3))
    Rd = np.empty((3, 3))
    w = np.empty(4)
    for i in range(n):
        quat_to_R_into(q[i], R)
        cr, sr = math.cos(roll[i]), math.sin(roll[i])
        cp, sp = math.cos(pitch[i]), math.sin(pitch[i])
        cy, sy = math.cos(yaw[i]), math.sin(yaw[i])
        Rd[0, 0], Rd[0, 1], Rd[0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
        Rd[1, 0], Rd[1, 1], Rd[1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
        Rd[2, 0], Rd[2, 1], Rd[2, 2] = -sp, cp * sr, cp * cr
        E = Rd.T @ R - R.T @ Rd  # eR = vee(E) / 2
        eR = (0.5 * (E[2, 1] - E[1, 2]) / 2.0, 0.5 * (E[0, 2] - E[2, 0]) / 2.0, 0.5 * (E[1, 0] - E[0, 1]) / 2.0)
        ox, oy, oz = Omega_b[i, 0], Omega_b[i, 1], Omega_b[i, 2]
        jx, jy, jz = J[i, 0] * ox, J[i, 1] * oy, J[i, 2] * oz
        w[0] = thrust[i]
        w[1] = -kR[i, 0] * eR[0] - kOm[i, 0] * ox + (oy * jz - oz * jy)
        w[2] = -kR[i, 1] * eR[1] - kOm[i, 1] * oy + (oz * jx - ox * jz)
        w[3] = -kR[i, 2] * eR[2] - kOm[i, 2] * oz + (ox * jy - oy * jx)
        for r in range(4):
            f = B_inv[i, r, 0] * w[0] + B_inv[i, r, 1] * w[1] + B_inv[i, r, 2] * w[2] + B_inv[i, r, 3] * w[3]
            out[i, r] = min(max(f, 0.0), f_max[i])
    return out


class OnboardGains(NamedTuple):
    """The per-drone constants of :func:`onboard_rotor_thrusts` for ``n`` drones."""

    kR: FloatArray  # (n, 3) attitude gains
    kOm: FloatArray  # (n, 3) angular-rate gains
    J: FloatArray  # (n, 3) kg m^2: inertia diagonal
    B_inv: FloatArray  # (n, 4, 4) inverse mixers
    f_max: FloatArray  # (n,) N: rotor thrust limits

    @staticmethod
    def stack(gains: list[OnboardGains]) -> OnboardGains:
        """The gains of several drones, one row each (each of ``gains`` has one drone)."""
        return OnboardGains(*(np.concatenate(parts) for parts in zip(*gains, strict=True)))


class OnboardController:
    """Emulates the Crazyflie firmware's attitude loop at physics rate: it integrates
    the yaw-rate setpoint into a yaw target and tracks ``Rz(yaw) Ry(pitch) Rx(roll)``
    with the geometric controller (:func:`onboard_rotor_thrusts`)."""

    def __init__(self, model: QuadModel, yaw0_rad: float = 0.0, gains: AttitudeGains | None = None) -> None:
        self.ctrl = AttitudeController(model, gains)
        self.yaw_sp_rad = yaw0_rad
        c = self.ctrl
        self.gains = OnboardGains(
            c.kR[None, :].copy(),
            c.kOm[None, :].copy(),
            np.diag(model.J)[None, :].copy(),
            model.B_inv[None, :, :].copy(),
            np.array([c.f_max]),
        )

    def rotor_thrusts(self, state: QuadState, sp: AttitudeSetpoint, dt_s: float) -> FloatArray:
        self.yaw_sp_rad += sp.yaw_rate_radps * dt_s
        return onboard_rotor_thrusts(
            state.q[None, :],
            state.Omega_b[None, :],
            np.array([sp.roll_rad]),
            np.array([sp.pitch_rad]),
            np.array([self.yaw_sp_rad]),
            np.array([sp.thrust_N]),
            *self.gains,
        )[0]


def yaw_of(state: QuadState) -> float:
    """Yaw [rad] (ZYX) of a state's attitude."""
    return R_to_euler(quat_to_R(state.q))[2]
