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

ATTITUDE_COAST_S = 0.05
"""The last frame's attitude is turned forward by the body rates over its age, but no further than
this [s]: the rates from frame differences are a low-passed guess, and over a gap of a motion
capture's occlusion they would spin the estimate round (and with it the direction the estimator
predicts the thrust in, so the position it predicts runs away); past it the attitude is held."""

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
    occlusion_rate_hz: float = 0.0
    """How often a drone's markers are lost, per second it is seen [1/s]: at each frame of a
    drone in view a burst of occlusion begins with probability ``occlusion_rate_hz / rate_hz``
    (at most 1), and for its length no frame of the drone is made. Optical motion capture loses a
    body its cameras cannot see (Autodesk MotionBuilder, "Optical motion data: Occlusion"); how
    often in a given lab is not published: assumed, per run (0: never)."""
    occlusion_mean_s: float = 0.2
    """The mean length of a burst of occlusion [s]. A burst's length in frames is geometric with
    this mean, drawn at its start: the two-state (Gilbert-Elliott) chain over frames, whose bad
    state ends with probability ``1 / (occlusion_mean_s rate_hz)`` at each frame. Assumed: a
    drone passing behind another or under a lamp for a fifth of a second."""
    swap_rate_hz: float = 0.0
    """How often two drones' identities swap, per second of the run [1/s] (not per drone): at a
    frame with probability ``swap_rate_hz / rate_hz``, the two drones closest to each other then
    (by their true centres) each get the other's frame, its measured position and attitude, for
    ``swap_duration_s``. A tracker matching identical marker sets confuses the bodies that are
    close (Autodesk MotionBuilder, "Optical motion data: Swapping"; Crazyswarm tracks identical
    marker arrangements by their predicted positions, Preiss et al., ICRA 2017). Rate assumed
    (0: never); one swap at a time."""
    swap_duration_s: float = 0.5
    """How long a swap lasts [s] (at least one frame). Assumed: until the tracker's labelling
    recovers, as a Vicon or OptiTrack system re-labels a body from its full marker set."""
    outlier_fraction: float = 0.0
    """The fraction of frames whose position jumps by ``outlier_m`` in a random direction (a ghost
    or mislabelled marker moves the fitted pose). Assumed (0: never)."""
    outlier_m: float = 0.1
    """The length of a jump [m]. Assumed: about the size of a Crazyflie's marker arrangement."""
    centroid_offset_std_m: float = 0.0
    """The standard deviation of each coordinate of a drone's constant offset [m] between its
    markers' centroid (what motion capture reports) and its centre of mass: markers glued by hand,
    a body defined where they happened to be. Assumed a few millimetres (0: none)."""


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
    """Frames of n drones from their true poses, one :meth:`step` per physics step.

    Its failures (:class:`MocapParams`, each off by default and then drawing nothing): a burst of
    occlusion hides a drone (no frame); a swap gives the two closest drones each other's frames; an
    outlier moves a frame by ``outlier_m``; every frame of a drone is off by its constant centroid
    offset. Every draw is a pure function of (seed, drone, frame number); the chains' state (the
    frame a burst ends, the swap under way) is kept here. The counters: ``dropped``, ``occluded``
    (frames hidden by occlusion), ``occlusions`` (bursts begun), ``swaps`` (swaps begun), ``swapped``
    (frames made with the other drone's pose) and ``outliers`` (frames made with a jump)."""

    def __init__(self, p: MocapParams, n: int, seed: int) -> None:
        self.p = p
        self.n = n
        self.seed = word(seed)
        self._next_seq = 0
        self._in_flight: list[tuple[float, int, int, MocapFrame]] = []  # (due, seq, drone, frame)
        self.dropped = 0
        self.occluded = 0
        self.occlusions = 0
        self.swaps = 0
        self.swapped = 0
        self.outliers = 0
        self._visible_from = np.zeros(n, np.int64)  # per drone: the first frame after its burst of occlusion
        self._swap: tuple[int, int, int] | None = None  # (drone, drone, the first frame after the swap)
        self._offset: FloatArray | None = None  # (n, 3) m: the centroids' offsets
        self._hidden: list[tuple[int, int, int]] = []  # scripted occlusions: (drone, first frame, first frame after)
        if p.centroid_offset_std_m > 0.0:
            self._offset = normals(int(self.seed), Stream.MOCAP_CENTROID, np.arange(n), 0, 3) * p.centroid_offset_std_m

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

    def hide(self, drone: int, from_s: float, until_s: float) -> None:
        """A scripted occlusion: no frame of ``drone`` is captured from ``from_s`` until ``until_s``
        [s] (an experiment's failure at a chosen moment; counted in ``occluded``)."""
        r = self.p.rate_hz
        self._hidden.append((drone, math.ceil(from_s * r - 1e-9), math.ceil(until_s * r - 1e-9)))

    def _occluded(self, i: int, seq: int) -> bool:
        """Whether drone ``i`` is hidden at frame ``seq``: in a burst, or one begins (its length drawn now)."""
        p = self.p
        if seq < self._visible_from[i]:
            return True
        u = uniform(self.seed, np.uint64(int(Stream.MOCAP_OCCLUSION)), np.uint64(i), word(seq), np.uint64(0))
        if u > min(p.occlusion_rate_hz / p.rate_hz, 1.0):
            return False
        mean_frames = p.occlusion_mean_s * p.rate_hz
        frames = 1
        if mean_frames > 1.0:  # geometric on 1, 2, ... with this mean: the chain's bad state, memoryless
            v = uniform(self.seed, np.uint64(int(Stream.MOCAP_OCCLUSION_LENGTH)), np.uint64(i), word(seq), np.uint64(0))
            frames = 1 + math.floor(math.log(v) / math.log1p(-1.0 / mean_frames))
        self._visible_from[i] = seq + frames
        self.occlusions += 1
        return True

    def _swap_at(self, seq: int, x_w: FloatArray) -> tuple[int, int, int] | None:
        """The swap under way at frame ``seq``, or one that begins now between the two drones closest
        to each other (their true centres ``x_w`` (n, 3)), or None."""
        p = self.p
        if self._swap is not None and seq < self._swap[2]:
            return self._swap
        self._swap = None
        u = uniform(self.seed, np.uint64(int(Stream.MOCAP_SWAP)), np.uint64(0), word(seq), np.uint64(0))
        if u > min(p.swap_rate_hz / p.rate_hz, 1.0):
            return None
        x = np.asarray(x_w, float)
        d = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=2)
        d[np.diag_indices(self.n)] = np.inf
        i, j = divmod(int(np.argmin(d)), self.n)
        frames = max(1, round(p.swap_duration_s * p.rate_hz))
        self._swap = (min(i, j), max(i, j), seq + frames)
        self.swaps += 1
        return self._swap

    def _capture(self, seq: int, t_s: float, x_w: FloatArray, q: FloatArray) -> None:
        p = self.p
        drones = np.arange(self.n)
        dpos = normals(int(self.seed), Stream.MOCAP_POSITION, drones, seq, 3) * p.position_noise_m
        datt = normals(int(self.seed), Stream.MOCAP_ATTITUDE, drones, seq, 3) * p.attitude_noise_rad
        due = t_s + p.latency_s
        swap = self._swap_at(seq, x_w) if p.swap_rate_hz > 0.0 and self.n >= 2 else None
        for i in range(self.n):
            if p.occlusion_rate_hz > 0.0 and self._occluded(i, seq):
                self.occluded += 1
                continue
            if self._hidden and any(d == i and a <= seq < b for d, a, b in self._hidden):
                self.occluded += 1
                continue
            if p.drop_fraction > 0.0:
                u = uniform(self.seed, np.uint64(int(Stream.MOCAP_DROP)), np.uint64(i), word(seq), np.uint64(0))
                if u <= p.drop_fraction:
                    self.dropped += 1
                    continue
            src = i  # whose pose this frame of drone i carries
            if swap is not None and i in (swap[0], swap[1]):
                src = swap[1] if i == swap[0] else swap[0]
                self.swapped += 1
            qi = np.asarray(q[src], float)
            q_meas = quat_mul(qi, quat_exp(datt[src])) if p.attitude_noise_rad > 0 else qi.copy()
            x_meas = np.asarray(x_w[src], float) + dpos[src]
            if self._offset is not None:
                x_meas = x_meas + self._offset[src]
            if p.outlier_fraction > 0.0:
                u = uniform(self.seed, np.uint64(int(Stream.MOCAP_OUTLIER)), np.uint64(i), word(seq), np.uint64(0))
                if u <= p.outlier_fraction:
                    away = normals(int(self.seed), Stream.MOCAP_OUTLIER_DIRECTION, [i], seq, 3)[0]
                    x_meas = x_meas + p.outlier_m * away / norm(away)
                    self.outliers += 1
            frame = MocapFrame(i, seq, t_s, due, x_meas, q_meas)
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
    gate_sigmas: float = 0.0
    """The innovation gate (:meth:`Estimator.frame`), in standard deviations of the innovation
    (0: off, every frame is fused, the filter of before exactly). A frame is refused when the
    normalised innovation ``sqrt(sum_k y_k^2 / (P_k + R))`` over the three axes (``P_k`` the
    filter's position variance predicted to the frame's capture) exceeds this and the innovation's
    length exceeds ``gate_floor_m + gate_accel_mps2 tau^2 / 2`` (``tau``: since the last frame
    fused). 5 keeps a consistent filter's frames (chi-square, 3 degrees of freedom: 1.6e-5 refused)."""
    gate_floor_m: float = 0.03
    """A frame this close to the prediction [m] is never refused: 20 sigma of the lab's 1.5 mm
    innovations (1 mm noise plus the filter's own), so noise never trips the gate. Assumed; a
    swap of two drones this close cannot happen (two Crazyflies are 9 cm across)."""
    gate_accel_mps2: float = 1.0
    """The acceleration [m/s^2] the gate allows a drone beyond the one it predicts (its commands and
    its disturbance estimate) while it has no frame: the gate's reach grows as
    ``gate_accel_mps2 tau^2 / 2``, so a drone pushed by less than this is never locked out, however
    long it went unseen. Assumed: about twice the lab's 1-sigma thrust-to-mass departure
    (0.57 m/s^2, before the disturbance estimate has found it)."""
    gate_reset_s: float = 1.0
    """After refusing every frame for this long [s] (from the first refused), the gate takes the next
    frame and starts the filter afresh from it: a filter that fused a wrong frame (a swap fused late,
    when its covariance had grown over the other drone) can be wrong and sure of itself, and nothing
    else would let it out. Assumed: twice the swaps' assumed 0.5 s, so a swap is refused whole."""

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
    age_s: float  # since the capture of the last frame fused (as the agent reckons it), however long the gap
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


REJECT_REASONS = ("jump", "after_gap", "in_run")
"""Why a frame was refused (:attr:`Estimator.rejected_reasons`): ``jump``, the frame right after one
fused (an outlier, a swap's first frame); ``after_gap``, the first frame after frames missed
(lost, dropped or occluded; a return far from where the drone was predicted); ``in_run``, a frame
after one refused (a swap's later frames)."""


@dataclass
class Estimator:
    """One agent's estimate of its own drone from motion-capture frames.

    Per control tick: :meth:`frame` for each frame that arrived, :meth:`estimate` for the
    state to act on, :meth:`command` with the acceleration it then commands.

    With ``p.gate_sigmas`` > 0 an implausible frame is refused and treated as lost: not fused, the
    filter coasts on the commands, its covariance and the estimate's age grow. Implausible: its
    position is beyond the gate in the filter's own innovation covariance *and* beyond the reach
    ``gate_floor_m + gate_accel_mps2 tau^2 / 2`` (``tau`` since the last frame fused). Re-acquiring
    after a gap needs no rule of its own: the prediction (the commanded motion and the disturbance
    estimate) stays near a drone that is seen again, and both the covariance and the reach grow
    with the gap, so a true return is fused at once, and a drone whose acceleration stays within
    ``gate_accel_mps2`` of the predicted one is never locked out. A rule that accepts frames once
    several agree with each other is not used: the frames of a swap agree with each other (they
    are the other drone's track), and that rule would fuse them. A swap is refused for as long as
    the other drone is beyond both the gate's grown covariance and its reach: with the lab's
    estimator, two drones 0.2 m or more apart, for 0.5 s (the reach is then 15.5 cm; the
    covariance's 5 sigma about 15 cm vertically, 7 cm across). Longer swaps of close drones can be
    fused, and a filter that fused a wrong frame is wrong and sure of itself (its disturbance
    estimate takes the jump): so, last, after ``gate_reset_s`` of refusing every frame it takes the
    next (``resets``). A frame fused beyond the statistical gate (on the reach, or on that reset)
    restarts the filter from it (:meth:`_restart`: its position, and no more trust in its velocity
    and disturbance than the gap allows), so one wrong or late frame cannot leave the filter
    confidently wrong (``reacquired``: on the reach). Counters: ``rejected``, ``rejected_reasons``
    (:data:`REJECT_REASONS`), ``reacquired``, ``resets``."""

    p: EstimatorParams
    x0_w: FloatArray  # (3,) m, world: the start
    q0: FloatArray  # (4,)
    t0_s: float = 0.0
    v0_w: FloatArray | None = None  # (3,) m/s, world: the start velocity (None: at rest), to initial_velocity_std_mps
    X: FloatArray = field(init=False)  # (3, 3): per axis position [m], velocity [m/s], disturbance [m/s^2] at t_fused_s
    P: FloatArray = field(init=False)  # (3, 3, 3)
    t_fused_s: float = field(init=False)
    stale: int = field(init=False, default=0)  # frames older than the last fused, dropped
    rejected: int = field(init=False, default=0)  # frames refused by the gate
    rejected_reasons: dict[str, int] = field(init=False)  # the refused, by REJECT_REASONS
    reacquired: int = field(init=False, default=0)  # frames fused on the gate's reach alone
    resets: int = field(init=False, default=0)  # frames fused after gate_reset_s of refusals
    _seq: int = field(init=False, default=-1)
    _run: int = field(init=False, default=0)  # frames refused since the last fused
    _run_t_s: float = field(init=False, default=0.0)  # the capture time of the run's first
    _t_frame_s: float = field(init=False)  # the capture time of the last frame fused (the start: t0_s)
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
        self.t_fused_s = self._t_frame_s = self.t0_s
        self.rejected_reasons = dict.fromkeys(REJECT_REASONS, 0)
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
        self._moved_to(t_s)

    def _moved_to(self, t_s: float) -> None:
        self.t_fused_s = t_s
        while len(self._cmds) > 1 and self._cmds[1][0] <= t_s:
            self._cmds.pop(0)

    def frame(self, f: MocapFrame) -> bool:
        """Fuse a frame; False (and counted) if it is older than the last one fused (by its
        frame number, or by its capture time as the agent reckons it), or, with the gate on,
        implausible (``rejected``; the class docstring)."""
        t_c = f.t_arrival_s - self.p.latency_s
        if f.seq <= self._seq or t_c < self.t_fused_s:
            self.stale += 1
            return False
        if self.p.gate_sigmas > 0.0:
            if not self._gated(f, t_c):
                return False
        else:
            self._seq = f.seq
            self._advance(t_c)
            _update(self.X, self.P, np.asarray(f.x_w, float), self.p.r2_m2)
        self._attitude(f, t_c)
        return True

    def _gated(self, f: MocapFrame, t_c: float) -> bool:
        """The gate on a frame captured at ``t_c`` [s]: fuse it (True) or refuse it (False, counted)."""
        p = self.p
        z = np.asarray(f.x_w, float)
        X, P = self.X.copy(), self.P.copy()
        self._propagate(X, P, self.t_fused_s, t_c)
        y = z - X[:, 0]
        d2 = float(np.sum(y * y / (P[:, 0, 0] + p.r2_m2)))
        dist = norm(y)
        tau = t_c - self._t_frame_s
        if d2 > p.gate_sigmas**2 and dist > p.gate_floor_m:
            if self._run and t_c - self._run_t_s >= p.gate_reset_s:
                self.resets += 1
            elif dist <= p.gate_floor_m + 0.5 * p.gate_accel_mps2 * tau * tau:
                self.reacquired += 1
            else:
                reason = "in_run" if self._run else ("jump" if f.seq == self._seq + 1 else "after_gap")
                self.rejected += 1
                self.rejected_reasons[reason] += 1
                if not self._run:
                    self._run_t_s = t_c
                self._run += 1
                return False
            self._restart(X, P, tau)
        self.X, self.P = X, P
        self._moved_to(t_c)
        self._seq, self._t_frame_s, self._run = f.seq, t_c, 0
        _update(self.X, self.P, z, p.r2_m2)
        return True

    def _restart(self, X: FloatArray, P: FloatArray, tau: float) -> None:
        """Before fusing a frame beyond the statistical gate, ``tau`` [s] after the last one fused:
        the filter's state ``X`` and covariance ``P`` at its capture (in place) stop trusting
        themselves: the position to be taken from the frame (its variance 1 m^2), the velocity off
        by up to what the allowed push and the disturbance estimated give over ``tau`` plus what it
        may have been off by at the start, the disturbance by itself and its initial deviation;
        the correlations dropped. The frames that follow find velocity and disturbance again, as
        from a start in motion."""
        p = self.p
        a = p.gate_accel_mps2 + np.abs(X[:, 2])
        for k in range(3):
            pvv = P[k, 1, 1] + (a[k] * tau) ** 2 + p.initial_velocity_std_mps**2
            pdd = P[k, 2, 2] + X[k, 2] ** 2 + p.initial_disturbance_std_mps2**2
            P[k] = 0.0
            P[k, 0, 0], P[k, 1, 1], P[k, 2, 2] = 1.0, pvv, pdd

    def _attitude(self, f: MocapFrame, t_c: float) -> None:
        """The attitude and the body rates from a frame fused, captured at ``t_c`` [s]."""
        q = np.asarray(f.q, float)
        q = q / norm(q)
        dt = t_c - self._q_t_s
        if dt > 0.0:
            rate = quat_log(quat_mul(quat_conj(self._q), q)) / dt
            a = dt / (self.p.rate_filter_s + dt) if self.p.rate_filter_s > 0 else 1.0
            self._Omega_b = self._Omega_b + a * (rate - self._Omega_b)
        self._q, self._q_t_s = q, t_c

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
        q = quat_mul(self._q, quat_exp(rates * min(max(t_s - self._q_t_s, 0.0), ATTITUDE_COAST_S)))
        return Estimate(
            t_s,
            X[:, 0].copy(),
            X[:, 1].copy(),
            q,
            rates.copy(),
            np.sqrt(P[:, 0, 0]),
            np.sqrt(P[:, 1, 1]),
            t_s - self._q_t_s,
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
