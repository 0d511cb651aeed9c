"""Reference control: tracking of a path at a constant target speed, a geometric SO(3)
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
from swarm.rotation import E3, FloatArray, R_to_euler, norm, quat_to_R, quat_to_R_into, vee

_GAIN_FIELDS = (
    "kp_per_s",
    "kd_per_s",
    "brake_mps2",
    "kc_per_s",
    "max_horizontal_accel_mps2",
    "max_vertical_accel_mps2",
)
"""The fields of :class:`TrackingGains`, in the order of :data:`TRACKING`'s."""


@dataclass(frozen=True)
class TrackingGains:
    """Outer-loop gains of the path tracker."""

    kp_per_s: float = 3.0
    """Position error to velocity command [1/s] at the goal."""
    kc_per_s: float = 1.5
    """Cross-track error to velocity command [1/s]; corners are cut within ``speed / kc``
    of path ahead."""
    kd_per_s: float = 4.5
    """Velocity error to acceleration command [1/s]."""
    brake_mps2: float = 1.5
    """The deceleration [m/s^2] the tracker plans with to slow for a corner and stop at the goal."""
    max_horizontal_accel_mps2: float = 4.0
    max_vertical_accel_mps2: float = 3.0

    def __post_init__(self) -> None:
        for name in _GAIN_FIELDS:
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"TrackingGains.{name}: must be a finite number > 0, got {v!r}")


TRACKING = np.dtype(
    [
        ("kp", "f8"),  # 1/s: position gain at the goal
        ("kd", "f8"),  # 1/s: velocity gain
        ("brake", "f8"),  # m/s^2: planned deceleration
        ("kc", "f8"),  # 1/s: cross-track gain (and look-ahead speed / kc)
        ("a_h", "f8"),  # m/s^2: largest horizontal acceleration
        ("a_v", "f8"),  # m/s^2: largest vertical acceleration
    ],
    align=True,
)
""":class:`TrackingGains` as the tracker's compiled kernels take them, a (1,) structured array."""


class PathTracker:
    """Tracking of a polyline at a constant target speed, cutting its corners within ``cut_m``.

    The commanded velocity runs along the chord from the agent's closest path point to the
    path point ``speed / kc`` of path further (:meth:`aim`), or nearer where that chord would
    cut a corner by more than ``cut_m`` [m] (0: the path's own tangent, every corner flown as
    it turns), plus ``kc`` times the error across the chord; on the last leg within that
    ``speed / kc`` of the goal it runs straight from the agent to the goal, so an agent
    pushed off its path does not fly on beside its goal. Its size along the chord is the
    target speed, braking at ``brake_mps2`` to each corner's speed (:func:`corner_speeds`)
    and to a stop at the goal, where it ends as ``kp`` times the distance left. The commanded
    acceleration is ``kd`` times the velocity error plus the braking's own deceleration
    (feedforward), clipped. The segment index only moves forward, so a detour around an
    obstacle does not skip or repeat.
    """

    def __init__(
        self, waypoints_w: object, speed_mps: float, gains: TrackingGains | None = None, cut_m: float = 0.0
    ) -> None:
        W = check_finite("waypoints_w", waypoints_w)
        if W.ndim != 2 or W.shape[1] != 3 or W.shape[0] < 1:
            raise InputError(f"waypoints_w: expected shape (k >= 1, 3), got {W.shape}")
        if not (math.isfinite(speed_mps) and speed_mps > 0):
            raise InputError(f"speed_mps: must be a finite number > 0, got {speed_mps!r}")
        if not (math.isfinite(cut_m) and cut_m >= 0):
            raise InputError(f"cut_m: must be a finite number >= 0, got {cut_m!r}")
        if W.shape[0] == 1:
            W = np.vstack([W, W])
        self.W = W
        self.speed_mps = float(speed_mps)
        self.cut_m = float(cut_m)
        self.gains = gains or TrackingGains()
        seg_len = np.linalg.norm(np.diff(W, axis=0), axis=1)
        tail = np.concatenate([np.cumsum(seg_len[::-1])[::-1][1:], [0.0]])  # m of path after each segment
        head = np.concatenate([[0.0], np.cumsum(seg_len)[:-1]])  # m of path before each segment
        # per segment (k-1, 4): its length [m], the path after it [m], the speed [m/s] at its
        # end, the path before it [m]
        self._seg = np.column_stack([seg_len, tail, corner_speeds(W, self.speed_mps), head])
        g = self.gains
        self._gains = np.zeros(1, dtype=TRACKING)  # the gains as the compiled kernels read them
        self._gains[0] = tuple(getattr(g, name) for name in _GAIN_FIELDS)
        self.segment = 0

    @property
    def goal_w(self) -> FloatArray:
        return self.W[-1]

    def aim(self, x_w: FloatArray) -> FloatArray:
        """The path point [m, world] the tracker at ``x_w`` [m, world] steers along the chord
        to, from its closest path point (the class docstring); the goal within ``speed / kc``
        of it on the last leg, steered to from ``x_w`` itself."""
        self.segment, c, _, remaining = _path_point(self.W, self._seg, self.segment, np.asarray(x_w, dtype=float))
        last = self._seg[-1]
        ahead_m = self.speed_mps / self.gains.kc_per_s
        return _aim(self.W, self._seg, self.segment, last[3] + last[0] - remaining, c, ahead_m, self.cut_m)

    def reference(self, x_w: FloatArray) -> tuple[FloatArray, FloatArray, float]:
        """Closest path point [m, world], path tangent, remaining path length [m]."""
        self.segment, c, tangent, remaining = _path_point(self.W, self._seg, self.segment, np.asarray(x_w, dtype=float))
        return c, tangent, remaining

    def command(self, x_w: FloatArray) -> tuple[FloatArray, float]:
        """Commanded velocity [m/s, world] and the rate [1/s] at which its size falls per
        metre flown along it where the tracker brakes (0 at the target speed): the braking's
        feedforward, :meth:`desired_accel`'s ``brake_per_s``."""
        self.segment, v_des, slope = _desired_velocity(
            self.W, self._seg, self.segment, np.asarray(x_w, dtype=float), self.speed_mps, self._gains, self.cut_m
        )
        return v_des, slope

    def desired_velocity(self, x_w: FloatArray) -> FloatArray:
        """Commanded velocity [m/s, world] (:meth:`command`)."""
        return self.command(x_w)[0]

    def desired_accel(
        self, x_w: FloatArray, v_w: FloatArray, v_des_w: FloatArray | None = None, brake_per_s: float = 0.0
    ) -> FloatArray:
        """Commanded acceleration [m/s^2, world] (without gravity compensation) towards the
        commanded velocity ``v_des_w`` [m/s, world] (default: :meth:`command`'s, with its
        braking), less ``brake_per_s`` [1/s] times the velocity along it (the deceleration
        of a command that falls by that much per metre flown)."""
        if v_des_w is None:
            v_des, brake_per_s = self.command(x_w)
        else:
            v_des = np.asarray(v_des_w, dtype=float)
        return _desired_accel(v_des, np.asarray(v_w, dtype=float), brake_per_s, self._gains)

    def thrust_vector(
        self,
        model: QuadModel,
        x_w: FloatArray,
        v_w: FloatArray,
        v_des_w: FloatArray | None = None,
        brake_per_s: float = 0.0,
    ) -> FloatArray:
        """Desired thrust vector ``F_ref = m (a_des + g e3)`` [N, world]; ``v_des_w`` and
        ``brake_per_s`` as in :meth:`desired_accel`. Without ``v_des_w``, one compiled call
        does the whole tracker."""
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
                self.cut_m,
                p.mass_kg,
                p.g_mps2,
            )
            return F
        a = self.desired_accel(x_w, v_w, v_des_w, brake_per_s)
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
def _point_at(W, seg, s, out):
    """Write into ``out`` (3,) the point ``s`` [m] of path along ``W`` (clamped to its ends)."""
    i = 0
    last = seg.shape[0] - 1
    while i < last and s > seg[i + 1, 3]:
        i += 1
    L = seg[i, 0]
    t = 1.0 if L <= 1e-9 else min(max((s - seg[i, 3]) / L, 0.0), 1.0)
    for j in range(3):
        out[j] = W[i, j] + t * (W[i + 1, j] - W[i, j])


@njit(cache=True)
def _cuts_within(W, x, p, first, last, cut):
    """Whether every vertex ``W[first..last]`` lies within ``cut`` [m] of the chord from
    ``x`` to ``p`` [m, world] (a chord that cuts the corners between by at most that much)."""
    dd = 0.0
    for j in range(3):
        dd += (p[j] - x[j]) ** 2
    for k in range(first, last + 1):
        t = 0.0
        if dd > 1e-18:
            for j in range(3):
                t += (W[k, j] - x[j]) * (p[j] - x[j])
            t = min(max(t / dd, 0.0), 1.0)
        e = 0.0
        for j in range(3):
            e += (x[j] + t * (p[j] - x[j]) - W[k, j]) ** 2
        if e > (cut + 1e-9) ** 2:
            return False
    return True


@njit(cache=True)
def _aim(W, seg, segment, s0, c, ahead_m, cut):
    """The point (3,) [m, world] a tracker steers to from its closest path point ``c``
    [m, world], ``s0`` [m] along the path on segment ``segment``: ``ahead_m`` of path
    further, or the furthest point before that whose chord from ``c`` passes every corner
    between within ``cut`` [m] (with 0: at most the next corner, along the tangent)."""
    last = seg.shape[0] - 1
    total = seg[last, 3] + seg[last, 0]
    s1 = min(s0 + ahead_m, total)
    p = np.empty(3)
    _point_at(W, seg, s1, p)
    m = segment  # the last vertex strictly before s1 is W[m]
    while m < last and seg[m + 1, 3] < s1:
        m += 1
    if m == segment or _cuts_within(W, c, p, segment + 1, m, cut):
        return p
    v = m  # the furthest corner whose chord keeps the corners before it within the cut
    while v > segment + 1 and not _cuts_within(W, c, W[v], segment + 1, v - 1, cut):
        v -= 1
    lo, hi = seg[v, 3], min(seg[v, 3] + seg[v, 0], s1)  # then along its leg as far as the cut allows
    for j in range(3):
        p[j] = W[v, j]
    q = np.empty(3)
    for _ in range(10):
        mid = 0.5 * (lo + hi)
        _point_at(W, seg, mid, q)
        if _cuts_within(W, c, q, segment + 1, v, cut):
            lo = mid
            p[:] = q
        else:
            hi = mid
    return p


@njit(cache=True)
def _desired_velocity(W, seg, segment, x, speed, gains, cut):
    """(segment, v_des (3,) [m/s, world], brake [1/s]) of :meth:`PathTracker.command`;
    ``gains`` a (1,) :data:`TRACKING` array. Its size along the chord is the least of the
    target speed, the braking profile to a stop ``d`` [m] ahead (the goal: the longer of the
    path left and the straight line to it), ``sqrt(2 a (d - a / (2 kp^2)))``, which is
    ``kp d`` within ``a / kp^2`` of it (the same value and slope there), and
    ``sqrt(c^2 + 2 a d)`` to a corner's speed ``c`` ``d`` ahead: the time-optimal approach
    at the deceleration ``a``. ``brake`` is the least one's slope [1/s] along the path (0
    at the target speed). On the last leg within ``speed / kc`` of the goal (where the aim
    is the goal) it points from ``x`` straight at the goal, with no cross-track term."""
    segment, c, _, remaining = _path_point(W, seg, segment, x)
    g = gains[0]
    kp, a = g.kp, g.brake
    last = seg.shape[0] - 1
    to_goal = 0.0
    for j in range(3):
        to_goal += (W[last + 1, j] - x[j]) ** 2
    to_goal = math.sqrt(to_goal)  # m, straight to the goal
    d = max(remaining, to_goal)
    s, brake = speed, 0.0
    if d * kp * kp <= a:  # within a / kp^2 of the goal: kp d
        stop, slope = kp * d, kp
    else:
        stop = math.sqrt(2.0 * a * (d - 0.5 * a / (kp * kp)))
        slope = a / stop
    if stop < s:
        s, brake = stop, slope
    if segment < last:
        corner = seg[segment, 2]
        slow = math.sqrt(corner * corner + 2.0 * a * (remaining - seg[segment, 1]))
        if slow < s:
            s, brake = slow, a / slow
    v_des = np.zeros(3)
    if segment == last and remaining * g.kc <= speed:
        # the aim is the goal itself: straight at it from where the agent is (along the
        # chord from the closest point it would run beside a goal approached off the path)
        if to_goal > 1e-9:
            for j in range(3):
                v_des[j] = s * (W[last + 1, j] - x[j]) / to_goal
        return segment, v_des, brake
    total = seg[last, 3] + seg[last, 0]
    p = _aim(W, seg, segment, total - remaining, c, speed / g.kc, cut)
    # along the chord from the closest point to the aim (the tangent, where nothing is cut),
    # plus kc times the error across it
    u = np.empty(3)
    n = 0.0
    for j in range(3):
        u[j] = p[j] - c[j]
        n += u[j] * u[j]
    n = math.sqrt(n)
    if n < 1e-9:  # (not reached: short of the goal the aim lies ahead of c along the path)
        return segment, v_des, brake
    e_along = 0.0
    for j in range(3):
        u[j] /= n
        e_along += (c[j] - x[j]) * u[j]
    for j in range(3):
        v_des[j] = s * u[j] + g.kc * (c[j] - x[j] - e_along * u[j])
    return segment, v_des, brake


@njit(cache=True)
def _desired_accel(v_des, v, brake, gains):
    """``kd (v_des - v)`` less ``brake`` times the velocity along ``v_des`` (forward only)
    [m/s^2, world], horizontal part clipped to its norm limit and vertical part to its
    limit (``gains`` a (1,) :data:`TRACKING` array)."""
    g = gains[0]
    kd, a_h, a_v = g.kd, g.a_h, g.a_v
    n = math.sqrt(v_des[0] ** 2 + v_des[1] ** 2 + v_des[2] ** 2)
    along = 0.0
    if n > 1e-9 and brake > 0.0:
        along = max(0.0, (v[0] * v_des[0] + v[1] * v_des[1] + v[2] * v_des[2]) / n) * brake / n
    a = np.empty(3)
    for j in range(3):
        a[j] = kd * (v_des[j] - v[j]) - along * v_des[j]
    h = math.hypot(a[0], a[1])
    if h > a_h:
        a[0] *= a_h / h
        a[1] *= a_h / h
    a[2] = min(max(a[2], -a_v), a_v)
    return a


@njit(cache=True)
def _tracker_thrust(W, seg, segment, x, v, speed, gains, cut, mass, g):
    """(segment, F_ref (3,) [N, world]) of :meth:`PathTracker.thrust_vector` in one call."""
    segment, v_des, brake = _desired_velocity(W, seg, segment, x, speed, gains, cut)
    a = _desired_accel(v_des, v, brake, gains)
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
    hx, hy = float(heading_w[0]), float(heading_w[1])
    n = math.hypot(hx, hy)
    if n < 1e-9 or len(others_w) == 0:
        return np.zeros(3)
    follow = others_v_w is not None  # followed, not turned from: the agents ahead flying my way
    weight = _ahead_weight(
        np.asarray(x_w, dtype=float), hx, hy, n, others_w, others_v_w if follow else others_w, follow, trigger_m
    )
    weight = min(weight, 1.0)
    if cruise_mps is not None and cruise_mps > 0:
        weight *= min(1.0, n / cruise_mps)
    return np.array([hy / n, -hx / n, 0.0]) * (speed_mps * weight)  # (heading x e3, normalised)


@njit(cache=True)
def _ahead_weight(x, hx, hy, n, others, others_v, follow, trigger_m):
    """:func:`right_hand_bias`'s sum of ``1 - d / trigger_m`` over the others (k, 3) [m] in front
    of ``x`` (along the horizontal heading ``hx, hy`` of norm ``n`` [m/s]) within ``trigger_m``,
    less those flying this way (``follow``: their velocities ``others_v`` (k, 3) [m/s] along the
    heading at least :data:`FOLLOW_FRACTION` of its speed)."""
    total = 0.0
    for i in range(others.shape[0]):
        d0, d1, d2 = others[i, 0] - x[0], others[i, 1] - x[1], others[i, 2] - x[2]
        dist = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if d0 * hx + d1 * hy > 0 and dist < trigger_m:
            if not follow or others_v[i, 0] * hx + others_v[i, 1] * hy < FOLLOW_FRACTION * n * n:
                total += 1.0 - dist / trigger_m
    return total


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
    v_des, brake = tracker.command(x_w)
    bias = right_hand_bias(x_b_w, v_des, others_w, tiebreak[0], tiebreak[1], tracker.speed_mps, others_v_w)
    return tracker.thrust_vector(model, x_w, v_w, turned(v_des, bias), brake)


def turned(v_w: FloatArray, bias_w: FloatArray) -> FloatArray:
    """The commanded velocity ``v_w`` [m/s, world] with the tie-break's ``bias_w`` [m/s,
    world] added, scaled back to ``|v_w|`` where the sum is faster: the tie-break turns the
    commanded velocity and never speeds it up, so an agent's target speed stays its top
    reference speed (as ORCA's maximum speed is), and times to goal compare fairly
    (docs/design.md, "The barrier math")."""
    out = v_w + bias_w
    speed, faster = norm(v_w), norm(out)
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
        n = norm(F_w)
        b3 = F_w / n if n > 1e-9 else E3
        b1c = np.array([math.cos(yaw_des_rad), math.sin(yaw_des_rad), 0.0])
        b2 = np.cross(b3, b1c)
        nb2 = norm(b2)
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
