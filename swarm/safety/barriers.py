"""Collision-cone barriers, compiled with numba, one loop over rows. What each row kind
guarantees and why each liveness part exists: docs/design.md, "The barrier math"; the
formulas here.

A row is an obstacle seen from the agent: ``p`` the relative position obstacle centre
minus agent body centre [m, world], ``w = p'`` [m/s, world], ``r`` the full safety
radius [m], ``a`` a unit cylinder axis [world] or zeros for a sphere. Every barrier here
has gradients of the form

    dh/dp = a_p p + b_p w,        dh/dw = a_w p + b_w w + c_d d

with scalar coefficients per row (``d`` is the live row's direction, below):

| barrier | h | a_p | b_p | a_w | b_w | c_d |
|---|---|---|---|---|---|---|
| C3BF (paper, smoothed) | <p,w> + n(w) s | n/s | 1 | 1 | s/sqrt(\\|w\\|^2+eps^2) | 0 |
| C3BF (live) | <p,w> + s <d,w> | <d,w>/s | 1 | 1 | 0 | s |
| HO-CBF | <p,w> + gamma_ho s | gamma_ho/s | 1 | 1 | 0 | 0 |
| + horizon allowance | + (\\|p\\|^2 - r^2) / (2 tau) | + 1/tau | | | | |
| / \\|w\\|^lambda (free braking) | (row times \\|w\\|^lambda) | | | | - lambda h / \\|w\\|^2 | |
| escape (inside r) | <p,w>/\\|p\\| - v_esc | -<p,w>/\\|p\\|^3 | 1/\\|p\\| | 1/\\|p\\| | 0 | 0 |

with ``s = sqrt(|p|^2 - r^2)`` and the smoothed norm ``n = sqrt(|w|^2+eps^2) - eps``
(``n <= |w|``, so a non-negative smoothed h keeps the true one non-negative).
Cylinders use ``P p`` and ``P w`` with ``P = I - a a^T``; the gradients then lie in
range(P) and need no second projection. A row already inside ``r`` gets the escape
barrier (separate at ``v_esc``); a coincident pair is treated as if the obstacle were
``COINCIDENT_M`` below the agent, so the agent escapes upwards. No row produces NaN.

**Live rows** (the default of the filter). The exact C3BF ``h = <p,w> + |w| s`` is not
differentiable at ``w = 0``, where a swarm at rest sits (h = 0): there the exact
condition along ``w(t) ~ t a`` is ``<p,a> + s|a| >= 0``, any relative acceleration
outside the cone. The smoothed gradient collapses to ``<p, a> >= 0`` ("never towards the
centre"), and a few obstacles around leave only ``a = 0``: the swarm freezes. For any
``|d| <= 1``, ``|w| >= <d,w>``, so

    h >= h_d := <p, w> + s <d, w>                                        (1)

and ``h_d`` is smooth. A live row is the CBF condition ``h_d' + gamma h_d >= 0`` with
``d`` held for the tick, where ``d`` is chosen so that ``h_d >= 0`` now (``d`` in
``D = {|d| <= 1, <p + s d, w> >= 0}``, which holds ``w/|w|`` whenever ``h >= 0``). Then
``h_d`` stays non-negative over the tick, and with it ``h`` by (1): the row is
sufficient for safety. At ``w = 0`` it is ``<p + s d, a> >= 0``, a half-space inside the
exact set that touches it along ``d`` when ``|d| = 1`` on the cone's boundary.

``d`` per row and tick (:func:`live_direction`): a target ``d*`` from the relative
acceleration ``a_ref`` the reference command would give: ``a_ref/|a_ref|`` where the
cone allows it, else the cone's nearest boundary generator in the plane of ``p`` and
``a_ref``; straight at the centre, or for a neighbour (another agent, whose own filter
must pick the opposite ``d`` for the pair to agree), the generator on the side
``e x p`` (``e`` = world up, or the cylinder axis; world x when ``p`` is vertical):
every agent deflects the same way round, and the pair's two rows are mirror images
(``d_ji = -d_ij``), so each agent's half-space holds the other's. ``d*`` is moved into
``D`` and blended to the exact gradient ``w/|w|`` as ``|w|`` grows from ``w_lo`` to
``w_hi``: above ``w_hi`` the live row is the exact, unsmoothed C3BF row.

**A clear reference at rest** (still obstacles). Below ``w_lo`` the row of an obstacle
that is not another agent keeps ``d = d*`` unmoved when ``d*`` is the agent's own
reference and that reference clears every still obstacle's cone (``reference_clear``:
:func:`swarm.safety.constraints.free_target` kept it). A hovering drone drifts at a few
mm/s; where that drift points away from a wall, ``D`` excludes the way through its
doorway, and each pillar's row, moved into ``D``, forbids accelerating towards its centre:
together they admit only hovering. Unmoved, ``h_d`` may start below zero, by at most
``|w| (|p| + s)``; the row then asks ``h_d' + gamma h_d >= 0``, so ``h_d`` comes back at
rate gamma and ``h >= h_d`` stays above that start, and every acceleration a row admits
at ``w = 0`` lies outside the cone (``<p + s d*, a> >= 0`` with ``d*`` outside it). What
this gives up is ``h_d >= 0`` at the start, for relative speeds below ``w_lo``: the exact
h of such a velocity is at least ``-w_lo (|p| - s)`` (a few 1e-4 m^2/s).

Inside the cone (h < 0) at speed, where the exact row's gradient along the cone's axis is
about ``r^2 / (2|p|)`` long and only asks to brake, a live row is the barrier
``H = (r/|p|)(s w_perp - r w_par)`` (:func:`cone_row`; ``w_par`` the approach speed,
``w_perp`` the speed across p). Its safe set is the cone's, ``H <= h`` (Cauchy-Schwarz),
it equals h with the same gradient on the cone, and its lateral gradient is ``r`` long: a
head-on pair swerves. Its class-K gain is at least ``RECOVERY_PER_CONTACT`` over the time
to contact (coefficient ``RATE``). Within ``AXIS_BAND`` of the axis, where the lateral
speed is noise, it holds the generator on the side rule's side instead. What the gain
gives: the row asks ``H' >= g |H|`` with ``g >= 2 / T_c``, ``T_c = (|p| - r) / v_c`` the
time to contact at the closing speed ``v_c``, so ``|H(t)| <= |H(0)| exp(-2 int_0^t ds / T_c(s))``;
while the pair keeps its closing speed (``T_c = T_0 - t``) that is

    |H(t)| <= |H(0)| (1 - t / T_0)^2:

the violation shrinks with the square of the time left and vanishes as contact nears
(``T_c -> 0``), so at worst the pair grazes the safety radius. It does not promise to leave
the cone sooner: at half the time to contact a quarter of ``|H(0)|`` may remain.

**Far neighbours** (live rows only). The cone condition does not weaken with distance: a
neighbour 2 m away binds its row as hard as one close by. Two cases matter. In a crowd
settling at its goals every agent's small motions push the others (with ``rho < 1`` this
never settles). In a crowd converging from rest (a sphere swap) every pair's relative
velocity starts on its cone's axis; h grows only with the relative speed, and the paper's
rate ``h' >= -gamma h`` then lets a pair 2 m apart, still 10 s from contact, speed up
towards its cone by a few tenths of a m/s^2. A neighbour row with ``h > 0`` therefore asks
``h' + gamma k h >= 0`` with the gain factor (:func:`far_gain`)

    k = 1 + max(0, |p| / (FAR_GAIN_RADII r) - 1) * clip(1 - FAR_GAIN_CONTACT_S v_c / (|p| - r), 0, 1)

(``v_c = -<p, w>/|p|`` the closing speed, ``(|p| - r) / v_c`` the time to contact). ``k >= 1``
is continuous and bounded on the sensing ball, so ``gamma k h`` is a class-K function of h
for every state, and at ``h = 0`` the row is unchanged (``h' >= 0``): the set ``h >= 0``
stays forward invariant. What it gives up is the rate ``h' + gamma h >= 0`` for far pairs
that would not meet within ``FAR_GAIN_CONTACT_S`` (half the extra gain at twice that time,
all of it for a pair that is not closing); a pair that would meet within
``FAR_GAIN_CONTACT_S``, or within ``FAR_GAIN_RADII`` safety radii, keeps the paper's gain.
The rate a row allows is ``h' >= -gamma k h`` with ``k <= max(1, R / (FAR_GAIN_RADII r))``
for a neighbour within the sensing radius ``R`` (:data:`FAR_GAIN_RADII`; 9.4 at ``R = 3 m``
and ``r = 0.16 m``): up to about 9 gamma.

**Horizon allowance** (live rows, opt-in: ``filter.horizon_s = tau``). The cone forbids a
collision course however far away the contact is; ORCA truncates its velocity obstacles
at a time horizon. Every live row may instead use

    h_tau = h + (|p|^2 - r^2) / (2 tau) = <p, w> + |w| s + s^2 / (2 tau)      (2)

(and its lower bounds ``h_d``, ``H`` plus the same term, which stay lower bounds of
``h_tau``). ``h_tau >= h``, so its safe set holds the cone's; far away it admits a course
into the cone (head on, up to a closing speed of about ``|p| s^2 / (tau r^2)``), and the
allowance shrinks to 0 at contact. It is still collision-free: with ``S = |p|^2 - r^2``,
``h_tau >= 0`` gives ``S' = 2 <p, w> >= -2 |w| sqrt(S) - S / tau``, so S, like the cone's,
can at most reach 0, where ``h_tau = <p, w> >= 0`` (no approach): the same boundary as
the cone's grazing contact. Its w-gradient is the cone's, so a row still asks to turn
off the collision course rather than to brake.

Obstacle rows alone may have their own horizon (``filter.obstacle_horizon_s``), and an agent
flying a path planned round walls, at a gain that covers it, has one by default
(``swarm.tuning.obstacle_horizon_s``, 3 s): in a corridor or a doorway's line of sight the
cones of pillars far along the way leave the velocity a slit a few degrees wide, which the
velocity buffer can only widen by speeding up (agents flew 2.5 to 3 m/s through a corridor at
0.8 m/s, and one parked by a mouth was thrown back through it); their allowance opens the slit
while contact is far, and keeps nothing of it near a pillar. The path takes the agent round the
walls; the row keeps it collision-free.

**Contact horizon** (live neighbour rows, opt-in: ``filter.contact_s = T``). The cone
also forbids a collision course however slowly it closes: a crowd at rest converging on a
sphere's centre, every pair closing head on at a few cm/s, gets rows as hard as pairs
closing at speed, and contracts only as fast as it can swirl. A neighbour row may instead
relax its radius with the time to contact ``t_c = (|p| - r) / v_c`` (``v_c = -<p, w>/|p|``
the closing speed; ``t_c`` infinite when not closing):

    h_T = <p, w> + |w| S,   S = sqrt(|p|^2 - rho^2),   rho = r (1 - (1 - k) psi(t_c))   (3)

with ``psi`` the smoothstep from 0 at ``t_c = T`` to 1 at ``2 T`` and ``k`` =
``CONTACT_FLOOR`` (the radius never falls below ``k r``, so the cone keeps a gradient). The
live row is the row of ``h_T``: ``h_d`` with ``S`` for ``s`` and ``d`` in the relaxed cone,
plus rho's own gradient, ``dS = (g / S) dt_c`` with ``g = rho r (1 - k) psi'`` and
``t_c = N / D`` (``N = |p|^2 - r |p|``, ``D = -<p, w>``), which adds
``k_c (2 - r/|p|) D`` to ``a_p``, ``k_c N`` to ``b_p`` and to ``a_w`` (``k_c = <d, w> g /
(S D^2)``): so the row also answers for the radius it will have as the pair closes faster.
``rho <= r``, so ``h_T >= h``, and the two are equal where contact is less than ``T``
away. It is still collision-free: a pair closing at the safety radius has ``t_c = 0``,
hence ``rho = r`` and ``h_T = h``, and ``h_T >= 0`` there asks ``<p, w> >= 0`` as the cone
does. What it lets through, like ORCA's time horizon, is a slow approach, never a fast
one; obstacles keep the cone (``nb`` rows only).

**Free braking** (live rows, on by default: ``filter.free_braking``). The cone's
``h = |w| (<p, u> + s)``, ``u = w/|w|``, is the relative speed times an angular margin, so
braking a relative velocity without turning it lowers h in proportion: ``h' + gamma k h >= 0``
lets a relative speed decay no faster than ``exp(-gamma k t)`` (with ``rho < 1`` the agent's
share of that): an agent whose reference brakes a drift, past neighbours well outside their
cones, is held drifting. Any positive scaling of a barrier is a barrier with the same
safe set, so a row may be the condition of

    B = h / |w|^lambda,   0 <= lambda <= 1   (|w| > 0)                         (4)

which, multiplied by ``|w|^lambda > 0``, is ``h' - lambda h <w, w'> / |w|^2 + gamma k h >= 0``:
the row's ``b_w`` less ``lambda h / |w|^2``. h is homogeneous of degree 1 in w
(``<dh/dw, w> = h``), so at ``lambda = 1`` braking along w neither helps the row nor costs it.
At ``h = 0`` the row is the cone's ``h' >= 0`` whatever lambda, so ``h >= 0`` stays forward
invariant with lambda chosen per tick; for ``h > 0`` it asks ``h' >= -(gamma k - lambda
<w, w'> / |w|^2) h``, a class-K bound (``|w| >= w_hi`` and ``w'`` is bounded by the inputs).
That is the rate ``h' >= -(gamma k + lambda |w'| / |w|) h``, not ``h' >= -gamma k h``: braking
``|w'|`` a few m/s^2 at ``|w|`` down to ``w_hi`` (2 cm/s) lets h fall at hundreds per second
(200 /s measured in a swarm) while it stays non-negative. Free braking keeps ``h >= 0``
forward invariant, not the paper's rate.
A row takes ``lambda = max(0, min(1, 1 - v_c / BRAKE_CLOSING_MPS))`` (``v_c = -<p, w>/|p|`` the
closing speed) where its reference's relative acceleration brakes (``<w, a_ref> < 0``), it is
outside its cone (``h >= 0``) and above ``w_hi``; else ``lambda = 0``. A pair closing fast
keeps the paper's row: there braking is what the cone must price. An obstacle's row too: an
agent creeping at a few cm/s towards the slit between two pillars' cones, within their
velocity buffers, could otherwise neither brake (h falls with |w|) nor turn, and held that
creep for good. The
lambda of a row is held for the tick. A tick whose braking carries ``w`` through zero (the
plain row would have capped the braking near ``gamma |w|``) leaves ``h >= -|w+| (|p| - s)``,
``w+`` the relative velocity after it, no larger than the tick's change of velocity; the next
tick's recovery (``RATE``) takes that back.

**Keep-out ellipsoid** (rows of other drones, on by default: ``filter.ellipsoid``). A drone's
rotors blow a fast stream of air downwards, and a Crazyflie 0.2-0.3 m under another is pushed
down hard; Crazyswarm's planners keep an axis-aligned ellipsoid between two Crazyflies'
centres, 0.12 m across and 0.30 m up and down (jpreiss/smoothener, the downwash-aware planner
of Preiss et al. 2017: ``examples/no_obstacles/main_no_obstacles.m``, "robot-robot collision
ellipsoid [0.12 0.12 0.3]"; the firmware's collision avoidance keeps a tall ellipsoid for the
same reason: crazyflie-firmware ``src/modules/interface/collision_avoidance.h``). The row of
another drone (``OBSTACLE.is_agent``, whether it takes its share or not) keeps the ellipsoid of
radii ``r_xy = max(r, k_xy)`` across and ``r_z = max(r, k_z)`` along world up
(:func:`keep_out_frame`; ``r`` the row's safety radius, both bodies' radii and the margin; ``k``
the airframe pair's keep-out plus the margin: ``ROW_PARAMS.keep_xy``, ``keep_z``). In the frame
``S = diag(1, 1, r_xy / r_z)`` the ellipsoid is the ball of radius ``r_xy``, and the row is every
row of this module for ``(S p, S w)``, radius ``r_xy`` and reference ``S a_ref``: S is constant,
so ``(S p)' = S w`` and ``(S w)' = S w'``, and the row is the C3BF of a sphere in that frame with
everything this docstring says of it there (the paper's row, live rows, the inside-cone row,
the escape row, horizon allowance, contact horizon, free braking, far gain):
``h(S p, S w) < 0`` exactly when the straight relative motion ``p + t w`` enters the ellipsoid.
Its gradients map back by S (symmetric): ``dh/dp = S dh/dp'``, ``dh/dw = S dh/dw'``
(``BarrierRows.sz``). Where ``r_xy = r_z`` (no keep-out, or one within the sphere), ``S = I``
and the row is the sphere's, bit for bit. Obstacles keep their rows; a drone's row has no axis.
A row whose radius grew for its state's age (``OBSTACLE.grow``: the prediction bounds and a lost
neighbour's growth, ``swarm.net.neighbours``) keeps the ellipsoid of ``k + grow`` on both axes,
which holds every point within ``grow`` of the ellipsoid of ``k``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np
from numba import njit

from swarm.rotation import BoolArray, FloatArray

COINCIDENT_M = 1e-3
"""Distance below which p is replaced by (0, 0, -COINCIDENT_M) for the escape row."""


class BarrierKind(StrEnum):
    """Which barrier builds the rows."""

    C3BF = "c3bf"
    """Collision cone: ``h = <p, w> + |w| sqrt(|p|^2 - r^2)`` (the paper)."""
    HOCBF = "hocbf"
    """Higher-order CBF baseline: ``h = <p, w> + gamma_ho sqrt(|p|^2 - r^2)``."""

    @property
    def code(self) -> int:
        return 0 if self is BarrierKind.C3BF else 1


# columns of the coefficient array returned by the kernels
H, A_P, B_P, A_W, B_W, PW, WW, C_D, RATE = range(9)
N_COEF = 9
RECOVERY_PER_CONTACT = 2.0
"""Inside the cone a live row's class-K gain is at least this over the time to contact
[unit-free]: while the pair keeps its closing speed the row's violation ``|H|`` shrinks at
least as ``(1 - t / T_0)^2``, ``T_0`` the time to contact (module docstring, inside the cone)."""

FAR_GAIN_RADII = 2.0
"""A neighbour row's class-K gain grows with distance beyond this many safety radii
(:func:`far_gain`) [unit-free]."""
FAR_GAIN_CONTACT_S = 1.0
"""... times ``1 - FAR_GAIN_CONTACT_S / (time to contact)``: none for a pair that would meet
within this [s], all of it for one that is not closing."""

LIVE_W_LO_MPS = 0.005
"""Below this relative speed [m/s] a live row's direction is the target ``d*`` alone (moved
into ``D`` unless it is a clear reference: module docstring)."""
LIVE_W_HI_MPS = 0.02
"""From this relative speed [m/s] up a live row is the exact C3BF row (``d = w/|w|``)."""
_TINY = 1e-12
BRAKE_CLOSING_MPS = 0.5
"""Free braking (module docstring) fades out as a pair's closing speed grows to this [m/s]."""
CONTACT_FLOOR = 0.1
"""The contact horizon relaxes a neighbour's radius to this fraction of it, not to nothing:
the cone stays a cone (a zero radius would leave the row without a gradient)."""

ROW_PARAMS = np.dtype(
    [
        ("kind", "i8"),  # BarrierKind.code: 0 C3BF, 1 HO-CBF
        ("gamma", "f8"),  # class-K gain [1/s]
        ("rho", "f8"),  # responsibility share of neighbour rows, (0, 1]
        ("r_own", "f8"),  # added to each obstacle's radius [m]: the agent's bounding radius and margin
        ("eps", "f8"),  # smoothing of |w| [m/s] (paper rows)
        ("gamma_ho", "f8"),  # HO-CBF gain [m/s]
        ("v_esc", "f8"),  # separation speed asked inside a safety radius [m/s]
        ("live", "?"),  # C3BF rows are live rows (module docstring)
        ("w_lo", "f8"),  # live rows: below this relative speed [m/s] the target alone
        ("w_hi", "f8"),  # live rows: from this relative speed [m/s] the exact C3BF row
        ("inv_tau", "f8"),  # live rows: 1 / the time horizon [1/s] (0: no horizon allowance)
        ("inv_tau_obs", "f8"),  # live obstacle rows (not other agents): 1 / their time horizon [1/s] (0: inv_tau)
        ("buffer", "f8"),  # live rows: velocity buffer [m/s] of the tightened rows (0: none)
        ("t_contact", "f8"),  # live neighbour rows: contact time [s] beyond which the radius relaxes (0: never)
        ("free_brake", "?"),  # live rows: free braking (module docstring)
        ("keep_xy", "f8"),  # rows of other drones: keep-out radius across [m], margin included (0: the sphere)
        ("keep_z", "f8"),  # ... and along world up [m] (module docstring, "Keep-out ellipsoid")
    ],
    align=True,
)
"""The row settings the compiled kernels take, as a (1,) structured array (numba reads
its fields by name; a structured array passes into a kernel as fast as a plain one)."""


@dataclass(frozen=True)
class RowSettings:
    """What every row of one filter shares: the filter's settings in the rows' terms.
    ``live`` applies to C3BF rows only; ``horizon_s``, ``buffer_mps`` to live rows;
    ``contact_s`` to live neighbour rows; ``free_braking`` to live rows; ``obstacle_horizon_s``
    to live obstacle rows."""

    gamma: float = 1.0  # class-K gain [1/s]
    rho: float = 1.0  # responsibility share of neighbour rows, (0, 1]
    r_own_m: float = 0.0  # added to each obstacle's radius [m]: the agent's bounding radius and margin
    eps: float = 1e-3  # smoothing of |w| [m/s] (paper rows)
    gamma_ho: float = 1.0  # HO-CBF gain [m/s]
    escape_speed: float = 0.3  # separation speed asked inside a safety radius [m/s]
    live: bool = False  # C3BF rows are live rows ("Live rows")
    w_lo_mps: float = LIVE_W_LO_MPS  # live rows: below this relative speed [m/s] the target alone
    w_hi_mps: float = LIVE_W_HI_MPS  # live rows: from this relative speed [m/s] the exact C3BF row
    horizon_s: float | None = None  # live rows: the horizon allowance's time [s] (None: none)
    obstacle_horizon_s: float | None = None  # live obstacle rows: their horizon allowance's time [s] (None: horizon_s)
    buffer_mps: float = 0.0  # live rows: the velocity buffer [m/s] (0: none)
    contact_s: float = 0.0  # live neighbour rows: the contact horizon [s] (0: none)
    free_braking: bool = False  # live rows: free braking
    keep_out_xy_m: float = 0.0  # rows of other drones: keep-out radius across [m], margin included (0: the sphere)
    keep_out_z_m: float = 0.0  # ... and along world up [m] ("Keep-out ellipsoid")


def row_params(kind: BarrierKind = BarrierKind.C3BF, settings: RowSettings | None = None) -> np.ndarray:
    """``settings`` (default :class:`RowSettings`) for rows of ``kind`` as the (1,)
    :data:`ROW_PARAMS` array the kernels take."""
    kind = BarrierKind(kind)
    st = settings or RowSettings()
    live = st.live and kind is BarrierKind.C3BF
    out = np.zeros(1, dtype=ROW_PARAMS)
    out[0] = (
        kind.code,
        st.gamma,
        st.rho,
        st.r_own_m,
        st.eps,
        st.gamma_ho,
        st.escape_speed,
        live,
        st.w_lo_mps,
        st.w_hi_mps,
        0.0 if st.horizon_s is None else 1.0 / st.horizon_s,
        0.0 if st.obstacle_horizon_s is None else 1.0 / st.obstacle_horizon_s,
        st.buffer_mps if live else 0.0,
        st.contact_s if live else 0.0,
        st.free_braking and live,
        st.keep_out_xy_m,
        st.keep_out_z_m,
    )
    return out


@njit(cache=True)
def _unit_side(P, pp, a, out):
    """``e x p / |e x p|`` into ``out`` (3,): ``e`` = the cylinder axis ``a``, or world up
    for a sphere (world x when ``p`` is nearly vertical). Odd in ``p``."""
    if a[0] == 0.0 and a[1] == 0.0 and a[2] == 0.0:
        e0, e1, e2 = 0.0, 0.0, 1.0
        if P[0] * P[0] + P[1] * P[1] < 1e-6 * pp:
            e0, e2 = 1.0, 0.0
    else:
        e0, e1, e2 = a[0], a[1], a[2]
    out[0] = e1 * P[2] - e2 * P[1]
    out[1] = e2 * P[0] - e0 * P[2]
    out[2] = e0 * P[1] - e1 * P[0]
    n = math.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2])
    for k in range(3):
        out[k] /= n


@njit(cache=True)
def _generator(P, V, pp, s, a, t, d):
    """The cone's boundary generator nearest to direction ``V`` (3,), in the plane of
    ``P`` and ``V`` (the side ``e x p`` when ``V`` is along ``P``), into ``d``; ``t`` is
    scratch (3,). The cone: half-angle ``asin(r/|P|)`` about ``-P``."""
    rp = math.sqrt(pp)
    vp = (V[0] * P[0] + V[1] * P[1] + V[2] * P[2]) / pp
    for k in range(3):
        t[k] = V[k] - vp * P[k]
    nt = math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
    nv = math.sqrt(V[0] * V[0] + V[1] * V[1] + V[2] * V[2])
    # V within 1e-6 rad of P's line: the side rule (t would be V's rounding error, magnified by 1/nt)
    if nt <= 1e-6 * nv or nt == 0.0:
        _unit_side(P, pp, a, t)
    else:
        for k in range(3):
            t[k] /= nt
    tp = (t[0] * P[0] + t[1] * P[1] + t[2] * P[2]) / pp  # re-orthogonalise (t of a near-parallel V)
    ta = t[0] * a[0] + t[1] * a[1] + t[2] * a[2]  # and keep it across a cylinder's axis (a = 0: a sphere)
    for k in range(3):
        t[k] -= tp * P[k] + ta * a[k]
    nt = math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
    cphi, sphi = s / rp, math.sqrt(max(pp - s * s, 0.0)) / rp
    for k in range(3):
        d[k] = -cphi * P[k] / rp + sphi * t[k] / nt


AXIS_BAND = 1e-4
"""Inside the cone, within this angle [rad] of its axis (lateral speed below
``AXIS_BAND |w|``), a live row turns to the side rule's side rather than to the lateral
speed, which there is noise (an exactly symmetric swap measured 1e-5 |w|)."""


@njit(cache=True)
def _inside_direction(P, W, pp, s, a, t, d):
    """Inside the cone: the generator nearest to ``W``, with the side rule's side ``e x p``
    added to ``W``'s lateral part at ``AXIS_BAND |W|`` (odd in ``P``, ``W``)."""
    nw = math.sqrt(W[0] * W[0] + W[1] * W[1] + W[2] * W[2])
    _unit_side(P, pp, a, t)
    eps = AXIS_BAND * nw
    V = np.empty(3)
    wp = (W[0] * P[0] + W[1] * P[1] + W[2] * P[2]) / pp
    for k in range(3):
        V[k] = W[k] - wp * P[k] + eps * t[k] - P[k]  # lateral part, biased, then along -p
    _generator(P, V, pp, s, a, t, d)


@njit(cache=True)
def live_direction(P, W, A, s, pp, a, has_ref, side_only, ref_clear, w_lo, w_hi, d):
    """The live row's direction ``d`` (3,) [unit-free, |d| <= 1, in range(P)] into ``d``,
    for the projected ``P`` = p [m], ``W`` = w [m/s], ``A`` = a_ref [m/s^2] of one row
    (``s = sqrt(|P|^2 - r^2) > 0``, ``pp = |P|^2``). See the module docstring.

    ``has_ref``: ``A`` is the reference's relative acceleration (else no target but the
    side rule for ``side_only`` rows, and ``d* = 0`` for the others); ``side_only``: a
    neighbour, whose target is always the side generator (odd in ``p``, so two agents'
    rows of one pair agree); ``ref_clear``: ``A`` is the agent's own reference, clear of every
    still obstacle's cone, which below ``w_lo`` is kept unmoved (module docstring, "A clear
    reference at rest"). Where ``h < 0`` (inside the cone) the fast direction is the
    boundary generator nearest to ``w`` rather than ``w/|w|``: any ``|d| <= 1`` bounds
    ``h`` from below there. Returns ``<d, W>``."""
    t = np.empty(3)
    aa = A[0] * A[0] + A[1] * A[1] + A[2] * A[2]
    clear = False  # d* is the agent's own reference, clear of every still obstacle's cone
    # the target d*
    if side_only:
        _generator(P, P, pp, s, a, t, d)
    elif has_ref and aa > _TINY:
        na = math.sqrt(aa)
        if (P[0] * A[0] + P[1] * A[1] + P[2] * A[2]) / na + s >= 0.0:  # outside the cone: the reference itself
            clear = ref_clear
            for k in range(3):
                d[k] = A[k] / na
        else:  # inside: the nearest generator, in the plane of p and a_ref
            _generator(P, A, pp, s, a, t, d)
    else:
        d[0], d[1], d[2] = 0.0, 0.0, 0.0
    ww = W[0] * W[0] + W[1] * W[1] + W[2] * W[2]
    nw = math.sqrt(ww)
    if nw <= _TINY:  # at rest relative to it: any |d| <= 1 keeps h_d = 0 = h (to 1e-12)
        return d[0] * W[0] + d[1] * W[1] + d[2] * W[2]
    u = np.empty(3)
    for k in range(3):
        u[k] = W[k] / nw
    c0 = -(P[0] * u[0] + P[1] * u[1] + P[2] * u[2]) / s  # d in D  <=>  <d, w/|w|> >= c0
    fast = np.empty(3)
    if c0 > 1.0:  # h < 0: D is empty and any |d| <= 1 is a lower bound; fast: the nearest generator
        _inside_direction(P, W, pp, s, a, t, fast)
    else:
        for k in range(3):
            fast[k] = u[k]
        du = d[0] * u[0] + d[1] * u[1] + d[2] * u[2]
        if du < c0 and d[0] == 0.0 and d[1] == 0.0 and d[2] == 0.0:  # no target: D's point nearest to 0
            for k in range(3):
                d[k] = c0 * u[k]
        elif du < c0 and not (clear and nw <= w_lo):  # move d* into D: the unit vector at <d, u> = c0 nearest to it
            for k in range(3):
                t[k] = d[k] - du * u[k]
            nt = math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
            if nt < 1e-9:
                _unit_side(W, ww, a, t)
            else:
                for k in range(3):
                    t[k] /= nt
                tu = t[0] * u[0] + t[1] * u[1] + t[2] * u[2]  # once more across u (d* near -u: t is a small difference)
                for k in range(3):
                    t[k] -= tu * u[k]
                nt = math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
                for k in range(3):
                    t[k] /= nt
            q = math.sqrt(max(1.0 - c0 * c0, 0.0))
            for k in range(3):
                d[k] = c0 * u[k] + q * t[k]
    lam = 1.0 if nw <= w_lo else (0.0 if nw >= w_hi else (w_hi - nw) / (w_hi - w_lo))
    for k in range(3):
        d[k] = lam * d[k] + (1.0 - lam) * fast[k]
    return d[0] * W[0] + d[1] * W[1] + d[2] * W[2]


@njit(cache=True)
def cone_row(r, s, pp, pw, ww):
    """``H = (r/|p|)(s w_perp - r w_par)`` and its coefficients (h, a_p, b_p, a_w, b_w),
    for a row inside the cone off its axis (``w_perp > 0``): ``w_par = -<p,w>/|p|`` is the
    approach speed [m/s], ``w_perp`` the speed across ``p``. ``H <= h`` everywhere (Cauchy-
    Schwarz), ``H = h = 0`` on the cone with the same gradient, and H is smooth off the
    axis; on the axis its w-gradient is ``r`` long where h's is about ``r^2 / (2|p|)``."""
    rp = math.sqrt(pp)
    c = pw / rp  # = -w_par
    wperp = math.sqrt(max(ww - c * c, 0.0))
    H = r / rp * (s * wperp + r * c)
    k = (r * wperp - s * c) / (rp * wperp)
    a_p = -H / pp + r * wperp / (rp * s) - r * c * k / pp
    b_p = r * k / rp
    return H, a_p, b_p, b_p, r * s / (rp * wperp)


@njit(cache=True)
def contact_radius(r, pp, pw, T):
    """The contact horizon's radius (module docstring, "Contact horizon") for ``pp = |p|^2``
    [m^2] outside the safety radius ``r`` [m], ``pw = <p, w>`` [m^2/s] and ``T`` [s] > 0:
    (rho [m], g [m^2/s]) with ``rho = r (1 - (1 - CONTACT_FLOOR) psi(t_c))`` and
    ``g = rho r (1 - CONTACT_FLOOR) psi'(t_c)``, so that ``S = sqrt(|p|^2 - rho^2)`` has
    ``dS/dt_c = g / S``. ``t_c = (|p| - r) |p| / -<p, w>`` is the time to contact at the
    closing speed (infinite when not closing), ``psi`` the smoothstep from 0 at ``t_c = T``
    to 1 at ``2 T``."""
    rp = math.sqrt(pp)
    num = (rp - r) * rp  # m^2
    den = -pw * T  # m^2 (can underflow to 0 for a closing speed of a few 1e-324 m/s)
    if den <= 0.5 * num:  # not closing, or t_c >= 2 T
        return CONTACT_FLOOR * r, 0.0
    x = num / den - 1.0  # (den > 0.5 num > 0)
    if x <= 0.0:
        return r, 0.0
    if x >= 1.0:
        return CONTACT_FLOOR * r, 0.0
    rho = r * (1.0 - (1.0 - CONTACT_FLOOR) * x * x * (3.0 - 2.0 * x))
    return rho, rho * r * (1.0 - CONTACT_FLOOR) * 6.0 * x * (1.0 - x) / T


@njit(cache=True)
def keep_out_frame(r, keep_xy, keep_z):
    """A drone pair's keep-out ellipsoid (module docstring, "Keep-out ellipsoid") for a row
    of safety radius ``r`` [m] > 0 (both bodies' radii and the margin) and the airframe
    pair's keep-out radii ``keep_xy`` across and ``keep_z`` along world up [m] (0: none):
    the ellipsoid's radii are ``r_xy = max(r, keep_xy)`` and ``r_z = max(r, keep_z)``.
    Returns ``(r_xy, sz)``: in the frame ``S = diag(1, 1, sz)``, ``sz = r_xy / r_z``, the
    ellipsoid is the ball of radius ``r_xy``; ``(r, 1.0)`` without a keep-out."""
    r_xy = np.maximum(r, keep_xy)  # (elementwise: arrays of pairs too)
    return r_xy, r_xy / np.maximum(r, keep_z)


def scaled_distance(p: FloatArray, r_xy: FloatArray | float, r_z: FloatArray | float) -> FloatArray:
    """``|S p| / r_xy`` with ``S = diag(1, 1, r_xy / r_z)`` (:func:`keep_out_frame`'s frame) of
    each ``p`` (..., 3) [m, world]: below 1 exactly inside the axis-aligned ellipsoid of radii
    ``r_xy`` across and ``r_z`` along world up [m] about the origin [unit-free]."""
    p = np.asarray(p, dtype=float)
    r_xy = np.asarray(r_xy, dtype=float)
    sz = r_xy / np.asarray(r_z, dtype=float)
    return np.sqrt(p[..., 0] ** 2 + p[..., 1] ** 2 + (sz * p[..., 2]) ** 2) / r_xy


@njit(cache=True, fastmath=False)
def barrier_row(par, p, w, r, a, Y_out, coef_out, a_ref, has_ref, nb, ref_clear):
    """One row for relative ``p`` [m], ``w`` [m/s], safety radius ``r`` [m] and cylinder
    axis ``a`` (zeros for a sphere), under the settings ``par`` (a :data:`ROW_PARAMS`
    record: ``kind``, ``eps``, ``gamma_ho``, ``v_esc``, ``live``, ``w_lo``, ``w_hi``).
    Writes the (projected) p, w and the live direction d into ``Y_out`` (3, 3) and
    ``h, a_p, b_p, a_w, b_w, <p,w>, <w,w>, c_d, rate`` into ``coef_out`` (9,); returns
    inside. ``rate`` [1/s] is the least class-K gain of the row (non-zero inside the cone).

    With ``par.live`` C3BF rows are live rows (module docstring); ``a_ref`` (3,) [m/s^2,
    world] is the reference's relative acceleration (read when ``has_ref``); ``nb``: the
    obstacle is another agent (the side rule); ``ref_clear``: ``a_ref`` is the agent's own
    reference, clear of every still obstacle's cone (:func:`live_direction`)."""
    kind = par.kind
    ap = a[0] * p[0] + a[1] * p[1] + a[2] * p[2]
    aw = a[0] * w[0] + a[1] * w[1] + a[2] * w[2]
    for k in range(3):
        Y_out[0, k] = p[k] - ap * a[k]
        Y_out[1, k] = w[k] - aw * a[k]
        Y_out[2, k] = 0.0
    P = Y_out[0]
    W = Y_out[1]
    pp = P[0] * P[0] + P[1] * P[1] + P[2] * P[2]
    pw = P[0] * W[0] + P[1] * W[1] + P[2] * W[2]
    ww = W[0] * W[0] + W[1] * W[1] + W[2] * W[2]
    s2 = pp - r * r
    c_d = 0.0
    rate = 0.0
    if s2 > 0.0:
        s = math.sqrt(s2)
        if kind == 0 and par.live:
            aA = a[0] * a_ref[0] + a[1] * a_ref[1] + a[2] * a_ref[2]
            A = np.empty(3)
            for k in range(3):
                A[k] = a_ref[k] - aA * a[k]
            nw = math.sqrt(ww)
            rp = math.sqrt(pp)
            c = pw / rp
            rho_c, g_c = r, 0.0  # the contact horizon's radius [m] and rho r psi' [m^2/s]
            if nb and par.t_contact > 0.0:
                rho_c, g_c = contact_radius(r, pp, pw, par.t_contact)
                s = math.sqrt(pp - rho_c * rho_c)
            if pw + nw * s < 0.0:  # inside the cone, closing at -c: the gain 2 / (time to contact)
                rate = RECOVERY_PER_CONTACT * -c / (rp - r)
            band = AXIS_BAND * nw
            if rho_c == r and nw >= par.w_hi and pw + nw * s < 0.0 and ww - c * c > band * band:
                h, a_p, b_p, a_w, b_w = cone_row(r, s, pp, pw, ww)  # inside the full cone, moving, off the axis: H
            else:
                dw = live_direction(P, W, A, s, pp, a, has_ref, nb, ref_clear, par.w_lo, par.w_hi, Y_out[2])
                h, a_p, b_p, a_w, b_w, c_d = pw + s * dw, dw / s, 1.0, 1.0, 0.0, s
                if g_c > 0.0:  # rho's own gradient: dS = (g / S) dt_c, t_c = N / D (module docstring)
                    D = -pw
                    N = pp - r * rp
                    k_c = dw * g_c / max(s * D * D, 1e-300)  # (D > 0 here; the max for underflow)
                    a_p += k_c * (2.0 - r / rp) * D
                    b_p += k_c * N
                    a_w += k_c * N
            inv_tau = par.inv_tau_obs if not nb and par.inv_tau_obs > 0.0 else par.inv_tau
            if inv_tau > 0.0:  # the horizon allowance (module docstring): h + (|p|^2 - r^2) / (2 tau)
                h += 0.5 * s2 * inv_tau
                a_p += inv_tau
                if h >= 0.0:  # (the recovery gain is for rows that are violated)
                    rate = 0.0
            if par.free_brake and has_ref and nw >= par.w_hi and h >= 0.0:  # B = h / |w|^lambda
                lam = min(1.0, max(0.0, 1.0 + c / BRAKE_CLOSING_MPS))  # (c = -v_c)
                if lam > 0.0 and W[0] * A[0] + W[1] * A[1] + W[2] * A[2] < 0.0:
                    b_w -= lam * h / ww
            inside = False
        elif kind == 0:
            root = math.sqrt(ww + par.eps * par.eps)
            nw = root - par.eps
            h, a_p, b_w = pw + nw * s, nw / s, s / root
        else:
            h, a_p, b_w = pw + par.gamma_ho * s, par.gamma_ho / s, 0.0
        if kind != 0 or not par.live:
            b_p, a_w = 1.0, 1.0
            inside = False
    else:
        if pp < COINCIDENT_M * COINCIDENT_M:
            P[0], P[1], P[2] = 0.0, 0.0, -COINCIDENT_M
            pp = COINCIDENT_M * COINCIDENT_M
            pw = -COINCIDENT_M * W[2]
        d = math.sqrt(pp)
        h, a_p, b_p, a_w, b_w = pw / d - par.v_esc, -pw / (d * pp), 1.0 / d, 1.0 / d, 0.0
        inside = True
    coef_out[0] = h
    coef_out[1] = a_p
    coef_out[2] = b_p
    coef_out[3] = a_w
    coef_out[4] = b_w
    coef_out[5] = pw
    coef_out[6] = ww
    coef_out[7] = c_d
    coef_out[8] = rate
    return inside


@njit(cache=True)
def far_gain(p, w, r):
    """Gain factor ``k >= 1`` of a neighbour row's class-K term (module docstring, "Far
    neighbours"): ``p`` (3,) m and ``w`` (3,) m/s relative, ``r`` the safety radius [m]."""
    dist = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
    if dist <= FAR_GAIN_RADII * r:
        return 1.0
    closing = -(p[0] * w[0] + p[1] * w[1] + p[2] * w[2]) / dist  # m/s
    fade = min(1.0, max(0.0, 1.0 - FAR_GAIN_CONTACT_S * closing / (dist - r)))  # (dist - r > r > 0)
    return 1.0 + (dist / (FAR_GAIN_RADII * r) - 1.0) * fade


@njit(cache=True)
def barrier_rows(params, Y, r, axis, a_ref, has_ref, nb, ref_clear, sz):
    """All rows of stacked ``Y = [p; w]`` (n, 2, 3) under ``params`` (a (1,) :data:`ROW_PARAMS`
    array), row i in the frame ``S = diag(1, 1, sz[i])`` (module docstring, "Keep-out
    ellipsoid"; ``p``, ``w`` and ``a_ref`` scaled by it): returns (Y_used (n, 3, 3), coef
    (n, 9), inside), Y_used in each row's frame."""
    par = params[0]
    n = Y.shape[0]
    Y_out = np.empty((n, 3, 3))
    coef = np.empty((n, N_COEF))
    inside = np.empty(n, dtype=np.bool_)
    p = np.empty(3)
    w = np.empty(3)
    A = np.empty(3)
    for i in range(n):
        for k in range(3):
            p[k] = Y[i, 0, k]
            w[k] = Y[i, 1, k]
            A[k] = a_ref[i, k]
        p[2] *= sz[i]
        w[2] *= sz[i]
        A[2] *= sz[i]
        inside[i] = barrier_row(par, p, w, r[i], axis[i], Y_out[i], coef[i], A, has_ref, nb[i], ref_clear)
    return Y_out, coef, inside


@dataclass(slots=True)
class BarrierRows:
    """Barrier values and gradient coefficients of ``n`` rows."""

    Y: FloatArray  # (n, 3, 3) the (projected) p [m], w [m/s] and live direction d, in the row's frame (sz)
    coef: FloatArray  # (n, 9) columns H, A_P, B_P, A_W, B_W, PW, WW, C_D, RATE
    inside: BoolArray  # (n,): |P p| <= r, the row holds the escape barrier
    sz: FloatArray | None = None  # (n,) each row's frame S = diag(1, 1, sz) (keep-out ellipsoid); None: all 1

    @property
    def h(self) -> FloatArray:
        """(n,) barrier value [m^2/s] (escape rows: [m/s])."""
        return self.coef[:, H]

    @property
    def dh_dp(self) -> FloatArray:
        """(n, 3) gradient of h with respect to p [world] (``S dh/dp'`` in a row's frame)."""
        return self._world(self.coef[:, A_P, None] * self.Y[:, 0] + self.coef[:, B_P, None] * self.Y[:, 1])

    @property
    def dh_dw(self) -> FloatArray:
        """(n, 3) gradient of h with respect to w [world] (``S dh/dw'`` in a row's frame)."""
        c = self.coef
        return self._world(
            c[:, A_W, None] * self.Y[:, 0] + c[:, B_W, None] * self.Y[:, 1] + c[:, C_D, None] * self.Y[:, 2]
        )

    def _world(self, g: FloatArray) -> FloatArray:
        if self.sz is not None:
            g[:, 2] *= self.sz
        return g

    @property
    def d(self) -> FloatArray:
        """(n, 3) the live rows' direction (zeros for other rows)."""
        return self.Y[:, 2]


def evaluate(
    kind: BarrierKind,
    Y: FloatArray,
    r: FloatArray,
    axis_w: FloatArray | None = None,
    *,
    settings: RowSettings | None = None,
    a_ref: FloatArray | None = None,
    is_neighbour: BoolArray | None = None,
    reference_clear: bool = False,
    scale_z: FloatArray | None = None,
) -> BarrierRows:
    """Barrier rows for stacked ``Y = [p; w]`` (n, 2, 3) with ``settings`` (default
    :class:`RowSettings`). ``axis_w`` (n, 3) holds unit cylinder axes (zero rows for
    spheres); ``None`` means all spheres. Live C3BF rows take the reference relative
    accelerations ``a_ref`` (n, 3) [m/s^2, world] (``None``: no reference), the
    neighbour flags ``is_neighbour`` (n,) and ``reference_clear``: ``a_ref`` is the agent's
    own reference, clear of every still obstacle's cone (as the filter finds it:
    ``swarm.safety.constraints.free_target``; module docstring). ``scale_z`` (n,): each
    row's frame ``S = diag(1, 1, scale_z)``, the row that of ``(S p, S w)`` with radius
    ``r`` (module docstring, "Keep-out ellipsoid"; :func:`keep_out_frame` gives both for a
    drone pair); None: all 1, every row the sphere's."""
    Y = np.ascontiguousarray(Y, dtype=float)
    n = Y.shape[0]
    axis = np.zeros((n, 3)) if axis_w is None else np.ascontiguousarray(axis_w, dtype=float)
    A = np.zeros((n, 3)) if a_ref is None else np.ascontiguousarray(a_ref, dtype=float)
    nb = np.zeros(n, dtype=np.bool_) if is_neighbour is None else np.ascontiguousarray(is_neighbour, dtype=np.bool_)
    sz = np.ones(n) if scale_z is None else np.ascontiguousarray(np.broadcast_to(scale_z, (n,)), dtype=float)
    params = row_params(kind, settings)
    Y_used, coef, inside = barrier_rows(
        params, Y, np.ascontiguousarray(r, dtype=float), axis, A, a_ref is not None, nb, reference_clear, sz
    )
    return BarrierRows(Y_used, coef, inside, None if scale_z is None else sz)


def evaluate_pw(
    kind: BarrierKind,
    p: FloatArray,
    w: FloatArray,
    r: FloatArray,
    axis_w: FloatArray | None = None,
    *,
    a_ref: FloatArray | None = None,
    is_neighbour: BoolArray | None = None,
    reference_clear: bool = False,
    scale_z: FloatArray | None = None,
    **settings: Any,
) -> BarrierRows:
    """:func:`evaluate` for separate ``p`` and ``w`` (n, 3), with the fields of
    :class:`RowSettings` given by name."""
    Y = np.stack([p, w], axis=1)
    return evaluate(
        kind,
        Y,
        r,
        axis_w,
        settings=RowSettings(**settings),
        a_ref=a_ref,
        is_neighbour=is_neighbour,
        reference_clear=reference_clear,
        scale_z=scale_z,
    )


def horizon_allowance(p: FloatArray, r: FloatArray, axis_w: FloatArray | None = None) -> FloatArray:
    """``(|p|^2 - r^2) / 2`` [m^2] of each row (0 inside the safety radius), ``p`` and the
    axes as in :func:`cone_h`: times ``1 / tau`` it is what the horizon allowance adds to
    a row's h (module docstring, "Horizon allowance")."""
    p = np.asarray(p, dtype=float)
    if axis_w is not None:
        a = np.asarray(axis_w, dtype=float)
        p = p - np.sum(p * a, axis=-1, keepdims=True) * a
    return 0.5 * np.maximum(np.sum(p * p, axis=-1) - np.asarray(r, dtype=float) ** 2, 0.0)


def cone_h(
    p: FloatArray,
    w: FloatArray,
    r: FloatArray,
    axis_w: FloatArray | None = None,
    scale_z: FloatArray | None = None,
) -> tuple[FloatArray, BoolArray]:
    """The exact C3BF barrier ``h = <p, w> + |w| sqrt(|p|^2 - r^2)`` [m^2/s] of each row,
    as the paper defines it, and whether the row is inside its safety radius.

    ``p`` (n, 3) [m, world] obstacle centre minus body centre, ``w = p'`` (n, 3) [m/s,
    world], ``r`` (n,) the full safety radius [m], ``axis_w`` (n, 3) unit cylinder axes
    (zero rows for spheres; None: all spheres), projected out as the rows do. ``h < 0``
    exactly when the relative motion, held straight, would come closer than ``r``. For a
    row inside ``r`` (``|p| <= r``) the root is taken as 0, so there ``h = <p, w>`` (the
    rate the gap opens at, times ``|p|``); such a row is a margin violation however its h
    reads. Metrics take it from ground truth; it is not what a filter row holds (those
    are lower bounds of it, or other barriers: the module docstring).

    ``scale_z`` (n,): the rows of drone pairs' keep-out ellipsoids (module docstring,
    "Keep-out ellipsoid"), h of ``(S p, S w)`` with ``S = diag(1, 1, scale_z)`` and ``r`` the
    radius across: ``h < 0`` exactly when the straight relative motion enters the ellipsoid.
    None: all 1."""
    p = np.asarray(p, dtype=float)
    w = np.asarray(w, dtype=float)
    if scale_z is not None:
        sz = np.asarray(scale_z, dtype=float)
        p = np.concatenate([p[..., :2], (sz * p[..., 2])[..., None]], axis=-1)
        w = np.concatenate([w[..., :2], (sz * w[..., 2])[..., None]], axis=-1)
    if axis_w is not None:
        a = np.asarray(axis_w, dtype=float)
        p = p - np.sum(p * a, axis=-1, keepdims=True) * a
        w = w - np.sum(w * a, axis=-1, keepdims=True) * a
    pp = np.sum(p * p, axis=-1)
    r2 = np.asarray(r, dtype=float) ** 2
    s = np.sqrt(np.maximum(pp - r2, 0.0))
    h = np.sum(p * w, axis=-1) + np.linalg.norm(w, axis=-1) * s
    return h, pp <= r2
