"""Starts a run's processes by forking one that has imported what they need, once.

    python -m swarm.runs.forkserver

Each process of a run (router, recorder, world, agents) is ``python -m MODULE ARGS``. Started
from scratch, each spends about a second of CPU importing numpy, numba (LLVM), pydantic,
Zenoh and PyBullet before it does anything: with 8 agents, most of a short run's start on two
cores. The fork server imports them once (:data:`PRELOAD`) and forks each process from
itself. A child then is what ``subprocess.Popen([python, "-m", MODULE, *ARGS],
start_new_session=True, env=ENV, stdout=LOG, stderr=STDOUT)`` makes, run by :mod:`runpy`
instead of a new interpreter: a session and process group of its own, listed in the run's
``process_groups`` before it runs (:mod:`swarm.runs.reaper`), its log on stdout and stderr
(written through, as ``PYTHONUNBUFFERED``), nothing on stdin, ``ENV`` as its environment.

The server holds no Zenoh session and no thread of its own, so a fork copies no runtime
(numpy's BLAS threads are stopped and restarted across a fork by OpenBLAS itself), and what it
holds is frozen out of the children's garbage collector (``gc.freeze``). Before it forks a run's
agents it loads their compiled kernels (``{"warm": CONFIG}``: an agent's warm-up, once). Its
protocol is lines of JSON on stdin (a :class:`Request`, or a warm-up) and stdout (``{"pid": N}``
per request, ``{"exit": N, "code": C}`` per child reaped: C as ``Popen.returncode``, negative for
a signal). It exits when its stdin closes (its launcher is gone); the children run on, ended as
before by their launcher or the reaper.

:class:`ForkServer` is the launcher's side; :class:`Child` stands for ``subprocess.Popen``
where :class:`swarm.runs.launch.RunHandle` uses one. One server serves every run of a
launcher whose environment has not changed since it started (:func:`shared`)."""

from __future__ import annotations

import atexit
import ctypes
import gc
import importlib
import io
import json
import os
import runpy
import select
import signal
import subprocess
import sys
import threading
import time
import traceback
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from swarm.proctitle import name_process

PRELOAD = (
    "numpy",
    "numba",
    "pydantic",
    "zenoh",
    "pybullet",
    "swarm.cli",
    "swarm.agents.agent",
    "swarm.world.main",
    "swarm.runs.record",
    "swarm.runs.router",
)
"""What the server imports before it forks (what every process of a run imports anyway)."""

DISABLE_ENV = "SWARM_FORKSERVER"
"""``SWARM_FORKSERVER=0``: start every process of a run from scratch (``subprocess``)."""


@dataclass(frozen=True)
class Request:
    """One process to start: ``python -m module *args``."""

    module: str
    args: list[str]
    log: str  # its stdout and stderr (created, truncated)
    env: dict[str, str]
    groups: str  # the run's process_groups file: its pid is appended before it runs


def _child(req: Request, proto_fd: int) -> None:
    """In the forked child: become what ``Popen(..., start_new_session=True)`` makes, run the
    module as ``__main__``, and exit with its code (never return into the server)."""
    code = 1
    try:
        os.close(proto_fd)
        os.setsid()
        fd = os.open(req.groups, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        os.write(fd, b"%d\n" % os.getpid())
        os.close(fd)
        log = os.open(req.log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.dup2(log, 1)
        os.dup2(log, 2)
        os.close(log)
        os.close(null)
        sys.stdin = io.TextIOWrapper(io.FileIO(0, "r", closefd=False))
        sys.stdout = io.TextIOWrapper(io.FileIO(1, "w", closefd=False), write_through=True)
        sys.stderr = io.TextIOWrapper(io.FileIO(2, "w", closefd=False), write_through=True, errors="backslashreplace")
        os.environ.clear()
        os.environ.update(req.env)
        sys.argv = [req.module, *req.args]
        warnings.filterwarnings("ignore", "'.*' found in sys.modules", RuntimeWarning, "runpy")  # (imported: PRELOAD)
        try:
            runpy.run_module(req.module, run_name="__main__", alter_sys=True)
            code = 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
            if e.code is not None and not isinstance(e.code, int):
                print(e.code, file=sys.stderr)
        except KeyboardInterrupt:  # as Python ends on an unhandled Ctrl-C: killed by SIGINT
            traceback.print_exc()
            atexit._run_exitfuncs()
            signal.signal(signal.SIGINT, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGINT)
        except BaseException:
            traceback.print_exc()
            code = 1
        atexit._run_exitfuncs()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:
                pass
    finally:
        os._exit(code & 0xFF)


def _warm(config: str) -> None:
    """Load the compiled kernels the agents of the run ``config`` (its file) will run, here,
    once for every agent forked after (swarm.agents.agent.warm_kernels). Only saves time: a
    config it cannot warm is left to the agents to meet (and name)."""
    from swarm.agents.agent import warm_kernels
    from swarm.config import load

    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        warm_kernels(load(config))
    except Exception as exc:
        print(f"fork server: no warm-up for {config}: {type(exc).__name__}: {exc}", file=sys.stderr)
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


def serve() -> int:
    """The server's loop (``python -m swarm.runs.forkserver``), named ``swarm fork-server`` (each
    child names itself as its process of a run: ``swarm.proctitle``)."""
    name_process("fork-server")
    proto_fd = os.dup(1)  # the protocol's; fd 1 goes to stderr (PyBullet prints on import)
    os.dup2(2, 1)
    for name in PRELOAD:
        importlib.import_module(name)
    sys.stdout.flush()
    ctypes.CDLL(None).fflush(None)  # (C's buffered stdout, or each child would write it again)
    gc.freeze()  # what is here now, the children's collector never walks (nor copies, by touching it)

    def say(**msg: Any) -> None:
        os.write(proto_fd, json.dumps(msg).encode() + b"\n")

    pending = b""
    while True:
        ready, _, _ = select.select([0], [], [], 0.02)  # (stdin's fd: Python's buffer would hide lines from select)
        if ready:
            chunk = os.read(0, 65536)
            if not chunk:
                return 0
            pending += chunk
            *lines, pending = pending.split(b"\n")
            for line in filter(None, lines):
                msg = json.loads(line)
                if "warm" in msg:
                    _warm(msg["warm"])
                    gc.freeze()
                    continue
                req = Request(**msg)
                pid = os.fork()
                if pid == 0:
                    _child(req, proto_fd)
                say(pid=pid)
        while True:
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                break
            if pid == 0:
                break
            say(exit=pid, code=os.waitstatus_to_exitcode(status))


@dataclass
class Child:
    """A process the server started: the part of ``subprocess.Popen`` a launcher uses."""

    pid: int
    server: ForkServer
    returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            self.server.pump()
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired([str(self.pid)], timeout or 0.0)
            self.server.pump(0.05)
        assert self.returncode is not None
        return self.returncode


@dataclass
class ForkServer:
    """The launcher's side of a fork server (see the module's docstring)."""

    proc: subprocess.Popen[bytes]
    env: dict[str, str]  # the launcher's environment when it was started
    children: dict[int, Child] = field(default_factory=dict)  # started, not yet reaped
    _started: list[Child] = field(default_factory=list)  # said, not yet handed to spawn
    _buf: bytes = b""
    # one thread at a time talks to the server: a spawn's request and its pid are one exchange
    # (a sweep's runs start their processes from threads of one launcher)
    _lock: threading.RLock = field(default_factory=threading.RLock)

    @classmethod
    def start(cls) -> ForkServer:
        proc = subprocess.Popen(
            [sys.executable, "-m", "swarm.runs.forkserver"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            start_new_session=True,  # (a Ctrl-C at the terminal is the launcher's to handle)
        )
        return cls(proc, _environ())

    def alive(self) -> bool:
        return self.proc.poll() is None

    def pump(self, block_s: float = 0.0) -> None:
        """Read what the server said (waiting up to ``block_s`` for it): children started
        and children's exits. With the server gone, a child that no longer exists has
        ended with an unknown code (1)."""
        with self._lock:
            self._pump(block_s)

    def _pump(self, block_s: float) -> None:
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        if self.proc.returncode is None and select.select([fd], [], [], block_s)[0]:
            chunk = os.read(fd, 65536)
            if not chunk:
                self.proc.wait()
            self._buf += chunk
        *lines, self._buf = self._buf.split(b"\n")
        for line in lines:
            msg = json.loads(line)
            if "pid" in msg:
                child = self.children[msg["pid"]] = Child(msg["pid"], self)
                self._started.append(child)
            elif "exit" in msg and msg["exit"] in self.children:
                self.children.pop(msg["exit"]).returncode = msg["code"]
        if self.proc.returncode is not None:
            for pid in list(self.children):
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    self.children.pop(pid).returncode = 1
            if block_s > 0:
                time.sleep(block_s)

    def _send(self, msg: dict[str, Any]) -> None:
        assert self.proc.stdin is not None
        with self._lock:
            self.proc.stdin.write(json.dumps(msg).encode() + b"\n")
            self.proc.stdin.flush()

    def warm(self, config: Path) -> None:
        """Have the server load the kernels the agents of the run ``config`` (its file) run,
        before it forks them (:func:`_warm`; processes asked for after wait for it)."""
        self._send({"warm": str(config)})

    def spawn(self, args: list[str], log: Path, env: dict[str, str], groups: Path) -> Child:
        """``python *args`` (``args`` starts with ``-m MODULE``) forked from the server."""
        if args[:1] != ["-m"] or len(args) < 2:
            raise ValueError(f"the fork server runs modules (-m MODULE ...), not {args[:2]}")
        with self._lock:  # (the pid the server says next is this request's)
            self._send(asdict(Request(args[1], args[2:], str(log), env, str(groups))))
            deadline = time.monotonic() + 300.0  # (the server's imports, the first time; a warm-up on a cold cache)
            while not self._started:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"the fork server did not start {args[1]} (exit code {self.proc.returncode})")
                self.pump(0.1)
            return self._started.pop(0)


_SHARED: ForkServer | None = None
_SHARED_LOCK = threading.Lock()
VOLATILE = ("PYTEST_CURRENT_TEST", "ZENOH_RUNTIME")
"""Variables that change in a launcher without changing what a server imports (pytest's for
each test; Zenoh's runtime, read at a process's first session: each child gets its own)."""


def _environ() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in VOLATILE}


def shared() -> ForkServer | None:
    """This process's fork server, started the first time, and again if it died or the
    environment changed since (what a server imports may depend on it: ``NUMBA_CACHE_DIR``);
    a server replaced serves its children until they end. None where ``SWARM_FORKSERVER=0``
    or the platform has no ``fork``."""
    global _SHARED
    if os.environ.get(DISABLE_ENV) == "0" or not hasattr(os, "fork"):
        return None
    with _SHARED_LOCK:
        if _SHARED is None or not _SHARED.alive() or _SHARED.env != _environ():
            _SHARED = ForkServer.start()
        return _SHARED


if __name__ == "__main__":
    sys.exit(serve())
