"""Graceful stop: SIGTERM and SIGINT set a flag the loop checks (a process's loop: :class:`StopFlag`;
a launcher's, while it holds its children: :class:`StopSignals`)."""

from __future__ import annotations

import signal
from types import FrameType
from typing import Any


class StopFlag:
    """``bool(flag)`` turns true on SIGTERM or SIGINT (or :meth:`set`)."""

    def __init__(self) -> None:
        self.now = False
        signal.signal(signal.SIGTERM, self._handler)
        signal.signal(signal.SIGINT, self._handler)

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        self.now = True

    def set(self) -> None:
        self.now = True

    def __bool__(self) -> bool:
        return self.now


class StopSignals:
    """While entered, Ctrl-C, ``kill`` and a closed terminal (SIGINT, SIGTERM, SIGHUP) set
    :attr:`now` and count in :attr:`count` instead of killing the launcher: the children run
    in their own process groups, so a launcher that just died would leave them flying
    (``swarm run`` lands them on the first, ``swarm.landing``)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

    def __init__(self) -> None:
        self.now = False
        self.count = 0  # stop signals received while entered
        self._old: dict[int, Any] = {}

    def _set(self, signum: int, frame: Any) -> None:
        self.now = True
        self.count += 1

    def __enter__(self) -> StopSignals:
        self._old = {sig: signal.signal(sig, self._set) for sig in self.SIGNALS}
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)
