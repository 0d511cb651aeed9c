"""Small dense QPs: a checked :class:`QPProblem`, a :class:`QPSolution`, one backend per file,
and the registry that makes them by name (:mod:`swarm.safety.qp.registry`)."""

from swarm.safety.qp.problem import QPBackend, QPProblem, QPSolution, QPStatus
from swarm.safety.qp.registry import make_backend

__all__ = ["QPBackend", "QPProblem", "QPSolution", "QPStatus", "make_backend"]
