"""Ends a run's processes once the process that started it is gone.

    python -m swarm.runs.reaper RUN_DIR

A sweep's Ray task (:mod:`swarm.runs.ray_engine`) starts this first, as its own child in a
session of its own, then starts the run. Each of the run's processes has a process group
of its own (:class:`swarm.runs.launch.RunHandle` writes them to ``RUN_DIR/process_groups``,
one per line, as it starts them), so a Ray worker that is killed or lost would leave them
behind: Ray ends a task's direct children at most. This process waits on its parent (a
Linux pidfd, readable once the parent has exited); when the parent is gone it sends
SIGTERM to every listed group, SIGKILL two seconds later, and exits. The task ends it
with SIGTERM when the run is over."""

from __future__ import annotations

import os
import select
import signal
import sys
import time
from pathlib import Path

GROUPS_FILE = "process_groups"
"""The file in a run folder that lists the run's process groups (one pgid per line)."""


def process_groups(run_dir: Path | int) -> list[int]:
    """The process groups listed in ``run_dir`` (a path, or an open directory's file
    descriptor, which follows the folder if it is renamed); none yet: an empty list."""
    try:
        if isinstance(run_dir, int):
            with open(GROUPS_FILE, opener=lambda name, flags: os.open(name, flags, dir_fd=run_dir)) as f:
                text = f.read()
        else:
            text = (run_dir / GROUPS_FILE).read_text()
    except FileNotFoundError:
        return []
    return [int(line) for line in text.split() if line.isdigit()]


def _signal(groups: list[int], sig: int) -> None:
    for g in groups:
        try:
            os.killpg(g, sig)
        except (ProcessLookupError, PermissionError):
            pass


def reap(run_dir: Path | int, grace_s: float = 2.0) -> None:
    """SIGTERM to every group of the run, then SIGKILL after ``grace_s`` seconds to every
    group listed by then (a child forked just before its launcher died lists itself an
    instant later: :class:`swarm.runs.launch.RunHandle`)."""
    _signal(process_groups(run_dir), signal.SIGTERM)
    time.sleep(grace_s)
    _signal(process_groups(run_dir), signal.SIGKILL)


def main(run_dir: Path) -> int:
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # the task ended it: the run is over
    folder = os.open(run_dir, os.O_RDONLY | os.O_DIRECTORY)  # (a retry may rename the folder)
    parent = os.getppid()
    try:
        fd: int | None = os.pidfd_open(parent)
    except ProcessLookupError:  # already gone
        fd = None
    if fd is not None and os.getppid() == parent:  # (not reparented before the pidfd was open)
        select.select([fd], [], [])  # readable once the parent has exited
    reap(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
