"""The QP form shared by the backends::

minimise 0.5 x^T H x + q^T x   s.t.   lb <= x <= ub,   A x <= b
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Protocol

from numba import njit

from swarm.errors import InputError
from swarm.rotation import FloatArray

_CHECK_MESSAGES = {
    1: "H, q or A holds NaN or infinity",
    2: "b holds NaN",
    3: "lb > ub, or a bound is NaN",
}


@njit(cache=True)
def _check_values(H, q, lb, ub, A, b):
    for a in (H.ravel(), q, A.ravel()):
        for x in a:
            if not math.isfinite(x):
                return 1
    for x in b:
        if math.isnan(x):
            return 2
    for i in range(lb.shape[0]):
        if not lb[i] <= ub[i]:
            return 3
    return 0


class QPStatus(StrEnum):
    OPTIMAL = "optimal"
    INFEASIBLE = "infeasible"
    FAILED = "failed"
    """Iteration limit, numerical trouble: no trustworthy ``x``."""


@dataclass(frozen=True)
class QPProblem:
    """A dense convex QP, checked at construction (shapes, finiteness, ``lb <= ub``)."""

    H: FloatArray  # (n, n) symmetric positive definite
    q: FloatArray  # (n,)
    lb: FloatArray  # (n,) may hold -inf
    ub: FloatArray  # (n,) may hold +inf
    A: FloatArray  # (k, n)
    b: FloatArray  # (k,)

    def __post_init__(self) -> None:
        n = self.q.shape[0]
        if self.H.shape != (n, n) or self.lb.shape != (n,) or self.ub.shape != (n,):
            raise InputError(f"QPProblem: H {self.H.shape}, lb {self.lb.shape}, ub {self.ub.shape} do not fit n = {n}")
        if self.A.ndim != 2 or self.A.shape[1] != n or self.b.shape != (self.A.shape[0],):
            raise InputError(f"QPProblem: A {self.A.shape} and b {self.b.shape} do not fit n = {n}")
        code = _check_values(self.H, self.q, self.lb, self.ub, self.A, self.b)
        if code:
            raise InputError(f"QPProblem: {_CHECK_MESSAGES[code]}")

    @classmethod
    def trusted(
        cls, H: FloatArray, q: FloatArray, lb: FloatArray, ub: FloatArray, A: FloatArray, b: FloatArray
    ) -> QPProblem:
        """A problem whose builder vouches for its shapes and finiteness, built without the
        checks (about 5 us a call). The safety filter uses it for the rows its compiled
        kernel built from a validated state: the backends still reject a non-finite
        solution, and the filter then falls back, so a bad row cannot become a NaN command."""
        obj = object.__new__(cls)
        obj.__dict__.update(H=H, q=q, lb=lb, ub=ub, A=A, b=b)  # frozen: no __setattr__
        return obj

    @property
    def n(self) -> int:
        return self.q.shape[0]

    def violation(self, x: FloatArray) -> float:
        """Largest violation of any bound or row by ``x`` (0 if feasible)."""
        v = max(float((self.lb - x).max()), float((x - self.ub).max()), 0.0)
        if self.b.size:
            v = max(v, float((self.A @ x - self.b).max()))
        return v


@dataclass(slots=True)
class QPSolution:
    problem: QPProblem
    x: FloatArray  # (n,), finite when status is OPTIMAL
    status: QPStatus
    solve_time_s: float
    iterations: int

    def primal_residual(self) -> float:
        """Largest bound or row violation of ``x`` (inf when not OPTIMAL)."""
        return self.problem.violation(self.x) if self.status is QPStatus.OPTIMAL else math.inf


class QPBackend(Protocol):
    name: str

    def solve(self, problem: QPProblem) -> QPSolution: ...
