"""The router process of ``network.topology: router``: a Zenoh router session, nothing else.

    swarm router CONFIG [--run RUN] [--port P] [--secrets DIR]

Every other process of the run is a Zenoh client linked to this router alone; the router
forwards each message to the sessions whose subscriptions match its key (Zenoh's own key
matching and batching: no relay of ours), and its access-control rules accept from each
client only that client's own keys (``swarm.access.acl`` with ``router="router"``). It
declares the liveliness token ``alive/router`` and runs until SIGTERM or SIGINT.
"""

from __future__ import annotations

import sys
import time

from swarm import transport as tp
from swarm.shutdown import StopFlag


def main(run: str, conf) -> int:
    """Route the run's traffic until stopped."""
    stop = StopFlag()
    try:
        session = tp.open_session(conf)
    except Exception as exc:  # zenoh raises its own ZError when the port cannot be listened on
        print(f"router: cannot start: {exc}", file=sys.stderr)
        return 2
    token = tp.declare_liveliness(session, tp.Keys(run).alive("router"))
    print("router: listening", file=sys.stderr, flush=True)
    while not stop:
        time.sleep(0.1)  # nothing to do: Zenoh's own threads route; this only waits for a signal
    token.undeclare()
    return 0
