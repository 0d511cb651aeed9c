"""A process for tests/integration/test_forkserver.py, run as ``python -m
tests.integration.forkchild WHAT [ARG]``: it reports what it is, says it is ready (its pid, in a
datagram to the abstract Unix socket named by ``FORKCHILD_READY``), and then does WHAT (exit
with ARG, raise, or wait for a signal; ``stubborn``: set up as a run's process (swarm.cli), ignore
SIGTERM and wait for a signal)."""

from __future__ import annotations

import json
import os
import signal
import socket
import sys


def main(argv: list[str]) -> int:
    what = argv[0]
    print(
        "FACTS "
        + json.dumps(
            {
                "argv": argv,
                "name": __name__,
                "pid": os.getpid(),
                "pgid": os.getpgid(0),
                "sid": os.getsid(0),
                "env": dict(os.environ),
                "stdin": sys.stdin.read(),
                "threads": len(os.listdir("/proc/self/task")),
            }
        )
    )
    print("to stderr", file=sys.stderr)
    if what == "stubborn":
        from swarm.cli import _pin_cpu

        _pin_cpu()
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if "FORKCHILD_READY" in os.environ:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as ready:
            ready.sendto(b"%d" % os.getpid(), "\0" + os.environ["FORKCHILD_READY"])
    if what == "exit":
        return int(argv[1])
    if what == "raise":
        raise RuntimeError("raised on purpose")
    if what in ("wait", "stubborn"):
        while True:
            signal.pause()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
