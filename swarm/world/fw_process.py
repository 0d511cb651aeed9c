"""The firmware's process as the relay starts it: the binary (:func:`find_cf2`), tied to the
relay's life, and its CPU time."""

from __future__ import annotations

import ctypes
import math
import os
import signal
from pathlib import Path

CF2_ENV = "C3SWARM_CF2"
"""The environment variable naming the firmware binary when none is given."""


def find_cf2(given: str | None) -> Path:
    """The firmware binary: ``given``, else ``$C3SWARM_CF2``; raises saying how to get one."""
    path = given or os.environ.get(CF2_ENV, "")
    if not path:
        raise FileNotFoundError(
            "no Crazyflie firmware binary: build CrazySim's cf2 (bash crazyflie-sitl/build.sh OUT_DIR, or "
            f"CrazySim's sitl_make) and give its path as mocap.options.cf2 or in ${CF2_ENV}"
        )
    p = Path(path).expanduser()
    if not (p.is_file() and os.access(p, os.X_OK)):
        raise FileNotFoundError(f"the Crazyflie firmware binary {p} is not an executable file")
    return p


def die_with_parent() -> None:
    """In the firmware's process before exec: die when this relay dies (Linux prctl
    PR_SET_PDEATHSIG), so no firmware spins on at half a core behind a killed relay."""
    try:
        ctypes.CDLL(None).prctl(1, signal.SIGKILL)
    except (OSError, AttributeError):
        pass


def cpu_s(pid: int) -> float:
    """User plus system CPU time [s] of a live process (/proc/PID/stat, clock ticks)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return math.nan
