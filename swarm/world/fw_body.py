"""The body a Crazyflie firmware flies in the loop (``swarm.world.sitl_fw``): pure and compiled.

* **Motors.** Each of the four PWM commands the firmware sends on CRTP port 9 asks for a
  thrust ``a u^2 + b u`` [N], ``u = PWM / 65535``, with the simulated motors' constants
  (``swarm.crazyflie_fw.CRAZYSIM``, from the firmware's ``power_distribution_sitl.c``):
  the rotor speed that makes it, which the rotor reaches through a first-order lag, 12.5 ms
  up and 25 ms down, as in ``swarm.realism.motors`` (CrazySim's Gazebo motor model, whose
  constants it cites; thrust goes with the speed squared). The firmware's gains are tuned
  for motors that lag: on a body whose thrust follows the PWM at once its attitude-rate
  loop rings (docs/design.md, "Firmware in the loop").
* **Layout.** M1 front right, M2 back right, M3 back left, M4 front left, each
  ``ARM_LENGTH / sqrt 2`` from the body axes; M1 and M3 turn the body about -z, M2 and M4
  about +z, ``thrustToTorque`` metres times their thrust: the inverse of the firmware's
  ``powerDistributionForceTorque`` (:func:`firmware_mixer`).
* **Rigid body.** The project's equations (``swarm.model``: ``m v' = -m g e3 + T R e3``,
  ``J Omega' = tau - Omega x J Omega``, ``q' = q (x) (0, Omega) / 2``), integrated by the
  same RK4 as :func:`swarm.model.step_rk4`, compiled, because the firmware wants a step
  every millisecond (a numpy step takes half of that: docs/benchmarks.md).
* **Ground.** A flat floor at z = 0: a body on it whose thrust cannot lift it rests there,
  level at its yaw, at rest.
* **IMU.** The accelerometer measures the specific force (acceleration minus gravity) in
  the body frame, in g, and the gyro the body rates in deg/s; both go out as int16 with
  the scales ``sensors_sitl.c`` reads them with (``SENSORS_G_PER_LSB_CFG`` 32/65536 g,
  ``SENSORS_DEG_PER_LSB_CFG`` 4000/65536 deg/s). Noiseless: the firmware's gyro-bias
  search accepts a still body at once.

State rows ``s`` (13,): position [m, world], velocity [m/s, world], scalar-last unit
quaternion body to world, body rates [rad/s, body].
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarm.crazyflie_fw import CRAZYSIM, MOTOR_XY, MOTOR_YAW
from swarm.model import QuadParams
from swarm.realism.motors import MotorParams
from swarm.rotation import FloatArray

G_PER_LSB = 2.0 * 16.0 / 65536.0  # sensors_sitl.c SENSORS_G_PER_LSB_CFG
DEG_PER_LSB = 2.0 * 2000.0 / 65536.0  # sensors_sitl.c SENSORS_DEG_PER_LSB_CFG


def firmware_mixer(arm_m: float = CRAZYSIM.arm_m, yaw_m: float = CRAZYSIM.thrust_to_torque_m) -> FloatArray:
    """``[T, tau_x, tau_y, tau_z] = B f`` (4, 4) for motor thrusts ``f`` (M1..M4) [N]: the
    inverse of power_distribution_sitl.c ``powerDistributionForceTorque``."""
    d = arm_m / math.sqrt(2.0)
    xy = np.asarray(MOTOR_XY, dtype=float) * d
    return np.vstack([np.ones(4), xy[:, 1], -xy[:, 0], yaw_m * np.asarray(MOTOR_YAW, dtype=float)])


@njit(cache=True)
def motor_thrusts(pwm, a_N, b_N, f):
    """Motor thrusts [N] (4,) into ``f`` from PWM commands (4,): ``a u^2 + b u``."""
    for i in range(4):
        u = pwm[i] / 65535.0
        f[i] = a_N * u * u + b_N * u


@njit(cache=True)
def lagged_thrusts(pwm, a_N, b_N, spin, tau_up_s, tau_down_s, dt, f):
    """The thrusts [N] (4,) into ``f`` after ``dt`` [s] of the PWM commands (4,) held: each
    rotor's speed, kept in ``spin`` (4,) as the square root of the thrust it makes
    [sqrt N], moves toward the speed of ``a u^2 + b u`` by ``1 - exp(-dt / tau)``, with
    ``tau_up_s`` while it rises and ``tau_down_s`` while it falls (0: at once)."""
    motor_thrusts(pwm, a_N, b_N, f)
    for i in range(4):
        target = math.sqrt(max(f[i], 0.0))
        tau = tau_up_s if target > spin[i] else tau_down_s
        a = math.exp(-dt / tau) if tau > 0.0 else 0.0
        spin[i] = a * spin[i] + (1.0 - a) * target
        f[i] = spin[i] * spin[i]


@njit(cache=True)
def _deriv(s, wrench, J, J_inv, m, g, out):
    x, y, z, w = s[6], s[7], s[8], s[9]
    wx, wy, wz = s[10], s[11], s[12]
    T = wrench[0] / m
    out[0], out[1], out[2] = s[3], s[4], s[5]
    out[3] = T * 2 * (x * z + y * w)  # (R e3) T / m - g e3
    out[4] = T * 2 * (y * z - x * w)
    out[5] = T * (1 - 2 * (x * x + y * y)) - g
    out[6] = 0.5 * (w * wx + y * wz - z * wy)  # swarm.rotation.quat_derivative
    out[7] = 0.5 * (w * wy + z * wx - x * wz)
    out[8] = 0.5 * (w * wz + x * wy - y * wx)
    out[9] = 0.5 * (-x * wx - y * wy - z * wz)
    h0 = J[0, 0] * wx + J[0, 1] * wy + J[0, 2] * wz  # J Omega
    h1 = J[1, 0] * wx + J[1, 1] * wy + J[1, 2] * wz
    h2 = J[2, 0] * wx + J[2, 1] * wy + J[2, 2] * wz
    r0 = wrench[1] - (wy * h2 - wz * h1)  # tau - Omega x J Omega
    r1 = wrench[2] - (wz * h0 - wx * h2)
    r2 = wrench[3] - (wx * h1 - wy * h0)
    for i in range(3):
        out[10 + i] = J_inv[i, 0] * r0 + J_inv[i, 1] * r1 + J_inv[i, 2] * r2


@njit(cache=True)
def rk4(s, f, B, J, J_inv, m, g, dt):
    """One RK4 step of the rigid body, in place, with motor thrusts ``f`` (4,) [N] held
    over ``dt`` [s]; the quaternion is renormalised (as :func:`swarm.model.step_rk4`)."""
    wrench = B @ f
    k1, k2, k3, k4, tmp = np.empty(13), np.empty(13), np.empty(13), np.empty(13), np.empty(13)
    _deriv(s, wrench, J, J_inv, m, g, k1)
    for i in range(13):
        tmp[i] = s[i] + 0.5 * dt * k1[i]
    _deriv(tmp, wrench, J, J_inv, m, g, k2)
    for i in range(13):
        tmp[i] = s[i] + 0.5 * dt * k2[i]
    _deriv(tmp, wrench, J, J_inv, m, g, k3)
    for i in range(13):
        tmp[i] = s[i] + dt * k3[i]
    _deriv(tmp, wrench, J, J_inv, m, g, k4)
    for i in range(13):
        s[i] += dt / 6.0 * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i])
    n = math.sqrt(s[6] * s[6] + s[7] * s[7] + s[8] * s[8] + s[9] * s[9])
    for i in range(6, 10):
        s[i] /= n


@njit(cache=True)
def _clip16(v):
    r = round(v)
    return -32768 if r < -32768 else (32767 if r > 32767 else int(r))


@njit(cache=True)
def step(s, pwm, spin, body, dt, imu):
    """One millisecond of the body: motor thrusts from ``pwm`` through the rotors' lag
    (:func:`lagged_thrusts`), the RK4 step, the floor, and the IMU reading at its end into
    ``imu`` (6,) int16 counts (accelerometer x, y, z, gyro x, y, z, body frame). ``body``: its
    constants, ``(a_N, b_N, tau_up_s, tau_down_s, B, J, J_inv, m, g)`` (:attr:`FirmwareBody.constants`).
    Returns the collective thrust [N]."""
    a_N, b_N, tau_up_s, tau_down_s, B, J, J_inv, m, g = body
    f = np.empty(4)
    lagged_thrusts(pwm, a_N, b_N, spin, tau_up_s, tau_down_s, dt, f)
    v0 = s[3:6].copy()
    rk4(s, f, B, J, J_inv, m, g, dt)
    x, y, z, w = s[6], s[7], s[8], s[9]
    lift = (f[0] + f[1] + f[2] + f[3]) * (1 - 2 * (x * x + y * y))  # thrust along world z
    if s[2] <= 0.0 and lift <= m * g:  # on the floor, and the motors cannot lift it: it rests there, level
        yaw = math.atan2(2 * (x * y + z * w), 1 - 2 * (y * y + z * z))
        s[2] = 0.0
        s[3:6] = 0.0
        s[6], s[7], s[8], s[9] = 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)
        s[10:13] = 0.0
    elif s[2] < 0.0:  # lifting off: never below the floor
        s[2] = 0.0
        if s[5] < 0.0:
            s[5] = 0.0
    x, y, z, w = s[6], s[7], s[8], s[9]
    sf = np.empty(3)  # specific force [m/s^2, world]: what the accelerometer feels
    for i in range(3):
        sf[i] = (s[3 + i] - v0[i]) / dt
    sf[2] += g
    # R^T sf (body frame), in g
    r00, r01, r02 = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
    r10, r11, r12 = 2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)
    r20, r21, r22 = 2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)
    scale = 1.0 / (g * 2.0 * 16.0 / 65536.0)
    imu[0] = _clip16((r00 * sf[0] + r10 * sf[1] + r20 * sf[2]) * scale)
    imu[1] = _clip16((r01 * sf[0] + r11 * sf[1] + r21 * sf[2]) * scale)
    imu[2] = _clip16((r02 * sf[0] + r12 * sf[1] + r22 * sf[2]) * scale)
    dscale = 180.0 / math.pi / (2.0 * 2000.0 / 65536.0)
    for i in range(3):
        imu[3 + i] = _clip16(s[10 + i] * dscale)
    return f[0] + f[1] + f[2] + f[3]


class FirmwareBody:
    """One body: its state and constants, stepped by :meth:`step` with the latest PWM;
    ``motors`` gives the rotors' time constants (``MotorParams(0, 0)``: thrust at once)."""

    def __init__(
        self, x_w: FloatArray, yaw_rad: float, params: QuadParams | None = None, motors: MotorParams | None = None
    ) -> None:
        p = params or QuadParams(mass_kg=CRAZYSIM.mass_kg)
        lag = motors or MotorParams()
        self.tau_up_s, self.tau_down_s = lag.time_constant_up_s, lag.time_constant_down_s
        self.spin = np.zeros(4)  # each rotor's speed as the square root of its thrust [sqrt N]
        self.m, self.g = p.mass_kg, p.g_mps2
        self.J = np.diag([p.Ixx_kgm2, p.Iyy_kgm2, p.Izz_kgm2])
        self.J_inv = np.linalg.inv(self.J)
        self.B = firmware_mixer()
        self.a_N, self.b_N = CRAZYSIM.thrust.a_N, CRAZYSIM.thrust.b_N
        self.s = np.zeros(13)
        self.s[0:3] = x_w
        self.s[8], self.s[9] = math.sin(yaw_rad / 2), math.cos(yaw_rad / 2)
        self.pwm = np.zeros(4)
        self.imu = np.zeros(6, dtype=np.int64)
        self.thrust_N = 0.0  # collective thrust [N] of the last step

    @property
    def constants(self) -> tuple:
        """What :func:`step` takes of the body besides its state: thrust map, rotor lag, mixer,
        inertia, mass and gravity."""
        return (self.a_N, self.b_N, self.tau_up_s, self.tau_down_s, self.B, self.J, self.J_inv, self.m, self.g)

    def step(self, dt_s: float) -> None:
        self.thrust_N = step(self.s, self.pwm, self.spin, self.constants, dt_s, self.imu)

    @property
    def x_w(self) -> FloatArray:
        return self.s[0:3]

    @property
    def resting(self) -> bool:
        """On the floor with every motor's command zero."""
        return bool(self.s[2] <= 0.0 and not self.pwm.any())

    @property
    def q(self) -> FloatArray:
        return self.s[6:10]
