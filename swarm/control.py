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

import numpy as np

from swarm.errors import InputError
from swarm.model import QuadModel, QuadState, check_finite, thrust_vector_to_setpoint
from swarm.rotation import E3, FloatArray, R_to_euler, euler_to_quat, quat_to_R, vee


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
        seg = np.diff(W, axis=0)
        self._len = np.linalg.norm(seg, axis=1)
        self._tail = np.concatenate([np.cumsum(self._len[::-1])[::-1][1:], [0.0]])
        self.segment = 0

    @property
    def goal_w(self) -> FloatArray:
        return self.W[-1]

    def reference(self, x_w: FloatArray) -> tuple[FloatArray, FloatArray, float]:
        """Closest path point [m, world], path tangent, remaining path length [m]."""
        W, last = self.W, len(self._len) - 1
        while True:
            i = self.segment
            a, L = W[i], self._len[i]
            d = W[i + 1] - a
            t = float(np.clip((x_w - a) @ d / (L * L), 0.0, 1.0)) if L > 1e-9 else 1.0
            if t >= 1.0 and i < last:
                self.segment += 1
                continue
            tangent = d / L if L > 1e-9 else np.zeros(3)
            return a + t * d, tangent, (1.0 - t) * L + self._tail[i]

    def desired_accel(self, x_w: FloatArray, v_w: FloatArray) -> FloatArray:
        """Commanded acceleration [m/s^2, world] (without gravity compensation)."""
        g = self.gains
        c, tangent, remaining = self.reference(x_w)
        speed = min(self.speed_mps, g.kp_per_s * remaining)
        v_des = speed * tangent + g.kp_per_s * (c - x_w)
        a = g.kd_per_s * (v_des - v_w)
        h = math.hypot(a[0], a[1])
        if h > g.max_horizontal_accel_mps2:
            a[:2] *= g.max_horizontal_accel_mps2 / h
        a[2] = min(max(a[2], -g.max_vertical_accel_mps2), g.max_vertical_accel_mps2)
        return a

    def thrust_vector(self, model: QuadModel, x_w: FloatArray, v_w: FloatArray) -> FloatArray:
        """Desired thrust vector ``F_ref = m (a_des + g e3)`` [N, world]."""
        p = model.params
        return p.mass_kg * (self.desired_accel(x_w, v_w) + p.g_mps2 * E3)


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


def setpoint_from_thrust_vector(
    F_w: FloatArray, yaw_rad: float, yaw_des_rad: float = 0.0, k_yaw_per_s: float = 2.0
) -> AttitudeSetpoint:
    """Setpoint that points the body z axis along ``F_w`` at the current yaw and turns
    toward ``yaw_des_rad`` at ``k_yaw_per_s`` times the (wrapped) yaw error."""
    roll, pitch, thrust = thrust_vector_to_setpoint(F_w, yaw_rad)
    err = (yaw_des_rad - yaw_rad + math.pi) % (2 * math.pi) - math.pi
    return AttitudeSetpoint(roll, pitch, k_yaw_per_s * err, thrust)


class OnboardController:
    """Emulates the Crazyflie firmware's attitude loop at physics rate: it integrates
    the yaw-rate setpoint into a yaw target and tracks ``Rz(yaw) Ry(pitch) Rx(roll)``
    with the geometric controller."""

    def __init__(self, model: QuadModel, yaw0_rad: float = 0.0, gains: AttitudeGains | None = None) -> None:
        self.ctrl = AttitudeController(model, gains)
        self.yaw_sp_rad = yaw0_rad

    def rotor_thrusts(self, state: QuadState, sp: AttitudeSetpoint, dt_s: float) -> FloatArray:
        self.yaw_sp_rad += sp.yaw_rate_radps * dt_s
        R_des = quat_to_R(euler_to_quat(sp.roll_rad, sp.pitch_rad, self.yaw_sp_rad))
        return self.ctrl.rotor_thrusts(state, R_des, sp.thrust_N)


def yaw_of(state: QuadState) -> float:
    """Yaw [rad] (ZYX) of a state's attitude."""
    return R_to_euler(quat_to_R(state.q))[2]
