"""Dense active-set backend (daqp): exact on these small problems."""

from __future__ import annotations

import math
import time

import daqp
import numpy as np

from swarm.safety.qp.problem import QPProblem, QPSolution, QPStatus


class DaqpBackend:
    name = "daqp"

    def __init__(self, primal_tol: float = 1e-9) -> None:
        self.primal_tol = primal_tol
        self._settings = {"primal_tol": primal_tol} if primal_tol != 1e-6 else {}
        # bound and sense buffers by problem size (n, rows)
        self._bufs: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def solve(self, problem: QPProblem) -> QPSolution:
        t0 = time.perf_counter()
        n, k = problem.q.shape[0], problem.b.shape[0]
        bufs = self._bufs.get((n, k))
        if bufs is None:
            lower = np.full(n + k, -np.inf)
            bufs = self._bufs[(n, k)] = (np.empty(n + k), lower, np.zeros(n + k, dtype=np.int32))
        upper, lower, sense = bufs
        sense.fill(0)  # daqp leaves its active set in here: start each solve cold
        upper[:n] = problem.ub
        upper[n:] = problem.b
        lower[:n] = problem.lb
        x, _fval, flag, info = daqp.solve(problem.H, problem.q, problem.A, upper, lower, sense, **self._settings)
        dt = time.perf_counter() - t0
        # (a sum of floats is finite only if every one is: inf - inf is nan)
        if flag == 1 and math.isfinite(sum(x.tolist())):
            return QPSolution(problem, x, QPStatus.OPTIMAL, dt, int(info["iterations"]))
        status = QPStatus.INFEASIBLE if flag == -1 else QPStatus.FAILED
        return QPSolution(problem, np.zeros(n), status, dt, int(info.get("iterations", 0)))
