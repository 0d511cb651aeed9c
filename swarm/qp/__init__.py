"""Small dense QPs: a checked :class:`QPProblem`, a :class:`QPSolution`, one backend per file."""

from swarm.qp.problem import QPBackend, QPProblem, QPSolution, QPStatus, make_backend

__all__ = ["QPBackend", "QPProblem", "QPSolution", "QPStatus", "make_backend"]
