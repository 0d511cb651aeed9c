"""Sensing: motion-capture frames (noisy, late, some dropped, at a frame rate) and the
estimator each agent runs on them, so an agent acts on an estimate, never on ground truth.

:class:`MocapSensor` (the world's side) captures every drone at the frame rate, adds
position noise [m] and attitude noise [rad] (a rotation by a normal rotation vector),
drops a frame with a probability, and hands a frame over ``latency_s`` after its capture
(stamped with that time, handed over at the first :meth:`MocapSensor.step` at or after it). Every draw is a pure
function of (seed, drone, frame number) (:mod:`swarm.realism.rng`).

:class:`Estimator` (the agent's side) is what the Crazyflie's own EKF does with external
position (``crazyflie-firmware/src/modules/src/kalman_core/kalman_core.c``), reduced to
what an off-board agent has: per axis a Kalman filter on (position, velocity), predicted
with the agent's own commanded acceleration as input, corrected by each frame at its
capture time (its arrival time less the latency the agent knows), and predicted forward
from there to the time asked for. Process noise is the firmware's, ``procNoiseAcc_xy``
0.5 m/s^2 and ``procNoiseAcc_z`` 1.0 m/s^2 (``kalman_core_params_defaults.h``) added per
its 100 Hz prediction step (``(sigma dt)^2`` to velocity variance per step), here as the
equivalent white-acceleration density ``q = sigma^2 x 10 ms``. Beyond the firmware's
filter, each axis may also estimate a disturbance, the acceleration the drone has beyond
the one commanded (thrust and mass off the model, a steady wind): a third state, a random
walk (``disturbance_walk_mps2``), so the estimate acts on the velocity and position it
predicts and the agent can take it off its command (``swarm.step``), as the firmware's own
position controllers do with their integral terms. Attitude: the last frame's,
turned forward over its age by the body rates; the rates are the drone's gyro when the
caller has it, else the frames' attitude differences, low-passed (as ``swarm.world.mocap``
does for real drones).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from swarm.errors import InputError
from swarm.realism.rng import Stream, normals, uniform, word
from swarm.rotation import FloatArray, norm

MAX_GAP_S = 0.5
"""An estimate this long after the last frame moves the filter's own state forward (:meth:`Estimator.estimate`)."""

FIRMWARE_PREDICT_S = 0.01
"""The Crazyflie EKF's prediction period (``estimator_kalman.c``: ``PREDICT_RATE RATE_100_HZ``)."""


@dataclass(frozen=True)
class MocapParams:
    rate_hz: float = 100.0
    position_noise_m: float = 0.0
    """Standard deviation of each position coordinate [m]."""
    attitude_noise_rad: float = 0.0
    """Standard deviation of each component of the attitude error's rotation vector [rad]."""
    latency_s: float = 0.0
    drop_fraction: float = 0.0


class MocapFrame(NamedTuple):
    """One drone seen once."""

    drone: int  # index in the plant's order
    seq: int  # frame number: captured at seq / rate_hz (on the physics grid)
    t_capture_s: float  # when it was captured (ground truth; an estimator must not use it)
    t_arrival_s: float  # when it reached the receiving computer (capture + latency; handed over at the next step)
    x_w: FloatArray  # (3,) m, world, measured
    q: FloatArray  # (4,) scalar-last, measured


def quat_mul(a: FloatArray, b: FloatArray) -> FloatArray:
    """Hamilton product of scalar-last quaternions (a then b in body frame: ``R(a) R(b)``)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


def quat_exp(rv: FloatArray) -> FloatArray:
    """The unit quaternion of the rotation vector ``rv`` (3,) [rad]."""
    angle = norm(rv)
    if angle < 1e-12:
        return np.array([rv[0] / 2, rv[1] / 2, rv[2] / 2, 1.0]) / math.sqrt(1.0 + angle * angle / 4)
    s = math.sin(angle / 2) / angle
    return np.array([rv[0] * s, rv[1] * s, rv[2] * s, math.cos(angle / 2)])


def quat_log(q: FloatArray) -> FloatArray:
    """The rotation vector [rad] of a unit quaternion (the shorter way round)."""
    q = q if q[3] >= 0 else -q
    v = q[:3]
    s = norm(v)
    if s < 1e-12:
        return 2.0 * v
    return 2.0 * math.atan2(s, float(q[3])) / s * v


def quat_conj(q: FloatArray) -> FloatArray:
    return np.array([-q[0], -q[1], -q[2], q[3]])


class MocapSensor:
    """Frames of n drones from their true poses, one :meth:`step` per physics step."""

    def __init__(self, p: MocapParams, n: int, seed: int) -> None:
        self.p = p
        self.n = n
        self.seed = word(seed)
        self._next_seq = 0
        self._in_flight: list[tuple[float, int, int, MocapFrame]] = []  # (due, seq, drone, frame)
        self.dropped = 0

    def step(self, t_s: float, x_w: FloatArray, q: FloatArray) -> list[MocapFrame]:
        """Capture the drones at ``t_s`` [s] if a frame is due (true centres of mass
        ``x_w`` (n, 3) [m, world] and attitudes ``q`` (n, 4)), and return the frames that
        arrive by ``t_s``, in order of arrival, then drone."""
        seq = math.floor(t_s * self.p.rate_hz + 1e-9)
        if seq >= self._next_seq:
            self._capture(seq, t_s, x_w, q)
            self._next_seq = seq + 1
        out = []
        while self._in_flight and self._in_flight[0][0] <= t_s + 1e-12:
            out.append(heapq.heappop(self._in_flight)[3])
        return out

    def _capture(self, seq: int, t_s: float, x_w: FloatArray, q: FloatArray) -> None:
        p = self.p
        drones = np.arange(self.n)
        dpos = normals(int(self.seed), Stream.MOCAP_POSITION, drones, seq, 3) * p.position_noise_m
        datt = normals(int(self.seed), Stream.MOCAP_ATTITUDE, drones, seq, 3) * p.attitude_noise_rad
        due = t_s + p.latency_s
        for i in range(self.n):
            if p.drop_fraction > 0.0:
                u = uniform(self.seed, np.uint64(int(Stream.MOCAP_DROP)), np.uint64(i), word(seq), np.uint64(0))
                if u <= p.drop_fraction:
                    self.dropped += 1
                    continue
            qi = np.asarray(q[i], float)
            q_meas = quat_mul(qi, quat_exp(datt[i])) if p.attitude_noise_rad > 0 else qi.copy()
            frame = MocapFrame(i, seq, t_s, due, np.asarray(x_w[i], float) + dpos[i], q_meas)
            heapq.heappush(self._in_flight, (due, seq, i, frame))


@dataclass(frozen=True)
class EstimatorParams:
    position_noise_m: float = 0.001
    """The measurement noise the filter assumes [m] (R = sigma^2)."""
    latency_s: float = 0.0
    """The latency the agent knows: a frame was captured this long before it arrived."""
    process_accel_xy_mps2: float = 0.5
    process_accel_z_mps2: float = 1.0
    initial_velocity_std_mps: float = 0.01
    """The firmware's ``stdDevInitialVelocity``: the start velocity (at rest on a real drone) is known this well."""
    rate_filter_s: float = 0.02
    """Time constant of the low-pass on body rates from frame differences [s]."""
    disturbance_walk_mps2: float = 0.0
    """How fast the disturbance the filter estimates may change: the standard deviation of its
    random walk over one second [m/s^2] (0, with ``initial_disturbance_std_mps2`` 0: no disturbance estimate)."""
    initial_disturbance_std_mps2: float = 0.0
    """The standard deviation of the disturbance at the start [m/s^2]: before any frame, how far the
    drone's acceleration may be off the one its commands ask for (thrust and mass off the model)."""

    @property
    def r2_m2(self) -> float:
        """The measurement variance [m^2], at least (1 um)^2 so the filter never divides by 0."""
        return max(self.position_noise_m, 1e-6) ** 2

    @property
    def q_density(self) -> FloatArray:
        """(3,) white-acceleration spectral density per axis [(m/s^2)^2 s]."""
        xy, z = self.process_accel_xy_mps2, self.process_accel_z_mps2
        return np.array([xy * xy, xy * xy, z * z]) * FIRMWARE_PREDICT_S

    @property
    def walk_density(self) -> FloatArray:
        """(3,) the disturbance's random-walk spectral density per axis [(m/s^2)^2 / s]."""
        return np.full(3, self.disturbance_walk_mps2**2)


class Estimate(NamedTuple):
    """What an agent acts on, at ``t_s``."""

    t_s: float
    x_w: FloatArray  # (3,) m, world, centre of mass
    v_w: FloatArray  # (3,) m/s, world
    q: FloatArray  # (4,) scalar-last
    Omega_b: FloatArray  # (3,) rad/s, body
    pos_std_m: FloatArray  # (3,) the filter's standard deviation of each coordinate
    vel_std_mps: FloatArray  # (3,)
    age_s: float  # since the capture of the last frame fused (as the agent reckons it)
    d_w: FloatArray  # (3,) m/s^2, world: the acceleration the drone has beyond the one commanded (0: not estimated)


@njit(cache=True)
def _predict(X, P, a, dt, qd, qw):
    """Per axis k: (p, v, d) of X[k] and P[k] (3, 3) forward by dt under the commanded
    acceleration a[k] plus the disturbance d, white acceleration of density qd[k] on v and a
    random walk of density qw[k] on d (in place). With d and its variances 0 it is the
    (position, velocity) filter exactly."""
    dt2 = dt * dt
    dt3 = dt2 * dt
    for k in range(3):
        acc = a[k] + X[k, 2]
        X[k, 0] += X[k, 1] * dt + 0.5 * acc * dt2
        X[k, 1] += acc * dt
        p00, p01, p11 = P[k, 0, 0], P[k, 0, 1], P[k, 1, 1]
        p02, p12, p22 = P[k, 0, 2], P[k, 1, 2], P[k, 2, 2]
        # F P F' + Q with F = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]]
        n00 = p00 + 2.0 * dt * p01 + dt2 * p11 + qd[k] * dt3 / 3.0
        n00 += dt2 * p02 + dt3 * p12 + 0.25 * dt2 * dt2 * p22 + qw[k] * dt3 * dt2 / 20.0
        n01 = p01 + dt * p11 + qd[k] * dt2 / 2.0
        n01 += 0.5 * dt2 * p12 + dt * p02 + dt2 * p12 + 0.5 * dt3 * p22 + qw[k] * dt2 * dt2 / 8.0
        n11 = p11 + qd[k] * dt
        n11 += 2.0 * dt * p12 + dt2 * p22 + qw[k] * dt3 / 3.0
        n02 = p02 + dt * p12 + 0.5 * dt2 * p22 + qw[k] * dt3 / 6.0
        n12 = p12 + dt * p22 + qw[k] * dt2 / 2.0
        n22 = p22 + qw[k] * dt
        P[k, 0, 0], P[k, 0, 1], P[k, 1, 0], P[k, 1, 1] = n00, n01, n01, n11
        P[k, 0, 2], P[k, 2, 0], P[k, 1, 2], P[k, 2, 1], P[k, 2, 2] = n02, n02, n12, n12, n22


@njit(cache=True)
def _update(X, P, z, r2):
    """Per axis: the Kalman update with a position measurement z[k] of variance r2."""
    for k in range(3):
        s = P[k, 0, 0] + r2
        k0, k1, k2 = P[k, 0, 0] / s, P[k, 0, 1] / s, P[k, 0, 2] / s
        y = z[k] - X[k, 0]
        X[k, 0] += k0 * y
        X[k, 1] += k1 * y
        X[k, 2] += k2 * y
        p00, p01, p11 = P[k, 0, 0], P[k, 0, 1], P[k, 1, 1]
        p02, p12, p22 = P[k, 0, 2], P[k, 1, 2], P[k, 2, 2]
        P[k, 0, 0] = (1.0 - k0) * p00
        P[k, 0, 1] = (1.0 - k0) * p01
        P[k, 1, 0] = P[k, 0, 1]
        P[k, 1, 1] = p11 - k1 * p01
        P[k, 0, 2] = (1.0 - k0) * p02
        P[k, 2, 0] = P[k, 0, 2]
        P[k, 1, 2] = p12 - k1 * p02
        P[k, 2, 1] = P[k, 1, 2]
        P[k, 2, 2] = p22 - k2 * p02


@dataclass
class Estimator:
    """One agent's estimate of its own drone from motion-capture frames.

    Per control tick: :meth:`frame` for each frame that arrived, :meth:`estimate` for the
    state to act on, :meth:`command` with the acceleration it then commands."""

    p: EstimatorParams
    x0_w: FloatArray  # (3,) m, world: the start
    q0: FloatArray  # (4,)
    t0_s: float = 0.0
    v0_w: FloatArray | None = None  # (3,) m/s, world: the start velocity (None: at rest), to initial_velocity_std_mps
    X: FloatArray = field(init=False)  # (3, 3): per axis position [m], velocity [m/s], disturbance [m/s^2] at t_fused_s
    P: FloatArray = field(init=False)  # (3, 3, 3)
    t_fused_s: float = field(init=False)
    stale: int = field(init=False, default=0)  # frames older than the last fused, dropped
    _seq: int = field(init=False, default=-1)
    _cmds: list[tuple[float, FloatArray]] = field(init=False)  # (from t [s], a [m/s^2, world])
    _q: FloatArray = field(init=False)
    _q_t_s: float = field(init=False)
    _Omega_b: FloatArray = field(init=False)
    _qd: FloatArray = field(init=False)  # (3,) the parameters' densities, made once
    _qw: FloatArray = field(init=False)

    def __post_init__(self) -> None:
        self.X = np.zeros((3, 3))
        self.X[:, 0] = np.asarray(self.x0_w, float)
        if self.v0_w is not None:
            self.X[:, 1] = np.asarray(self.v0_w, float)
        self.P = np.zeros((3, 3, 3))
        self.P[:, 0, 0] = self.p.r2_m2
        self.P[:, 1, 1] = self.p.initial_velocity_std_mps**2
        self.P[:, 2, 2] = self.p.initial_disturbance_std_mps2**2
        self.t_fused_s = self.t0_s
        self._cmds = [(self.t0_s, np.zeros(3))]
        self._q = np.asarray(self.q0, float) / np.linalg.norm(self.q0)
        self._q_t_s = self.t0_s
        self._Omega_b = np.zeros(3)
        self._qd, self._qw = self.p.q_density, self.p.walk_density

    def command(self, t_s: float, a_w: FloatArray) -> None:
        """The agent commands the acceleration ``a_w`` (3,) [m/s^2, world, gravity
        included: ``F / m - g e3`` for a thrust vector F] from ``t_s`` on."""
        a = np.asarray(a_w, float)
        if not np.all(np.isfinite(a)):
            raise InputError("Estimator.command: acceleration is not finite")
        if t_s < self._cmds[-1][0]:
            raise InputError(f"Estimator.command: t_s {t_s} is before the last command's {self._cmds[-1][0]}")
        if t_s == self._cmds[-1][0]:
            self._cmds[-1] = (t_s, a)
        else:
            self._cmds.append((t_s, a))

    def _propagate(self, X: FloatArray, P: FloatArray, t0: float, t1: float) -> None:
        qd, qw = self._qd, self._qw
        cmds = self._cmds
        for k, (ts, a) in enumerate(cmds):
            end = cmds[k + 1][0] if k + 1 < len(cmds) else math.inf
            lo, hi = max(ts, t0), min(end, t1)
            if hi > lo:
                _predict(X, P, a, hi - lo, qd, qw)

    def _advance(self, t_s: float) -> None:
        """Predict the filter's own state to ``t_s`` and forget the commands before it."""
        self._propagate(self.X, self.P, self.t_fused_s, t_s)
        self.t_fused_s = t_s
        while len(self._cmds) > 1 and self._cmds[1][0] <= t_s:
            self._cmds.pop(0)

    def frame(self, f: MocapFrame) -> bool:
        """Fuse a frame; False (and counted) if it is older than the last one fused (by its
        frame number, or by its capture time as the agent reckons it)."""
        t_c = f.t_arrival_s - self.p.latency_s
        if f.seq <= self._seq or t_c < self.t_fused_s:
            self.stale += 1
            return False
        self._seq = f.seq
        self._advance(t_c)
        _update(self.X, self.P, np.asarray(f.x_w, float), self.p.r2_m2)
        q = np.asarray(f.q, float)
        q = q / norm(q)
        dt = t_c - self._q_t_s
        if dt > 0.0:
            rate = quat_log(quat_mul(quat_conj(self._q), q)) / dt
            a = dt / (self.p.rate_filter_s + dt) if self.p.rate_filter_s > 0 else 1.0
            self._Omega_b = self._Omega_b + a * (rate - self._Omega_b)
        self._q, self._q_t_s = q, t_c
        return True

    def estimate(self, t_s: float, Omega_b: FloatArray | None = None) -> Estimate:
        """The state at ``t_s`` [s]: the filter predicted forward from the last frame's
        capture time with the commands since; ``Omega_b`` (3,) [rad/s, body]: the
        drone's gyro, if the caller has it (else the rates from the frames).

        With no frame for :data:`MAX_GAP_S`, the filter's own state is first predicted to
        ``t_s - MAX_GAP_S`` (frames captured before that are then stale), so a long loss
        of motion capture costs no more per call than a short one."""
        if t_s - self.t_fused_s > MAX_GAP_S:
            self._advance(t_s - MAX_GAP_S)
        X, P = self.X.copy(), self.P.copy()
        if t_s > self.t_fused_s:
            self._propagate(X, P, self.t_fused_s, t_s)
        rates = self._Omega_b if Omega_b is None else np.asarray(Omega_b, float)
        q = quat_mul(self._q, quat_exp(rates * max(t_s - self._q_t_s, 0.0)))
        return Estimate(
            t_s,
            X[:, 0].copy(),
            X[:, 1].copy(),
            q,
            rates.copy(),
            np.sqrt(P[:, 0, 0]),
            np.sqrt(P[:, 1, 1]),
            t_s - self.t_fused_s,
            X[:, 2].copy(),
        )


def steady_std(p: EstimatorParams, rate_hz: float, drop_fraction: float, latency_s: float) -> tuple[float, float]:
    """The largest standard deviations of an axis of the :class:`Estimator`'s position [m] and
    velocity [m/s] in steady state when it is read: its own covariance predicted from a frame's
    capture over the latency and up to the next frame that arrives (one period, two where
    frames drop), the largest over the axes. The margins the agents' filter keeps for the noise
    of motion capture are multiples of them (``swarm.tuning``)."""
    period = 1.0 / rate_hz
    X = np.zeros((3, 3))
    P = np.zeros((3, 3, 3))
    P[:, 0, 0] = p.r2_m2
    P[:, 1, 1] = p.initial_velocity_std_mps**2
    P[:, 2, 2] = p.initial_disturbance_std_mps2**2
    zero, qd, qw = np.zeros(3), p.q_density, p.walk_density
    for _ in range(2000):  # the Riccati recursion to its fixed point (the filter's time constant is ~10 frames)
        _predict(X, P, zero, period, qd, qw)
        _update(X, P, zero, p.r2_m2)
    _predict(X, P, zero, latency_s + period * (2.0 if drop_fraction > 0 else 1.0), qd, qw)
    return float(np.sqrt(P[:, 0, 0].max())), float(np.sqrt(P[:, 1, 1].max()))
