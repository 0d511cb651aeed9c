"""OSQP backend with one persistent workspace.

The workspace is set up once for ``n`` variables and ``max_rows`` rows with a dense
sparsity pattern; every solve only updates values. Unused rows get infinite bounds.
Tolerances are tight and solution polishing is on so that a solution violates no row by
more than 1e-6 (at OSQP's defaults violations near 1e-3 are common).
"""

from __future__ import annotations

import time

import numpy as np
import osqp
import scipy.sparse as sp

from swarm.errors import InputError
from swarm.safety.qp.problem import QPProblem, QPSolution, QPStatus

_INF = 1e30
ACCEPT_VIOLATION = 1e-7
"""Largest row or bound violation of a solution reported OPTIMAL."""


class OsqpBackend:
    name = "osqp"

    def __init__(self, n: int, max_rows: int, eps: float = 1e-9, max_iter: int = 4000) -> None:
        self.n, self.max_rows = n, max_rows
        # P's upper triangle in CSC order (by column, then row) is H's lower triangle
        # read row by row, since H is symmetric
        self._tril = np.tril_indices(n)
        P = sp.csc_matrix(np.triu(np.ones((n, n))))
        A_pattern = np.vstack([np.eye(n), np.ones((max_rows, n))])
        A = sp.csc_matrix(A_pattern)
        self._solver = osqp.OSQP()
        self._solver.setup(
            P,
            np.zeros(n),
            A,
            -np.full(n + max_rows, _INF),
            np.full(n + max_rows, _INF),
            verbose=False,
            eps_abs=eps,
            eps_rel=eps,
            polishing=True,
            max_iter=max_iter,
            polish_refine_iter=5,
        )
        # CSC of A: column j holds the identity entry (row j), then rows n .. n+max_rows-1
        self._Ax = np.zeros((n, 1 + max_rows))
        self._Ax[:, 0] = 1.0
        self._l = np.empty(n + max_rows)
        self._u = np.empty(n + max_rows)

    def solve(self, problem: QPProblem) -> QPSolution:
        n, k = problem.n, problem.b.shape[0]
        if n != self.n or k > self.max_rows:
            raise InputError(f"osqp workspace holds n={self.n}, rows<={self.max_rows}; got n={n}, rows={k}")
        t0 = time.perf_counter()
        self._Ax[:, 1 : 1 + k] = problem.A.T
        self._Ax[:, 1 + k :] = 0.0
        self._l[:n], self._u[:n] = problem.lb, problem.ub
        self._l[n:] = -_INF
        self._u[n : n + k] = problem.b
        self._u[n + k :] = _INF
        np.clip(self._l, -_INF, _INF, out=self._l)
        np.clip(self._u, -_INF, _INF, out=self._u)
        self._solver.update(Px=problem.H[self._tril], q=problem.q, Ax=self._Ax.ravel(), l=self._l, u=self._u)
        res = self._solver.solve(raise_error=False)  # we read the status ourselves
        dt = time.perf_counter() - t0
        val = res.info.status_val
        x = np.asarray(res.x, dtype=float)
        solved = (osqp.SolverStatus.OSQP_SOLVED, osqp.SolverStatus.OSQP_SOLVED_INACCURATE)
        # accept a solution by its measured residual, not by OSQP's own stopping test
        if val in solved and np.isfinite(x).all() and problem.violation(x) <= ACCEPT_VIOLATION:
            return QPSolution(problem, x, QPStatus.OPTIMAL, dt, int(res.info.iter))
        infeasible = val in (
            osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE,
            osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE_INACCURATE,
        )
        status = QPStatus.INFEASIBLE if infeasible else QPStatus.FAILED
        return QPSolution(problem, np.zeros(n), status, dt, int(res.info.iter))
