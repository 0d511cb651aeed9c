"""c3swarm: quadrotor swarms kept safe by collision-cone CBF quadratic programs.

* ``swarm.safety``: the C3BF-QP safety core (barriers, their constraint rows, the filter,
  obstacles, the QP backends); pure functions and small classes, no I/O.
* ``swarm.model``, ``swarm.rotation``, ``swarm.control``, ``swarm.crazyflie_fw``: the
  quadrotor, its reference controllers and the Crazyflie firmware's rules.
* ``swarm.config``: scenario files, checked.
* ``swarm.realism``: the world's imperfections (aerodynamics, motors, wind, sensing,
  communication) for both simulators; pure, no I/O.
* ``swarm.net``: the runtime's wiring (Zenoh transport, messages, access control,
  neighbour tables, bundles).
* ``swarm.offline``: what runs without the swarm's processes (the in-process closed loop,
  the ORCA baseline, scenario generation, metrics).
* ``swarm.runs``: launching, recording, reporting and sweeping runs; ``swarm.cli``.

Importing it first drops numba's cached kernels if any source file changed since they were
compiled (:mod:`swarm.kernel_cache`): numba alone would keep a kernel whose callee in
another file changed."""

import os as _os
from pathlib import Path as _Path

if not _os.environ.get("NUMBA_CACHE_DIR"):  # (a cache elsewhere is the caller's to manage)
    from swarm.kernel_cache import clear_stale as _clear_stale

    _clear_stale([_Path(__file__).resolve().parent])

from swarm._moved import install as _install_moved

_install_moved()  # the modules' old import paths, for one release (swarm._moved)
