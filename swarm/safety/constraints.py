"""The constraint rows of the safety QP: Lie derivatives of the barriers
(:mod:`swarm.safety.barriers`) for both command levels, with the responsibility share and
the velocity buffer (why they exist: docs/design.md, "The barrier math").

For an obstacle with centre ``c`` and an agent body centre ``x_b = x + l R e3``::

    p = c - x_b,   w = c' - x_b',   w' = c'' + a0_own + A u

``a0_own`` and ``A`` are the agent's own (negated) body-centre acceleration, shared by
all rows; ``c''`` is the obstacle's. With ``h`` from :mod:`swarm.safety.barriers`::

    Lf_h = <dh_dp, w> + <dh_dw, c'' + a0_own>,   Lg_h = A^T dh_dw

and each row asks ``Lg_h u >= -(<dh_dw, c'' + a0_own> + rho <dh_dp, w> + sigma gamma h)``,
``rho = sigma = 1`` except for neighbours (``swarm.safety.filter``; docs/design.md).

**Responsibility share** (neighbour rows, ``rho`` in (0, 1]). An agent takes the share
``rho`` of the pair's relative drift ``<dh_dp, w>`` and, inside the cone (``h < 0``), of
the recovery ``gamma h`` (``sigma = rho``); outside it (``h > 0``) it keeps the whole
allowance ``gamma h`` of its own row (``sigma = 1``). Two agents whose shares add up to 1
then ask together, with ``h'`` the pair's true derivative under both commands,

    h' + kappa(h) >= 0,   kappa(h) = 2 g h for h >= 0,  g h for h < 0,

(``g`` the row's class-K gain: ``gamma`` times the far-neighbour gain outside the cone,
``max(gamma, rate)`` inside it; below), a CBF condition with the extended class-K function
``kappa`` (continuous, increasing, ``kappa(0) = 0``), so ``h >= 0`` stays forward invariant
as with any gain. Splitting the recovery keeps what each agent must do inside a cone as
small as with ``rho = 1``. With ``rho = 1`` each agent takes the whole condition, as if its neighbour
did nothing.

Rotor level, with ``M = J^-1 B[1:4]`` (J diagonal)::

    A = R K,  K = [-l M_y; l M_x; -B[0] / m]           (since l R hat(e3) M = R [-l M_y; l M_x; 0])
    a0_own = g e3 + R (-l Omega x (Omega x e3) + l hat(e3) Omega'_drift),
    Omega'_drift = -J^-1 (Omega x J Omega)

Attitude level (thrust-vector point mass): ``A = -I / m``, ``a0_own = g e3``, about the
body centre ``x + l R e3`` moving with the centre of mass (this level has no rotation
state), the point the roster reports for every other drone: a pair's two rows then see
mirrored ``p`` and ``w`` up to the body rates' term ``l R (Omega x e3)`` of a neighbour's
reported velocity, which this level leaves out of its own (docs/design.md, "What the rows
guarantee": taken in, it made swaps from rest fly least-violation ticks).

**Velocity buffer** (live rows; ``FilterConfig.buffer_mps``, default 0.1 m/s). A row with
class-K gain ``g k`` (``g = max(gamma, rate)``, ``k`` the far-neighbour factor, 1 for other
rows) asks ``h' + g k h >= 0``; its buffered form asks

    h' + g k h >= g k_b v |dh/dw|,   v = min(buffer, BUFFER_PER_SPEED |w|),
                                      k_b = min(k, BUFFER_FAR_GAIN_MAX)                  (B)

i.e. ``b - buffer`` in place of ``b`` with ``buffer = sigma g k_b v |dh/dw|``
(``Rows.buffer``). h is homogeneous of degree 1 in w, so ``h / |dh/dw|`` is, to first order,
how far [m/s] the relative velocity lies outside the cone; (B) makes it settle about
``v k_b / k`` outside rather than on the cone's boundary: ``v`` for ``k`` up to
``BUFFER_FAR_GAIN_MAX``, less for the farthest, slowest pairs (a far neighbour drifting
slowly needs little buffer).
The filter solves the QP with the buffered rows first and with the rows themselves only
if the buffered ones cannot all hold, so every command still satisfies
every row whenever the rows can hold: the buffer changes no guarantee, it only chooses among
the commands the rows admit. Why: the attitude level treats the commanded thrust vector as
the acceleration, while the firmware's attitude loop reaches it some 0.1 s later; a swarm
that rides its cones' boundaries then slips just inside some of them (h about -0.01 m^2/s
at 2 m), and an agent on several cones at once whose outward normals surround it has no
command that leaves them all: a least-violation tick, though it is far from contact. With
the buffer such slips stay outside the cones. ``v``
fades with the relative speed, so a swarm at rest, or flying side by side, keeps none and
settles where it is. A still obstacle the agent moves away from (``<p, w> > 0``) keeps
none either: its exact h is at least ``|w| s``, far from its cone, while a live row at a
few cm/s sits on the boundary of its direction set, where a buffer would forbid braking: an
agent drifting slowly away from a wall could then neither stop nor turn back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from swarm.model import CommandLevel, LinearInputSet, QuadModel, QuadState, body_point_into
from swarm.rotation import BoolArray, FloatArray, IntArray, quat_to_R_into
from swarm.safety.barriers import (
    A_P,
    A_W,
    B_P,
    B_W,
    C_D,
    N_COEF,
    PW,
    RATE,
    WW,
    BarrierKind,
    BarrierRows,
    H,
    RowSettings,
    barrier_row,
    far_gain,
    keep_out_frame,
    row_params,
)
from swarm.safety.obstacles import ObstacleArrays


@dataclass(slots=True)
class OwnAffine:
    """The agent's body-centre motion and ``-(body-centre acceleration) = a0_own + A u``."""

    xv_b: FloatArray  # (2, 3): body-centre position [m, world] and velocity [m/s, world]
    Aa: FloatArray  # (3, m + 1): [A | a0_own]; A in m/s^2 per N, a0_own in m/s^2, world

    @property
    def A(self) -> FloatArray:
        return self.Aa[:, :-1]

    @property
    def a0_own(self) -> FloatArray:
        return self.Aa[:, -1]


AIRFRAME = np.dtype(
    [
        ("rotor", "?"),  # rotor level (else the attitude level's thrust-vector point mass)
        ("l", "f8"),  # m: body centre above the centre of mass
        ("g", "f8"),  # m/s^2
        ("J", "f8", 3),  # kg m^2: inertia diagonal (body)
        ("mass", "f8"),  # kg
        ("K", "f8", (3, 4)),  # rotor level: A = R K [m/s^2 per N] (module docstring)
        ("Aa_att", "f8", (3, 4)),  # attitude level: the constant [A | a0_own]
    ],
    align=True,
)
"""The airframe constants the own-dynamics kernels take, as a (1,) structured array."""


@njit(cache=True)
def _own_rotor(x, v, q, Om, af):
    """Body-centre state and [A | a0_own] at the rotor level, for the :data:`AIRFRAME`
    record ``af``."""
    l, g, Jx, Jy, Jz, K = af.l, af.g, af.J[0], af.J[1], af.J[2], af.K  # noqa: E741
    R = np.empty((3, 3))
    quat_to_R_into(q, R)
    wx, wy, wz = Om[0], Om[1], Om[2]
    dx = -(Jz - Jy) * wy * wz / Jx  # Omega'_drift
    dy = -(Jx - Jz) * wz * wx / Jy
    k0 = (-l * (wz * wx + dy), l * (dx - wz * wy), l * (wx * wx + wy * wy))  # body vector of a0's part
    m = K.shape[1]
    xv_b = np.empty((2, 3))
    body_point_into(R, x, v, wx, wy, l, xv_b)
    Aa = np.empty((3, m + 1))
    for i in range(3):
        for j in range(m):
            Aa[i, j] = R[i, 0] * K[0, j] + R[i, 1] * K[1, j] + R[i, 2] * K[2, j]
        Aa[i, m] = R[i, 0] * k0[0] + R[i, 1] * k0[1] + R[i, 2] * k0[2]
    Aa[2, m] += g
    return xv_b, Aa


def airframe(level: CommandLevel, model: QuadModel) -> np.ndarray:
    """The (1,) :data:`AIRFRAME` array of ``model`` at ``level``: ``K`` (rotor level, with
    ``M = J^-1 B[1:4]``) and the attitude level's constant ``[A | a0_own]``."""
    p = model.params
    M = model.J_inv @ model.B[1:]
    out = np.zeros(1, dtype=AIRFRAME)
    af = out[0]
    af["rotor"] = level is CommandLevel.ROTORS
    af["l"], af["g"], af["J"], af["mass"] = p.l_m, p.g_mps2, (p.Ixx_kgm2, p.Iyy_kgm2, p.Izz_kgm2), p.mass_kg
    af["K"] = np.vstack([-p.l_m * M[1], p.l_m * M[0], -model.B[0] / p.mass_kg])
    af["Aa_att"] = np.column_stack([-np.eye(3) / p.mass_kg, [0.0, 0.0, p.g_mps2]])
    return out


class OwnDynamics:
    """Builds :class:`OwnAffine` each tick from the airframe constants (:func:`airframe`),
    computed once."""

    def __init__(self, level: CommandLevel, model: QuadModel) -> None:
        self.air = airframe(level, model)  # (its ``rotor`` field says the level)

    def __call__(self, state: QuadState) -> OwnAffine:
        return OwnAffine(*own_affine(self.air, state.x_w, state.v_w, state.q, state.Omega_b))


@njit(cache=True)
def own_affine(air, x, v, q, Om):
    """(xv_b, Aa) of :class:`OwnAffine` for the (1,) :data:`AIRFRAME` array ``air``: the
    rotor level's from the state, or at the attitude level the body centre ``x + l R e3``
    with the centre of mass's velocity and the constant ``Aa_att``."""
    af = air[0]
    if af.rotor:
        return _own_rotor(x, v, q, Om, af)
    R = np.empty((3, 3))
    quat_to_R_into(q, R)
    xv_b = np.empty((2, 3))
    body_point_into(R, x, v, 0.0, 0.0, af.l, xv_b)  # (this level has no rotation state)
    return xv_b, af.Aa_att.copy()


BUFFER_PER_SPEED = 0.1
"""Below ``buffer / BUFFER_PER_SPEED`` of relative speed a row's velocity buffer is this
fraction of the relative speed [unit-free]: none at rest (module docstring, (B))."""
BUFFER_FAR_GAIN_MAX = 3.0
"""A live neighbour row's buffer grows with its far-neighbour gain factor ``k`` up to this
factor [unit-free] (module docstring, (B))."""

RING = 16
"""Candidate directions per static cone in :func:`free_target` (around its boundary)."""


@njit(cache=True)
def _clear_of(v, Ps, ss, axes, szs, m):
    """``v`` (3,) [world] lies outside the first ``m`` cones (``Ps`` projected p and ``ss`` s
    in each cone's frame ``diag(1, 1, szs)``, axes)."""
    for i in range(m):
        a = axes[i]
        av = a[0] * v[0] + a[1] * v[1] + a[2] * v[2]
        pv = 0.0
        vv = 0.0
        for k in range(3):
            vk = v[k] - av * a[k]
            if k == 2:
                vk *= szs[i]
            pv += Ps[i, k] * vk
            vv += vk * vk
        if pv + ss[i] * math.sqrt(vv) < -1e-12:
            return False
    return True


@njit(cache=True)
def free_target(obs, sel, r_own, xv_b, A0, w_hi, keep_xy, keep_z):
    """The relative acceleration [m/s^2, world] the live rows of static obstacles aim at,
    for the obstacles ``obs[sel]`` (:data:`swarm.safety.obstacles.OBSTACLE`), safety radius
    ``r + r_own`` [m] (a drone taken whole: its keep-out ellipsoid with ``keep_xy``,
    ``keep_z`` [m], each cone in its own frame: ``swarm.safety.barriers.keep_out_frame``),
    the own body centre ``xv_b`` (2, 3).

    At rest relative to several obstacles the exact condition asks for one direction of
    relative acceleration outside every obstacle's cone; rows aimed at the reference
    ``A0`` one by one can together admit only ``a = 0``. This returns ``A0`` when its
    direction is clear of every cone of the non-neighbour rows slower than ``w_hi``
    [m/s] (and outside their radius), else the clear direction nearest to it among each
    cone's boundary generators (``RING`` around it, and the one nearest ``A0``, all 2 %
    outside), scaled to ``|A0|``; ``A0`` itself when none is clear."""
    n = sel.shape[0]
    Ps = np.empty((n, 3))
    ss = np.empty(n)
    axes = np.empty((n, 3))
    szs = np.empty(n)
    m = 0
    for i in range(n):
        ob = obs[sel[i]]
        if ob.is_nb:
            continue
        rr, sz = ob.r + r_own, 1.0
        if ob.is_agent:
            rr, sz = keep_out_frame(rr, keep_xy + ob.grow, keep_z + ob.grow)
        a = ob.axis
        ap, aw = 0.0, 0.0
        for k in range(3):
            ap += a[k] * (ob.c[k] - xv_b[0, k])
            aw += a[k] * (ob.cd[k] - xv_b[1, k])
        pp, ww = 0.0, 0.0
        for k in range(3):
            Ps[m, k] = ob.c[k] - xv_b[0, k] - ap * a[k]
            wk = ob.cd[k] - xv_b[1, k] - aw * a[k]
            if k == 2:
                Ps[m, k] *= sz
                wk *= sz
            pp += Ps[m, k] * Ps[m, k]
            ww += wk * wk
        if pp <= rr * rr or ww >= w_hi * w_hi:
            continue
        ss[m] = math.sqrt(pp - rr * rr)
        axes[m] = a
        szs[m] = sz
        m += 1
    na = math.sqrt(A0[0] * A0[0] + A0[1] * A0[1] + A0[2] * A0[2])
    if m == 0 or na < 1e-6 or _clear_of(A0, Ps, ss, axes, szs, m):
        return A0
    best = -2.0
    out = A0.copy()
    v = np.empty(3)
    e1 = np.empty(3)
    e2 = np.empty(3)
    Aj = A0.copy()  # A0 in the cone's frame
    for j in range(m):
        P = Ps[j]
        Aj[2] = A0[2] * szs[j]
        rp = math.sqrt(P[0] * P[0] + P[1] * P[1] + P[2] * P[2])
        sphi = min(1.0, 1.02 * math.sqrt(max(rp * rp - ss[j] * ss[j], 0.0)) / rp)
        cphi = math.sqrt(1.0 - sphi * sphi)
        # a frame about -P: e1 towards A0's lateral part (the nearest generator first), e2 = -P x e1
        ap = (Aj[0] * P[0] + Aj[1] * P[1] + Aj[2] * P[2]) / (rp * rp)
        for k in range(3):
            e1[k] = Aj[k] - ap * P[k]
        n1 = math.sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
        if n1 < 1e-9 * na:
            e1[0], e1[1], e1[2] = -P[1], P[0], 0.0
            if abs(P[2]) > 0.9 * rp:
                e1[0], e1[1], e1[2] = 0.0, -P[2], P[1]
            n1 = math.sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
        for k in range(3):
            e1[k] /= n1
        e2[0] = -(P[1] * e1[2] - P[2] * e1[1]) / rp
        e2[1] = -(P[2] * e1[0] - P[0] * e1[2]) / rp
        e2[2] = -(P[0] * e1[1] - P[1] * e1[0]) / rp
        for q in range(RING):
            th = 2.0 * math.pi * q / RING
            for k in range(3):
                v[k] = -cphi * P[k] / rp + sphi * (math.cos(th) * e1[k] + math.sin(th) * e2[k])
            a = axes[j]
            if a[0] != 0.0 or a[1] != 0.0 or a[2] != 0.0:  # a cylinder: keep A0's part along its axis
                aa = (a[0] * A0[0] + a[1] * A0[1] + a[2] * A0[2]) / na
                for k in range(3):
                    v[k] = v[k] * math.sqrt(max(1.0 - aa * aa, 0.0)) + aa * a[k]
            if szs[j] != 1.0:  # a generator of the cone's own frame, back in the world's, as a unit vector
                v[2] /= szs[j]
                nv = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
                for k in range(3):
                    v[k] /= nv
            score = (v[0] * A0[0] + v[1] * A0[1] + v[2] * A0[2]) / na
            if score > best and _clear_of(v, Ps, ss, axes, szs, m):
                best = score
                for k in range(3):
                    out[k] = na * v[k]
    return out


@njit(cache=True)
def rows_kernel(obs, sel, params, xv_b, Aa, u_ref, lb, ub, C, d):
    """All rows at once, row i for obstacle ``obs[sel[i]]`` (``obs`` an (n,)
    :data:`swarm.safety.obstacles.OBSTACLE` array; a selection indexes it, no copy), under the
    settings ``params`` (a (1,) :data:`swarm.safety.barriers.ROW_PARAMS` array: safety radius
    ``r + r_own``, responsibility share ``rho`` for neighbour rows, 1 for the others; module
    docstring, "Responsibility share"),
    for the own body centre ``xv_b`` and ``Aa`` = [A | a0_own] (:class:`OwnAffine`),
    stacked under the input rows ``C u <= d`` as one QP constraint set ``A u <= b_all``
    (barrier rows: ``G = -Lg_h``, ``b = -lower``), and the residuals ``b_all - A u_ref``
    of a reference command (an empty ``u_ref`` skips them) against those rows and the
    bounds ``lb <= u <= ub``. The live rows' target is the relative acceleration
    ``c'' + a0_own + A u_ref`` that ``u_ref`` would give (for the obstacles, its direction
    clear of all their cones: :func:`free_target`).

    The class-K gain of a row is ``max(gamma, rate)`` (``rate`` from the barrier: inside
    the cone, twice the inverse time to contact), times :func:`swarm.safety.barriers.far_gain`
    for a live neighbour row with ``h > 0``. With ``params.buffer`` each live row outside
    its safety radius also gets its velocity buffer (module docstring, (B); for a neighbour
    row with ``h > 0`` times the far gain, at most ``BUFFER_FAR_GAIN_MAX``): the buffered
    rows are ``b - buffer``, and ``u_ref`` counts as satisfying the rows only if it holds
    them.

    A row of another drone (``is_agent``) keeps the keep-out ellipsoid of ``params.keep_xy``,
    ``params.keep_z``, each plus the row's ``grow`` (:func:`swarm.safety.barriers.keep_out_frame`):
    its barrier is taken in the frame ``S = diag(1, 1, sz)`` where the ellipsoid is a ball (``S p``,
    ``S w``, ``S a_ref``; its
    far gain too), and its gradient in w maps back by S for ``Lg_h``, the own and the obstacle's
    accelerations and the buffer's ``|dh/dw|`` (a margin in world velocity).

    Returns (Y_used (n,3,3), coef (n,9), inside (n,), Lf_h (n,), A (k+n,m), b_all (k+n,),
    c_ref (k+n,), ref_ok, any_inside, buffer (n,), sz (n,)) where ``ref_ok`` says ``u_ref``
    satisfies every buffered row and bound, ``any_inside`` that some row is already inside
    its safety radius, and ``sz`` is each row's frame (1: the world's; Y_used is in it)."""
    par = params[0]
    kind, r_own, live = par.kind, par.r_own, par.live
    n = sel.shape[0]
    k_in = C.shape[0]
    m = Aa.shape[1] - 1
    Y = np.empty((n, 3, 3))
    coef = np.empty((n, N_COEF))
    inside = np.empty(n, dtype=np.bool_)
    Lf = np.empty(n)
    tight = np.zeros(n)
    scale = np.empty(n)
    A = np.empty((k_in + n, m))
    b = np.empty(k_in + n)
    A[:k_in] = C
    b[:k_in] = d
    with_ref = u_ref.shape[0] == m
    c_ref = np.empty(k_in + n if with_ref else 0)
    ref_ok = with_ref
    p = np.empty(3)
    w = np.empty(3)
    dp = np.empty(3)
    dw = np.empty(3)
    any_inside = False
    own_ref = np.zeros(3)  # a0_own + A u_ref [m/s^2, world]
    a_ref = np.empty(3)
    if with_ref:
        for k in range(3):
            acc = Aa[k, m]
            for j in range(m):
                acc += Aa[k, j] * u_ref[j]
            own_ref[k] = acc
    static_ref = own_ref
    any_static = False
    for i in range(n):
        any_static = any_static or not obs[sel[i]].is_nb
    ref_clear = False  # the reference itself is clear of every still obstacle's cone
    if with_ref and live and kind == 0 and any_static:  # (only obstacle rows share a target)
        static_ref = free_target(obs, sel, r_own, xv_b, own_ref, par.w_hi, par.keep_xy, par.keep_z)
        ref_clear = static_ref[0] == own_ref[0] and static_ref[1] == own_ref[1] and static_ref[2] == own_ref[2]
    for i in range(n):
        ob = obs[sel[i]]
        r, sz = ob.r + r_own, 1.0
        if ob.is_agent:  # another drone: the keep-out ellipsoid, a sphere in the frame diag(1, 1, sz)
            r, sz = keep_out_frame(r, par.keep_xy + ob.grow, par.keep_z + ob.grow)
        scale[i] = sz
        for k in range(3):
            p[k] = ob.c[k] - xv_b[0, k]
            w[k] = ob.cd[k] - xv_b[1, k]
            a_ref[k] = ob.cdd[k] + (own_ref[k] if ob.is_nb else static_ref[k])
        if sz != 1.0:
            p[2] *= sz
            w[2] *= sz
            a_ref[2] *= sz
        inside[i] = barrier_row(par, p, w, r, ob.axis, Y[i], coef[i], a_ref, with_ref, ob.is_nb, ref_clear)
        any_inside = any_inside or inside[i]
        co = coef[i]
        rel = 0.0  # <dh/dp, w>, in either frame
        own = 0.0
        for k in range(3):
            dp[k] = co[A_P] * Y[i, 0, k] + co[B_P] * Y[i, 1, k]
            dw[k] = co[A_W] * Y[i, 0, k] + co[B_W] * Y[i, 1, k] + co[C_D] * Y[i, 2, k]
            rel += dp[k] * Y[i, 1, k]
        dw[2] *= sz  # dh/dw = S dh/dw', world
        for k in range(3):
            own += dw[k] * (ob.cdd[k] + Aa[k, m])
        row = k_in + i
        for j in range(m):
            A[row, j] = -(dw[0] * Aa[0, j] + dw[1] * Aa[1, j] + dw[2] * Aa[2, j])
        Lf[i] = rel + own
        share = par.rho if ob.is_nb else 1.0  # of the drift (module docstring, "Responsibility share")
        share_h = 1.0 if co[H] > 0.0 else share  # of gamma h: the allowance is the agent's, a recovery shared
        gain = max(par.gamma, co[RATE])
        receding = not ob.is_nb and co[PW] > 0.0  # moving away from a still obstacle: no buffer
        if par.buffer > 0.0 and not inside[i] and not receding:
            v_buf = min(par.buffer, BUFFER_PER_SPEED * math.sqrt(co[WW]))  # m/s
            tight[i] = share_h * gain * v_buf * math.sqrt(dw[0] * dw[0] + dw[1] * dw[1] + dw[2] * dw[2])
        if ob.is_nb and live and co[H] > 0.0:
            k_far = far_gain(p, w, r)
            gain *= k_far
            tight[i] *= min(k_far, BUFFER_FAR_GAIN_MAX)
        b[row] = own + share * rel + share_h * gain * co[H]
    if with_ref:
        for row in range(k_in + n):
            acc = b[row]
            for j in range(m):
                acc -= A[row, j] * u_ref[j]
            c_ref[row] = acc
            if acc < (tight[row - k_in] if row >= k_in else 0.0):
                ref_ok = False
        for j in range(m):
            if not lb[j] <= u_ref[j] <= ub[j]:
                ref_ok = False
    return Y, coef, inside, Lf, A, b, c_ref, ref_ok, any_inside, tight, scale


@dataclass(slots=True)
class Rows:
    """``n`` barrier rows ``Lg_h u >= lower``, stored as ``G u <= b`` for the QP, under
    the ``k`` input rows (``A = [C; G]``, ``b_all = [d; b]``)."""

    barrier: BarrierRows
    Lf_h: FloatArray  # (n,)
    A: FloatArray  # (k + n, m)
    b_all: FloatArray  # (k + n,)
    c_ref: FloatArray  # (k + n,) b_all - A u_ref of the reference given to assemble (or empty)
    ref_ok: bool  # that reference satisfies every row and input bound
    k_in: int  # number of input rows on top
    any_inside: bool  # some row is already inside its safety radius
    buffer: FloatArray  # (n,) what each row's buffered form asks beyond it: b - buffer is the buffered rows' b

    @property
    def G(self) -> FloatArray:
        return self.A[self.k_in :]

    @property
    def b(self) -> FloatArray:
        return self.b_all[self.k_in :]

    @property
    def Lg_h(self) -> FloatArray:
        return -self.G

    @property
    def lower(self) -> FloatArray:
        return -self.b

    @property
    def h(self) -> FloatArray:
        return self.barrier.h

    @property
    def inside(self) -> BoolArray:
        return self.barrier.inside


_NO_REF = np.zeros(0)


def assemble(
    kind: BarrierKind,
    own: OwnAffine,
    obstacles: ObstacleArrays,
    settings: RowSettings,
    *,
    u_ref: FloatArray | None = None,
    input_set: LinearInputSet | None = None,
    sel: IntArray | None = None,
) -> Rows:
    """Build every row at once: one per obstacle, or row i for obstacle ``sel[i]``, with
    ``settings`` (:class:`swarm.safety.barriers.RowSettings`; its ``r_own_m`` [m] is added
    to each obstacle's radius for the full safety radius of its row: the agent's own
    bounding radius and margin). With ``input_set`` its rows ``C u <= d`` go on top of the
    barrier rows; with ``u_ref`` the residuals at it are computed too (``Rows.c_ref``,
    ``Rows.ref_ok``). ``settings.live`` makes the C3BF rows live rows aimed at ``u_ref``
    (:mod:`swarm.safety.barriers`; default the paper's rows)."""
    return assemble_with(own, obstacles, row_params(kind, settings), u_ref=u_ref, input_set=input_set, sel=sel)


def assemble_with(
    own: OwnAffine,
    obstacles: ObstacleArrays,
    params: np.ndarray,
    *,
    u_ref: FloatArray | None = None,
    input_set: LinearInputSet | None = None,
    sel: IntArray | None = None,
) -> Rows:
    """:func:`assemble` with the row settings given as a (1,) :data:`swarm.safety.barriers.ROW_PARAMS` array."""
    m = own.Aa.shape[1] - 1
    if input_set is None:  # no bounds: residuals of the barrier rows only
        lb, ub = np.full(m, -np.inf), np.full(m, np.inf)
        C, d = np.zeros((0, m)), _NO_REF
    else:
        lb, ub, C, d = input_set.lb, input_set.ub, input_set.C, input_set.d
    Y, coef, inside, Lf, A, b_all, c_ref, ref_ok, any_inside, tight, sz = rows_kernel(
        obstacles.rec,
        np.arange(len(obstacles)) if sel is None else sel,
        params,
        own.xv_b,
        own.Aa,
        _NO_REF if u_ref is None else u_ref,
        lb,
        ub,
        C,
        d,
    )
    return Rows(
        BarrierRows(Y, coef, inside, sz), Lf, A, b_all, c_ref, bool(ref_ok), C.shape[0], bool(any_inside), tight
    )


__all__ = [
    "A_P",
    "A_W",
    "B_P",
    "B_W",
    "OwnAffine",
    "OwnDynamics",
    "Rows",
    "assemble",
    "assemble_with",
    "own_affine",
    "rows_kernel",
]
