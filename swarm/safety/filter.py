"""The C3BF-QP safety filter (docs/design.md, "The core")::

    u* = argmin |u - u_ref|^2   s.t.   Lg_h u >= lower (one row per obstacle / neighbour),
                                       u in the input set of the command level

Inputs ``u``: rotor thrusts ``f`` (4,) [N] at the rotor level; thrust vector ``F`` (3,)
[N, world] at the attitude level. The live rows' buffered form (``swarm.safety.constraints``, "Velocity
buffer") is tried first and the rows themselves only if it cannot all hold; when the rows
cannot all hold either, the least-violation QP with one slack per row (quadratic penalty)
is solved instead and the tick is flagged.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from enum import StrEnum
from typing import NamedTuple

import numpy as np
from numba import njit

from swarm.errors import InputError
from swarm.model import (
    Q_NORM2_MAX,
    Q_NORM2_MIN,
    Q_RENORM_TOL,
    CommandLevel,
    LinearInputSet,
    QuadModel,
    QuadState,
    all_finite,
    check_finite,
    rotor_input_set,
    state_check,
    thrust_vector_input_set,
)
from swarm.rotation import BoolArray, FloatArray, IntArray
from swarm.safety.barriers import LIVE_W_HI_MPS, LIVE_W_LO_MPS, BarrierKind, H, RowSettings, row_params
from swarm.safety.constraints import OwnDynamics, Rows, assemble_with, own_affine, rows_kernel
from swarm.safety.obstacles import ObstacleArrays
from swarm.safety.qp import QPProblem, QPSolution, QPStatus, make_backend

DEFAULT_BACKEND = "daqp"
"""Chosen by ``tools/bench_filter.py``: daqp is exact and several times faster here."""


@njit(cache=True)
def _residuals(G, b, u, lb, ub, C, d):
    """``c = b - G u`` (>= 0 where a row holds) and the largest violation of a row, bound
    or input row by ``u`` (0 when all hold)."""
    n, m = G.shape
    c = np.empty(n)
    v = 0.0
    for i in range(n):
        acc = b[i]
        for j in range(m):
            acc -= G[i, j] * u[j]
        c[i] = acc
        v = max(v, -acc)
    for j in range(m):
        v = max(v, lb[j] - u[j], u[j] - ub[j])
    for i in range(C.shape[0]):
        acc = -d[i]
        for j in range(m):
            acc += C[i, j] * u[j]
        v = max(v, acc)
    return c, v


FILTER_PARAMS = np.dtype(
    [
        ("r2", "f8"),  # m^2: squared sensing radius (neighbours farther get no row)
        ("max_rows", "i8"),  # most rows a call builds
        ("floor", "?"),  # the floor row is on (FilterConfig.floor_z_m not None)
        ("floor_z", "f8"),  # m, world: the floor's height
        ("floor_k", "f8"),  # 1/s: the floor's HO-CBF gain
    ],
    align=True,
)
"""The selection and floor settings :func:`_prepare` takes, as a (1,) structured array."""


@njit(cache=True)
def _select(obs, x, r2, max_rows):
    """(indices of the rows, ascending; number of non-neighbours) of the obstacles ``obs``
    (:data:`swarm.safety.obstacles.OBSTACLE`): every non-neighbour, and the neighbours with
    ``|c - x|^2 <= r2``, nearest first (stable) while fewer than ``max_rows`` rows. The
    caller raises when the non-neighbours alone are too many."""
    n = obs.shape[0]
    d2 = np.empty(n)
    keep = np.empty(n, dtype=np.bool_)
    is_nb = np.empty(n, dtype=np.bool_)
    fixed = 0
    near = 0
    for i in range(n):
        c = obs[i].c
        d2[i] = (c[0] - x[0]) ** 2 + (c[1] - x[1]) ** 2 + (c[2] - x[2]) ** 2
        is_nb[i] = obs[i].is_nb
        if not is_nb[i]:
            keep[i] = True
            fixed += 1
        else:
            keep[i] = d2[i] <= r2
            near += keep[i]
    if fixed + near > max_rows and fixed <= max_rows:  # too many neighbours: the nearest ones
        cand = np.flatnonzero(keep & is_nb)
        order = np.argsort(d2[cand], kind="mergesort")
        for j in order[max_rows - fixed :]:
            keep[cand[j]] = False
    return np.flatnonzero(keep), fixed


@njit(cache=True)
def _floor_row(af, fp, C_row, d, j, z, vz, q, ub):
    """Fill the floor row ``C_row u <= d[j]`` (see ``FilterConfig.floor_z_m``; ``fp`` a
    :data:`FILTER_PARAMS` record, ``af`` a :data:`swarm.safety.constraints.AIRFRAME` record) for the
    centre-of-mass height ``z`` [m] and vertical speed ``vz`` [m/s]: ``-F_z <= -need`` at
    the attitude level, ``-R33 sum f <= -need`` at the rotor level (no row when upside
    down or on edge, ``R33 < 0.1``); ``need`` is capped at 95 % of what the inputs give."""
    k = fp.floor_k
    a_min = -2.0 * k * vz - k * k * (z - fp.floor_z)  # m/s^2
    need = af.mass * (af.g + a_min)  # N of vertical thrust
    if not af.rotor:
        C_row[0], C_row[1], C_row[2] = 0.0, 0.0, -1.0
        d[j] = -min(need, 0.95 * ub[2])
        return
    r33 = 1.0 - 2.0 * (q[0] * q[0] + q[1] * q[1])  # scalar-last (swarm.rotation)
    if r33 < 0.1:
        C_row[:] = 0.0
        d[j] = 0.0
    else:
        C_row[:] = -r33
        d[j] = -min(need, 0.95 * r33 * ub.sum())


# codes of _prepare's first result: which input failed its check
_BAD_NONE, _BAD_STATE, _BAD_QUAT, _BAD_UREF = 0, 1, 2, 3


class Prepared(NamedTuple):
    """What :func:`_prepare` hands back: ``bad`` (a ``_BAD_*`` code), ``fixed`` (as
    :func:`_select` gives it), ``idx`` (the obstacles that got a row), the rows' values and
    arrays as :func:`swarm.safety.constraints.rows_kernel` returns them (only what the filter
    uses: each array handed back costs a Python object), and the buffered rows."""

    bad: int
    fixed: int
    idx: IntArray
    h: FloatArray  # (n,) each row's barrier value
    inside: BoolArray
    A: FloatArray
    b_all: FloatArray
    c_ref: FloatArray
    ref_ok: bool
    any_inside: bool
    tight: FloatArray
    any_tight: bool  # some row has a buffer (tight > 0)
    b_tight: FloatArray  # (k + n,) b_all with each barrier row's buffer taken off: the buffered rows


@njit(cache=True)
def _prepare(check, x, v, q, Om, u_ref, obs, settings, inputs):
    """One filter call's work before the QP, in one compiled call, for the state ``x`` [m],
    ``v`` [m/s], ``q`` (scalar-last), ``Om`` [rad/s, body], the reference ``u_ref``,
    the obstacles ``obs`` (an (n,) :data:`swarm.safety.obstacles.OBSTACLE` array),
    ``settings`` = the (1,) arrays (``air``: :data:`swarm.safety.constraints.AIRFRAME`,
    ``params``: :data:`swarm.safety.barriers.ROW_PARAMS`, ``fparams``:
    :data:`FILTER_PARAMS`) and ``inputs`` = the input set (``lb``, ``ub``, ``C``, ``d``:
    ``lb <= u <= ub``, ``C u <= d``; the floor row, when on, is its last row, refilled
    here). With ``check`` the state's finiteness, shapes and quaternion norm and
    ``u_ref``'s finiteness (a failure returns its ``_BAD_*`` code at once; the caller
    raises the named error) and the quaternion normalised; then :func:`_select`, the
    floor row, the own dynamics (:func:`swarm.safety.constraints.own_affine`) and
    :func:`swarm.safety.constraints.rows_kernel` at ``u_ref``, and the buffered rows' right-hand
    side. Returns a :class:`Prepared`."""
    air, params, fparams = settings
    lb, ub, C, d = inputs
    fp = fparams[0]
    m = lb.shape[0]
    qn = np.empty(4)
    for i in range(4):
        qn[i] = q[i]
    if check:
        if x.shape[0] != 3 or v.shape[0] != 3 or q.shape[0] != 4 or Om.shape[0] != 3:
            bad = _BAD_STATE
        else:
            bad, nq2 = state_check(x, v, q, Om)
            if bad == 0 and not Q_NORM2_MIN < nq2 < Q_NORM2_MAX:
                bad = _BAD_QUAT
            elif bad == 0 and abs(nq2 - 1.0) > Q_RENORM_TOL:
                s = 1.0 / math.sqrt(nq2)
                for i in range(4):
                    qn[i] *= s
        if bad == 0 and (u_ref.shape[0] != m or not all_finite(u_ref)):
            bad = _BAD_UREF
        if bad != 0:
            z1 = np.zeros(0)
            return Prepared(
                bad,
                0,
                np.zeros(0, dtype=np.intp),
                z1,
                np.zeros(0, dtype=np.bool_),
                np.zeros((0, m)),
                z1,
                z1,
                False,
                False,
                z1,
                False,
                z1,
            )
    idx, fixed = _select(obs, x, fp.r2, fp.max_rows)
    if fp.floor:
        j = C.shape[0] - 1
        _floor_row(air[0], fp, C[j], d, j, x[2], v[2], qn, ub)
    xv_b, Aa = own_affine(air, x, v, qn, Om)
    _Y, coef, inside, _Lf, A, b_all, c_ref, ref_ok, any_inside, tight, _sz = rows_kernel(
        obs, idx, params, xv_b, Aa, u_ref, lb, ub, C, d
    )
    k = C.shape[0]
    b_tight = b_all.copy()
    any_tight = False
    for i in range(tight.shape[0]):
        if tight[i] != 0.0:
            any_tight = True
            b_tight[k + i] -= tight[i]
    return Prepared(
        0, fixed, idx, coef[:, H].copy(), inside, A, b_all, c_ref, ref_ok, any_inside, tight, any_tight, b_tight
    )


SPEED_GAIN_PER_S = 2.0
"""Class-K gain [1/s] of the speed row (``FilterConfig.speed_limit_mps``)."""


def _is_vector(a: object) -> bool:
    """A 1-D float64 numpy array (what the compiled checks take as they are)."""
    return type(a) is np.ndarray and a.dtype == np.float64 and a.ndim == 1


ACTIVE_TOL = 1e-8
"""A row whose constraint value ``Lg_h u - lower`` is at most this is reported active."""


class FilterStatus(StrEnum):
    OK = "ok"
    """Every row and bound holds (``u == u_ref`` when no row was active); ``buffered`` says
    whether the buffered rows hold too."""
    INFEASIBLE = "infeasible"
    """The rows could not all hold: least-violation command, ``slack`` says by how much."""
    COLLISION = "collision"
    """At least one obstacle is already inside its safety radius: escape rows were used."""
    FAILED = "failed"
    """Both QPs failed numerically: ``u`` is ``u_ref`` clipped to the input bounds."""


@dataclass(frozen=True)
class FilterConfig:
    """Settings of one agent's filter."""

    level: CommandLevel = CommandLevel.ROTORS
    kind: BarrierKind = BarrierKind.C3BF
    """Which barrier builds the rows (the config's ``filter.kind``)."""
    gamma: float = 1.0
    """Class-K gain [1/s]: ``kappa(h) = gamma h`` (the paper's 1)."""
    gamma_ho: float = 1.0
    """HO-CBF gain [m/s] in ``h = <p,w> + gamma_ho s``."""
    rho: float = 1.0
    """Responsibility share of neighbour rows, in (0, 1]: the agent's share of a pair's
    relative drift and, inside the cone, of its recovery; outside the cone each agent keeps
    its row's whole allowance ``gamma h`` (``swarm.safety.constraints``, "Responsibility share"). 1: the
    whole condition, as if the neighbour did nothing; 0.5: reciprocal, each pair then asks
    ``h' + 2 gamma h >= 0`` outside its cone between its two agents."""
    sensing_radius_m: float = 3.0
    """Neighbours farther than this (body centre to centre) get no row."""
    margin_m: float = 0.02
    """Extra clearance [m] added to every safety radius."""
    eps_w_mps: float = 1e-3
    """Smoothing of ``|w|`` [m/s] (``swarm.safety.barriers``)."""
    escape_speed_mps: float = 0.3
    """Separation speed asked of rows already inside their radius."""
    slack_weight: float = 1e6
    """Penalty on squared row violation in the infeasible fallback QP."""
    backend: str = DEFAULT_BACKEND
    max_rows: int = 64
    floor_z_m: float | None = None
    """Height [m, world] the centre of mass must stay above, or None (no floor). The
    floor is the HO-CBF ``z'' >= -2 k z' - k^2 (z - floor_z_m)`` (``k`` = ``floor_gain_per_s``),
    one more input row: ``F_z`` at the attitude level, ``R33 sum f`` at the rotor level."""
    floor_gain_per_s: float = 2.0
    live: bool = True
    """C3BF only: live rows (``swarm.safety.barriers``, "Live rows"), which let a swarm at rest
    move where the cone allows, or False for the paper's smoothed rows, which freeze at
    zero relative velocity. The live rows are the exact C3BF rows from ``live_hi_mps``."""
    live_lo_mps: float = LIVE_W_LO_MPS
    """Relative speed [m/s] below which a live row aims at the reference alone."""
    live_hi_mps: float = LIVE_W_HI_MPS
    """Relative speed [m/s] from which a live row is the exact C3BF row."""
    buffer_mps: float = 0.1
    """Live rows: the velocity buffer ``b`` [m/s] (``swarm.safety.constraints``, "Velocity buffer"): the
    QP is first solved with every live row asking ``h' + g k h >= g v |dh/dw|`` (``g k`` its
    class-K gain, ``v = min(b, 0.1 |w|)``), which keeps the relative velocity about ``v``
    outside its cone, and with the rows themselves only if those cannot all hold. 0: the
    rows alone."""
    contact_s: float = 0.0
    """Live neighbour rows: the contact horizon ``T`` [s] (``swarm.safety.barriers``, "Contact
    horizon"): a neighbour row whose time to contact exceeds ``T`` relaxes its radius,
    to a tenth of it from ``2 T``, so a slow approach is not held as hard as a fast one.
    0: none."""
    free_braking: bool = True
    """Live rows: free braking (``swarm.safety.barriers``, "Free braking"): where the
    reference brakes a relative velocity, outside the cone and not closing fast, the row
    is the condition of ``h / |w|^lambda`` (``lambda`` up to 1, fading with the closing
    speed), which leaves braking free, rather than of h."""
    horizon_s: float | None = None
    """Live rows: the time horizon ``tau`` [s] of the horizon allowance, which adds
    ``(|p|^2 - r^2) / (2 tau)`` to every live row's h (``swarm.safety.barriers``, "Horizon
    allowance"), or None: the cone alone (the default)."""
    obstacle_horizon_s: float | None = None
    """Live obstacle rows (not other agents): their own time horizon [s] of the horizon
    allowance, or None: ``horizon_s``. An agent flying a path planned round walls gets its
    planner's (``swarm.tuning.filter_config_for``; where its gain covers it): the path
    takes it round the walls, and the cones of pillars far along it no longer hold its
    velocity to a slit. Neighbours not doing their share get obstacle rows, and this too."""
    accel_limit_mps2: float | None = None
    """Attitude level: the largest acceleration [m/s^2] beyond gravity the filtered command may
    ask (``|a_xy|`` and ``|a_z|`` each at most this over sqrt 2, so ``|a|`` at most this): the
    bound a swarm's agents agree on, over which each extrapolates the others' states across the
    loop's delay (``swarm.tuning.agreed_accel_mps2``); None: the airframe's input set alone."""
    speed_limit_mps: float | None = None
    """Attitude level: the speed [m/s] the agent keeps within, one more input row, the CBF
    ``h_v = V^2 - |v|^2`` with ``h_v' + SPEED_GAIN_PER_S h_v >= 0`` (``h_v' = -2 <v, F / m - g
    e3>``), its right-hand side never asking for more braking than a quarter of
    ``accel_limit_mps2`` (which the box gives in any direction, so the set is never empty): a
    swarm's delay contract (``swarm.tuning.agreed_speed_mps``). None: no row."""
    ellipsoid: bool = True
    """Rows of other drones keep the keep-out ellipsoid of the airframe
    (``QuadParams.keep_out_xy_m``, ``keep_out_z_m``: Crazyswarm's 0.12 m across and 0.30 m up and
    down between two Crazyflies' centres), each radius plus ``margin_m`` where it exceeds the
    bodies' sphere (``swarm.safety.barriers``, "Keep-out ellipsoid"); False: the sphere of both
    bodies' radii and the margin."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "level", CommandLevel(self.level))
        object.__setattr__(self, "kind", BarrierKind(self.kind))
        if self.floor_z_m is not None and not math.isfinite(self.floor_z_m):
            raise InputError(f"FilterConfig.floor_z_m: must be finite or None, got {self.floor_z_m!r}")
        for name in ("gamma", "gamma_ho", "sensing_radius_m", "eps_w_mps", "slack_weight", "floor_gain_per_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"FilterConfig.{name}: must be a finite number > 0, got {v!r}")
        for name in ("margin_m", "escape_speed_mps", "buffer_mps", "contact_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"FilterConfig.{name}: must be a finite number >= 0, got {v!r}")
        for name in ("horizon_s", "obstacle_horizon_s"):
            h_s = getattr(self, name)
            if h_s is not None and not (isinstance(h_s, (int, float)) and math.isfinite(h_s) and h_s > 0):
                raise InputError(f"FilterConfig.{name}: must be a finite number > 0 or None, got {h_s!r}")
        if not (0.0 < self.rho <= 1.0):
            raise InputError(f"FilterConfig.rho: must be in (0, 1], got {self.rho!r}")
        if not (0.0 <= self.live_lo_mps < self.live_hi_mps and math.isfinite(self.live_hi_mps)):
            raise InputError(
                "FilterConfig.live_lo_mps, live_hi_mps: need 0 <= lo < hi, "
                f"got {self.live_lo_mps!r}, {self.live_hi_mps!r}"
            )
        if not (isinstance(self.max_rows, int) and self.max_rows >= 1):
            raise InputError(f"FilterConfig.max_rows: must be an integer >= 1, got {self.max_rows!r}")


@dataclass(slots=True)
class FilterResult:
    """What one filter call decided. Row arrays follow ``row_index`` order."""

    u: FloatArray  # (m,) the command: f [N] or F [N, world]; always finite
    u_ref: FloatArray  # (m,)
    status: FilterStatus
    row_index: IntArray  # (n,): index into the obstacle arrays of each row
    h: FloatArray  # (n,) barrier value of each row
    constraint: FloatArray  # (n,) Lg_h u - lower = h' + kappa(h) (rho-shared); >= 0 holds
    active: BoolArray  # (n,): the row binds: constraint == buffer if buffered, else constraint == 0
    inside: BoolArray  # (n,): already inside the safety radius
    slack: FloatArray  # (n,) violation allowed by the fallback QP (zeros when OK)
    solve_time_s: float  # whole call: rows and QP
    max_violation: float  # largest violation of a row or bound by u (0 when all hold)
    buffer: FloatArray  # (n,) what each row's buffered form asks of ``constraint`` (FilterConfig.buffer_mps)
    buffered: bool  # u holds the buffered rows (constraint >= buffer); False: the rows alone, or not even those

    @property
    def min_h(self) -> float:
        return min(self.h.tolist(), default=math.inf)

    @property
    def min_cone_h(self) -> float:
        """Smallest h [m^2/s] of the rows outside their safety radius (an escape row's
        value is a speed [m/s], not a barrier of this kind: left out); inf without any."""
        return min(self.h[~self.inside].tolist(), default=math.inf)

    @property
    def intervention(self) -> float:
        """``|u - u_ref|`` in input units."""
        return math.dist(self.u.tolist(), self.u_ref.tolist())


class SafetyFilter:
    """One agent's C3BF-QP. Build once; call :meth:`filter` every control tick."""

    def __init__(self, model: QuadModel, config: FilterConfig | None = None) -> None:
        self.model = model
        self.config = config or FilterConfig()
        cfg = self.config
        if cfg.level is CommandLevel.ROTORS:
            self.input_set: LinearInputSet = rotor_input_set(model.params)
        else:
            self.input_set = thrust_vector_input_set(model.params, accel_limit_mps2=cfg.accel_limit_mps2)
        self.m = self.input_set.lb.shape[0]
        self.r_own_m = model.params.body_radius_m + cfg.margin_m
        self._speed_row: int | None = None
        if cfg.speed_limit_mps is not None and cfg.level is CommandLevel.ATTITUDE:  # one more row, refilled every call
            if not (math.isfinite(cfg.speed_limit_mps) and cfg.speed_limit_mps > 0.0):
                raise InputError(f"FilterConfig.speed_limit_mps: must be finite and > 0, got {cfg.speed_limit_mps!r}")
            ins = self.input_set
            self._speed_row = ins.d.shape[0]
            self.input_set = LinearInputSet(
                ins.lb, ins.ub, np.vstack([ins.C, np.zeros((1, self.m))]), np.append(ins.d, np.inf)
            )
        ins = self.input_set
        if cfg.floor_z_m is not None:  # the floor: one more input row, refilled every call
            self._floor_set = LinearInputSet(
                ins.lb, ins.ub, np.vstack([ins.C, np.zeros((1, self.m))]), np.append(ins.d, 0.0)
            )
        k_in = self.input_set.d.shape[0] + (cfg.floor_z_m is not None)
        self._qp = make_backend(cfg.backend, self.m, cfg.max_rows + k_in)
        # The least-violation QP always uses daqp: its slack weights make ADMM (OSQP)
        # converge badly (measured: p99 about 0.3 s at 5 rows before falling back).
        self._qp_slack = make_backend("daqp", self.m + cfg.max_rows, 2 * cfg.max_rows + k_in)
        self._H = 2.0 * np.eye(self.m)
        # a numerically failed solve is retried once with the exact active-set solver
        self._fallback = None if cfg.backend == "daqp" else make_backend("daqp", self.m, 0)
        self._slack_cache: dict[tuple[int, int], tuple[FloatArray, ...]] = {}  # (rows, input set) -> arrays
        self._own = OwnDynamics(cfg.level, model)
        self._params = row_params(
            cfg.kind,
            RowSettings(
                gamma=cfg.gamma,
                rho=cfg.rho,
                r_own_m=self.r_own_m,
                eps=cfg.eps_w_mps,
                gamma_ho=cfg.gamma_ho,
                escape_speed=cfg.escape_speed_mps,
                live=cfg.live,
                w_lo_mps=cfg.live_lo_mps,
                w_hi_mps=cfg.live_hi_mps,
                horizon_s=cfg.horizon_s,
                obstacle_horizon_s=cfg.obstacle_horizon_s,
                buffer_mps=cfg.buffer_mps,
                contact_s=cfg.contact_s,
                free_braking=cfg.free_braking,
                keep_out_xy_m=model.params.keep_out_xy_m + cfg.margin_m if cfg.ellipsoid else 0.0,
                keep_out_z_m=model.params.keep_out_z_m + cfg.margin_m if cfg.ellipsoid else 0.0,
            ),
        )
        self._fparams = np.zeros(1, dtype=FILTER_PARAMS)
        self._fparams[0] = (
            cfg.sensing_radius_m**2,
            cfg.max_rows,
            cfg.floor_z_m is not None,
            cfg.floor_z_m or 0.0,
            cfg.floor_gain_per_s,
        )
        self._kernel_settings = (self._own.air, self._params, self._fparams)  # _prepare's settings
        used = self._floor_set if cfg.floor_z_m is not None else self.input_set
        self._inputs = (used.lb, used.ub, used.C, used.d)  # _prepare's input set (the floor row refilled in place)

    def select(self, state: QuadState, obstacles: ObstacleArrays) -> IntArray:
        """Indices of the obstacles that get a row: every non-neighbour, and neighbours
        within the sensing radius (nearest first while rows remain). More obstacles than
        ``max_rows`` raise :class:`InputError`: an obstacle is never silently dropped."""
        idx, fixed = _select(obstacles.rec, state.x_w, self.config.sensing_radius_m**2, self.config.max_rows)
        if fixed > self.config.max_rows:
            raise InputError(f"obstacles: {fixed} obstacles exceed FilterConfig.max_rows = {self.config.max_rows}")
        return idx

    def rows(
        self,
        state: QuadState,
        obstacles: ObstacleArrays,
        u_ref: FloatArray | None = None,
        input_set: LinearInputSet | None = None,
        sel: IntArray | None = None,
    ) -> Rows:
        """The barrier rows for ``obstacles`` (all of them, or those ``sel`` indexes); with
        ``u_ref`` also their residuals at it (against ``input_set``, default the filter's).
        Live rows depend on the reference (their direction at low speed, free braking), so
        the rows a command was filtered against are ``rows(state, obstacles, u_ref)``."""
        own = self._own(state)
        return assemble_with(own, obstacles, self._params, u_ref=u_ref, input_set=input_set or self.input_set, sel=sel)

    def filter(
        self, state: QuadState, u_ref: FloatArray, obstacles: ObstacleArrays, *, validate: bool = True
    ) -> FilterResult:
        """Filter ``u_ref`` against ``obstacles``. With ``validate`` the state and
        reference are checked and a bad one raises :class:`InputError`."""
        t0 = time.perf_counter()
        cfg, m = self.config, self.m
        if validate and not (
            _is_vector(state.x_w)
            and _is_vector(state.v_w)
            and _is_vector(state.q)
            and _is_vector(state.Omega_b)
            and _is_vector(u_ref)
        ):
            state = state.validated()  # not float64 vectors: checked and converted, or the field named
            u_ref = check_finite("u_ref", u_ref, (m,))
        ins = self.input_set if cfg.floor_z_m is None else self._floor_set
        if self._speed_row is not None:
            self._fill_speed_row(ins, state.v_w)
        prep = _prepare(
            validate,
            state.x_w,
            state.v_w,
            state.q,
            state.Omega_b,
            u_ref,
            obstacles.rec,
            self._kernel_settings,
            self._inputs,
        )
        if prep.bad != _BAD_NONE:  # the same checks as _prepare's, in Python: one of them raises, naming the field
            state.validated()
            check_finite("u_ref", u_ref, (m,))
        if prep.fixed > cfg.max_rows:
            raise InputError(f"obstacles: {prep.fixed} obstacles exceed FilterConfig.max_rows = {cfg.max_rows}")
        call = (t0, prep, ins)  # for whichever QP decides the call (_result)
        n = prep.idx.shape[0]
        zeros = np.zeros(n)

        # Fast path: the reference already satisfies everything (the buffered rows included).
        if prep.ref_ok:
            return self._result(call, u_ref, u_ref, FilterStatus.OK, zeros, residuals=(prep.c_ref, 0.0), buffered=True)

        A, bb = prep.A, prep.b_all  # input rows on top of the barrier rows (G u <= b)
        status = FilterStatus.COLLISION if prep.any_inside else FilterStatus.OK
        has_buffer = bool(prep.any_tight)
        if has_buffer:  # the buffered rows first; the rows themselves only if those cannot all hold
            sol = self._solve(QPProblem.trusted(self._H, -2.0 * u_ref, ins.lb, ins.ub, A, prep.b_tight))
            if sol.status is QPStatus.OPTIMAL:
                return self._result(call, sol.x, u_ref, status, zeros, buffered=True)
        sol = self._solve(QPProblem.trusted(self._H, -2.0 * u_ref, ins.lb, ins.ub, A, bb))  # rows from the kernel
        if sol.status is QPStatus.OPTIMAL:
            return self._result(call, sol.x, u_ref, status, zeros, buffered=not has_buffer)

        # Least violation: variables (u, s), G u - s <= b, s >= 0, cost |u-u_ref|^2 + W |s|^2;
        # obstacles first: with shared rows among them, the slacks of the rows without a share held at 0
        m = self.m
        H, q, lb, ub, A_s = self._slack_arrays(n, ins)
        q[:m] = -2.0 * u_ref
        G, b = A[ins.d.size :], bb[ins.d.size :]  # the barrier rows alone
        A_s[: ins.d.size, :m] = ins.C  # (the floor row changes every call)
        A_s[ins.d.size :, :m] = G
        sol_s = None
        own = ~obstacles.is_neighbour[prep.idx]  # (n,): no share (an obstacle, a neighbour taken whole)
        if own.any() and not own.all():
            ub_own = ub.copy()
            ub_own[m:][own] = 0.0
            sol_s = self._qp_slack_solve(QPProblem.trusted(H, q, lb, ub_own, A_s, bb))
        if sol_s is None:
            sol_s = self._qp_slack_solve(QPProblem.trusted(H, q, lb, ub, A_s, bb))
        if sol_s is not None:
            u = sol_s[:m]
            slack = np.maximum(G @ u - b, 0.0)
            st = FilterStatus.COLLISION if prep.any_inside else FilterStatus.INFEASIBLE
            return self._result(call, u, u_ref, st, slack)
        u = np.clip(u_ref, ins.lb, ins.ub)
        return self._result(call, u, u_ref, FilterStatus.FAILED, np.maximum(G @ u - b, 0.0))

    def _fill_speed_row(self, ins: LinearInputSet, v_w: FloatArray) -> None:
        """The speed row of ``ins`` (``FilterConfig.speed_limit_mps``) for the velocity ``v_w``
        [m/s, world], in place: ``<v, F> <= m g v_z + m k (V^2 - |v|^2) / 2`` (``k`` =
        :data:`SPEED_GAIN_PER_S`), and never below ``m g v_z - m a |v| / 4`` with ``a`` the
        acceleration limit (braking along ``-v`` at a quarter of it, inside the box's ``a / sqrt 2``
        per axis in any direction)."""
        p, cfg = self.model.params, self.config
        j = self._speed_row
        assert j is not None and cfg.speed_limit_mps is not None
        v = np.asarray(v_w, dtype=float)
        speed2 = float(v @ v)
        mg_vz = p.mass_kg * p.g_mps2 * float(v[2])
        rhs = mg_vz + 0.5 * p.mass_kg * SPEED_GAIN_PER_S * (cfg.speed_limit_mps**2 - speed2)
        a = cfg.accel_limit_mps2 if cfg.accel_limit_mps2 is not None else p.g_mps2
        ins.C[j] = v
        ins.d[j] = max(rhs, mg_vz - 0.25 * p.mass_kg * a * math.sqrt(speed2))

    def _solve(self, problem: QPProblem) -> QPSolution:
        """The QP by the configured backend, retried once by daqp if it failed numerically."""
        sol = self._qp.solve(problem)
        if sol.status is QPStatus.FAILED and self._fallback is not None:
            sol = self._fallback.solve(problem)
        return sol

    def _slack_arrays(self, n: int, ins: LinearInputSet) -> tuple[FloatArray, ...]:
        """The least-violation QP's arrays for ``n`` rows under ``ins``: H, q, lb, ub and
        A = [[C, 0]; [., -I]], built once per (n, input set) and refilled per call (the
        parts that change: q[:m], A[:, :m])."""
        key = (n, id(ins))
        arrays = self._slack_cache.get(key)
        if arrays is None:
            m, k, W = self.m, ins.d.size, self.config.slack_weight
            A_s = np.zeros((k + n, m + n))
            A_s[k:, m:] = -np.eye(n)
            arrays = self._slack_cache[key] = (
                np.diag(np.concatenate([np.full(m, 2.0), np.full(n, 2.0 * W)])),
                np.zeros(m + n),
                np.concatenate([ins.lb, np.zeros(n)]),
                np.concatenate([ins.ub, np.full(n, np.inf)]),
                A_s,
            )
        return arrays

    def _qp_slack_solve(self, problem: QPProblem) -> FloatArray | None:
        sol = self._qp_slack.solve(problem)
        return sol.x[: problem.n] if sol.status is QPStatus.OPTIMAL else None

    def _result(
        self,
        call: tuple[float, Prepared, LinearInputSet],
        u: FloatArray,
        u_ref: FloatArray,
        status: FilterStatus,
        slack: FloatArray,
        *,
        residuals: tuple[FloatArray, float] | None = None,
        buffered: bool = False,
    ) -> FilterResult:
        """The result of the call ``call`` = (its start time [s, perf_counter], what
        :func:`_prepare` built for it, the input set it used) for the command ``u``: its
        residuals at the rows (``residuals``: the reference's, already computed over [input
        rows; barrier rows]) and which rows bind (against the buffered rows where ``u`` holds
        them)."""
        t0, prep, ins = call
        k = ins.d.size
        if residuals is not None:
            c, viol = residuals[0][k:], residuals[1]
        else:
            c, viol = _residuals(prep.A[k:], prep.b_all[k:], u, ins.lb, ins.ub, ins.C, ins.d)  # c = Lg_h u - lower
        active = c - prep.tight <= ACTIVE_TOL if buffered else c <= ACTIVE_TOL
        return FilterResult(
            u=u,
            u_ref=u_ref,
            status=status,
            row_index=prep.idx,
            h=prep.h,
            constraint=c,
            active=active,
            inside=prep.inside,
            slack=slack,
            solve_time_s=time.perf_counter() - t0,
            max_violation=viol,
            buffer=prep.tight,
            buffered=buffered,
        )
