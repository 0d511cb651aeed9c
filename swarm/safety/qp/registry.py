"""The QP backends by name, apart from :mod:`swarm.safety.qp.problem` (which no backend's
import leads back to): one backend per file, each imported only when asked for."""

from __future__ import annotations

from swarm.errors import InputError
from swarm.safety.qp.problem import QPBackend

BACKENDS = ("daqp", "osqp")
"""The backends :func:`make_backend` knows."""


def make_backend(name: str, n: int, max_rows: int) -> QPBackend:
    """A backend by name (``daqp`` or ``osqp``) for ``n`` variables and at most
    ``max_rows`` rows of ``A`` (OSQP keeps one persistent workspace of that size)."""
    if name == "daqp":
        from swarm.safety.qp.daqp_backend import DaqpBackend

        return DaqpBackend()
    if name == "osqp":
        from swarm.safety.qp.osqp_backend import OsqpBackend

        return OsqpBackend(n, max_rows)
    raise InputError(f"unknown QP backend {name!r}; choose one of {', '.join(BACKENDS)}")
