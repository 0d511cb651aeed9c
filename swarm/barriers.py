"""Collision-cone barriers (DESIGN.md section 4), compiled with numba, one loop over rows.

A row is an obstacle seen from the agent: ``p`` the relative position obstacle centre
minus agent body centre [m, world], ``w = p'`` [m/s, world], ``r`` the full safety
radius [m], ``a`` a unit cylinder axis [world] or zeros for a sphere. Every barrier here
has gradients of the form

    dh/dp = a_p p + b_p w,        dh/dw = a_w p + b_w w

with scalar coefficients per row:

| barrier | h | a_p | b_p | a_w | b_w |
|---|---|---|---|---|---|
| C3BF | <p,w> + n(w) s | n/s | 1 | 1 | s/sqrt(\\|w\\|^2+eps^2) |
| HO-CBF | <p,w> + gamma_ho s | gamma_ho/s | 1 | 1 | 0 |
| escape (inside r) | <p,w>/\\|p\\| - v_esc | -<p,w>/\\|p\\|^3 | 1/\\|p\\| | 1/\\|p\\| | 0 |

with ``s = sqrt(|p|^2 - r^2)`` and the smoothed norm ``n = sqrt(|w|^2+eps^2) - eps``
(``n <= |w|``, so a non-negative smoothed h keeps the true one non-negative).
Cylinders use ``P p`` and ``P w`` with ``P = I - a a^T``; the gradients then lie in
range(P) and need no second projection. A row already inside ``r`` gets the escape
barrier (separate at ``v_esc``); a coincident pair is treated as if the obstacle were
``COINCIDENT_M`` below the agent, so the agent escapes upwards. No row produces NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

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
H, A_P, B_P, A_W, B_W, PW, WW = range(7)


@njit(cache=True, fastmath=False)
def barrier_row(kind, p, w, r, a, eps, gamma_ho, v_esc, Y_out, coef_out):  # noqa: ANN001
    """One row. Writes the (projected) p, w into ``Y_out`` (2, 3) and
    ``h, a_p, b_p, a_w, b_w, <p,w>, <w,w>`` into ``coef_out`` (7,); returns inside."""
    ap = a[0] * p[0] + a[1] * p[1] + a[2] * p[2]
    aw = a[0] * w[0] + a[1] * w[1] + a[2] * w[2]
    for k in range(3):
        Y_out[0, k] = p[k] - ap * a[k]
        Y_out[1, k] = w[k] - aw * a[k]
    P = Y_out[0]
    W = Y_out[1]
    pp = P[0] * P[0] + P[1] * P[1] + P[2] * P[2]
    pw = P[0] * W[0] + P[1] * W[1] + P[2] * W[2]
    ww = W[0] * W[0] + W[1] * W[1] + W[2] * W[2]
    s2 = pp - r * r
    if s2 > 0.0:
        s = math.sqrt(s2)
        if kind == 0:
            root = math.sqrt(ww + eps * eps)
            nw = root - eps
            h, a_p, b_w = pw + nw * s, nw / s, s / root
        else:
            h, a_p, b_w = pw + gamma_ho * s, gamma_ho / s, 0.0
        b_p, a_w = 1.0, 1.0
        inside = False
    else:
        if pp < COINCIDENT_M * COINCIDENT_M:
            P[0], P[1], P[2] = 0.0, 0.0, -COINCIDENT_M
            pp = COINCIDENT_M * COINCIDENT_M
            pw = -COINCIDENT_M * W[2]
        d = math.sqrt(pp)
        h, a_p, b_p, a_w, b_w = pw / d - v_esc, -pw / (d * pp), 1.0 / d, 1.0 / d, 0.0
        inside = True
    coef_out[0] = h
    coef_out[1] = a_p
    coef_out[2] = b_p
    coef_out[3] = a_w
    coef_out[4] = b_w
    coef_out[5] = pw
    coef_out[6] = ww
    return inside


@njit(cache=True)
def barrier_rows(kind, Y, r, axis, eps, gamma_ho, v_esc):  # noqa: ANN001
    """All rows of stacked ``Y = [p; w]`` (n, 2, 3): returns (Y_used, coef (n, 7), inside)."""
    n = Y.shape[0]
    Y_out = np.empty((n, 2, 3))
    coef = np.empty((n, 7))
    inside = np.empty(n, dtype=np.bool_)
    for i in range(n):
        inside[i] = barrier_row(kind, Y[i, 0], Y[i, 1], r[i], axis[i], eps, gamma_ho, v_esc, Y_out[i], coef[i])
    return Y_out, coef, inside


@dataclass(slots=True)
class BarrierRows:
    """Barrier values and gradient coefficients of ``n`` rows."""

    Y: FloatArray  # (n, 2, 3) the (projected) p [m] and w [m/s] the values refer to
    coef: FloatArray  # (n, 7) columns H, A_P, B_P, A_W, B_W, PW, WW
    inside: BoolArray  # (n,): |P p| <= r, the row holds the escape barrier

    @property
    def h(self) -> FloatArray:
        """(n,) barrier value [m^2/s] (escape rows: [m/s])."""
        return self.coef[:, H]

    @property
    def dh_dp(self) -> FloatArray:
        """(n, 3) gradient of h with respect to p."""
        return self.coef[:, A_P, None] * self.Y[:, 0] + self.coef[:, B_P, None] * self.Y[:, 1]

    @property
    def dh_dw(self) -> FloatArray:
        """(n, 3) gradient of h with respect to w."""
        return self.coef[:, A_W, None] * self.Y[:, 0] + self.coef[:, B_W, None] * self.Y[:, 1]


def evaluate(
    kind: BarrierKind,
    Y: FloatArray,
    r: FloatArray,
    axis_w: FloatArray | None = None,
    *,
    eps: float = 1e-3,
    gamma_ho: float = 1.0,
    escape_speed: float = 0.3,
) -> BarrierRows:
    """Barrier rows for stacked ``Y = [p; w]`` (n, 2, 3). ``axis_w`` (n, 3) holds unit
    cylinder axes (zero rows for spheres); ``None`` means all spheres."""
    Y = np.ascontiguousarray(Y, dtype=float)
    axis = np.zeros((Y.shape[0], 3)) if axis_w is None else np.ascontiguousarray(axis_w, dtype=float)
    Y_used, coef, inside = barrier_rows(
        kind.code, Y, np.ascontiguousarray(r, dtype=float), axis, eps, gamma_ho, escape_speed
    )
    return BarrierRows(Y_used, coef, inside)


def evaluate_pw(
    kind: BarrierKind,
    p: FloatArray,
    w: FloatArray,
    r: FloatArray,
    axis_w: FloatArray | None = None,
    **kw: float,
) -> BarrierRows:
    """:func:`evaluate` for separate ``p`` and ``w`` (n, 3)."""
    return evaluate(kind, np.stack([p, w], axis=1), r, axis_w, **kw)
