"""Graceful stop for process loops: SIGTERM and SIGINT set a flag the loop checks."""

from __future__ import annotations

import signal
from types import FrameType


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
