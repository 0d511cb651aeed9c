"""A process of a run names itself where ``ps``, ``top`` and ``py-spy`` show it: its role, its
drone and its run, in place of the interpreter's command line (every process forked from the
fork server would otherwise show as ``python3 -m swarm.runs.forkserver``)."""

from __future__ import annotations

import setproctitle


def title(role: str, run: str | None = None, drone: str | None = None) -> str:
    """``swarm <role> [<drone>] [run=<run>]``, e.g. ``swarm agent cf3 run=circle_8``."""
    return f"swarm {role}" + (f" {drone}" if drone else "") + (f" run={run}" if run else "")


def name_process(role: str, run: str | None = None, drone: str | None = None) -> None:
    """Name this process :func:`title` ``(role, run, drone)``: its command line (``ps``, ``top``'s
    command column) and, cut to 15 bytes by the kernel, its name (``top``'s default, ``ps -o comm``)."""
    name = title(role, run, drone)
    setproctitle.setproctitle(name)
    setproctitle.setthreadtitle(name.removeprefix("swarm ")[:15])
