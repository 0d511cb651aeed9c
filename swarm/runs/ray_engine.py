"""``swarm sweep --engine ray``: each point of a sweep as one Ray task.

A task reserves the CPUs its run's processes need (one per agent, the world, the recorder
and, where the run has one, the router or bundle relay: :func:`cpus_needed`, at most the
largest node's CPUs so that every run can be placed), flies the run as ``--engine local``
does in a run folder of its own (its own run id and ports, Zenoh scouting off, as every
run), and returns its results row. Ray is an optional extra (``pip install -e
'.[cluster]'``), imported only here.

Ray ends at most a task's direct children when the task is cancelled or its worker dies;
each of a run's processes leads a process group of its own. So a task first starts
:mod:`swarm.runs.reaper`, which ends every group of the run once the worker is gone, and
ends it when the run is over. A worker that dies is retried once (Ray's ``max_retries``):
the retry flies the point again in a fresh folder (the first attempt's is kept beside it,
``<run>.attempt1``) and its row says ``attempts: 2``; a point whose worker died twice, or
whose task failed, is a row with the reason in ``error``.

The code must be installed alike on every node (the same checkout, ``pip install -e
'.[cluster]'``); run folders are written where each task runs, so on several machines
``--out`` should be a shared file system.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from swarm.errors import InputError
from swarm.runs.point import Job, fly

if TYPE_CHECKING:
    from swarm.config import ScenarioConfig

ATTEMPT_FILE = "attempt"
"""In a run folder: which attempt of its point made it (1, or 2 after a worker died)."""
WORKER_PID_FILE = "worker.pid"
"""In a run folder: the pid of the Ray worker that flies it."""


def import_ray() -> Any:
    """The ``ray`` module, or an error that names the extra to install."""
    try:
        import ray
    except ImportError:
        raise InputError("--engine ray needs Ray: pip install -e '.[cluster]'") from None
    return ray


def cpus_needed(cfg: ScenarioConfig) -> int:
    """CPUs a run of ``cfg`` keeps busy: its agents, world and recorder, and its router or
    bundle relay where it has one."""
    relay = cfg.topology == "router" or cfg.uses_bundles
    return len(cfg.agents) + 2 + int(relay)


def fly_task(job: Job) -> dict[str, Any]:
    """One point, inside a Ray worker: the reaper first, then the run."""
    folder = job.folder
    attempt = 1
    if (folder / ATTEMPT_FILE).exists():  # a worker died flying it: keep what it left, fly it again
        attempt = int((folder / ATTEMPT_FILE).read_text()) + 1
        shutil.move(folder, folder.with_name(f"{folder.name}.attempt{attempt - 1}"))
    folder.mkdir(parents=True, exist_ok=True)
    (folder / ATTEMPT_FILE).write_text(str(attempt))
    (folder / WORKER_PID_FILE).write_text(str(os.getpid()))
    reaper = subprocess.Popen([sys.executable, "-m", "swarm.runs.reaper", str(folder)], start_new_session=True)
    try:
        row = fly(job)
    finally:
        reaper.terminate()
        reaper.wait()
    return {**row, "attempts": attempt}


def _started(job: Job, since: float) -> bool:
    """Whether a worker has begun ``job`` (its folder's worker pid written after ``since``,
    a ``time.time()``; run folders are on a file system the driver sees, as ``--out`` must be)."""
    try:
        return (job.folder / WORKER_PID_FILE).stat().st_mtime >= since
    except OSError:
        return False


def run(
    jobs: list[Job],
    finished: Callable[[Job, dict[str, Any]], None],
    address: str | None = None,
    started: Callable[[dict[str, Any]], None] | None = None,
) -> None:
    """Fly ``jobs`` on Ray (the cluster at ``address``, or a local one) and hand each row
    to ``finished`` as its run ends; ``started`` hears each point's first columns once a
    worker has begun it (seen by its run folder, every half second)."""
    ray = import_ray()
    if not jobs:
        return
    ray.init(address=address, ignore_reinit_error=True, include_dashboard=False, log_to_driver=False)
    largest = max((n["Resources"].get("CPU", 0.0) for n in ray.nodes() if n.get("Alive")), default=1.0)
    task = ray.remote(max_retries=1, retry_exceptions=False)(fly_task)
    since = time.time()
    pending = {task.options(num_cpus=min(float(cpus_needed(job.cfg)), largest)).remote(job): job for job in jobs}
    waiting = {job.index: job for job in jobs}  # not yet begun by a worker
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)
            ended = {pending[ref].index for ref in done}
            for job in [j for j in waiting.values() if j.index in ended or _started(j, since)]:
                del waiting[job.index]
                if started:
                    started(job.head)
            for ref in done:
                job = pending.pop(ref)
                try:
                    row = ray.get(ref)
                except ray.exceptions.RayError as exc:  # its worker died twice, or the task could not run
                    row = {**job.head, "success": 0, "error": f"{type(exc).__name__}: {str(exc).splitlines()[0]}"}
                finished(job, row)
    except BaseException:  # interrupted: end the runs still flying (their reapers end their processes)
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
