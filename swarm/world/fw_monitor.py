"""The relay's own log client of one firmware (``log.c``, protocol v2): the table of contents,
then the supervisor's bits, the setpoint it flies and its position estimate at 100 Hz
(:class:`LogMonitor`)."""

from __future__ import annotations

import math
import struct

from swarm.world.fw_crtp import (
    CMD_GET_INFO_V2,
    CMD_GET_ITEM_V2,
    CONTROL_CREATE_BLOCK_V2,
    CONTROL_START_BLOCK,
    LOG_CONTROL_CH,
    LOG_DATA_CH,
    LOG_TOC_CH,
    LOG_TYPES,
    MONITOR_BLOCK,
    MONITOR_PERIOD_10MS,
    MONITOR_VARS,
    PORT_LOG,
    header,
)


class LogMonitor:
    """This process's own log client of one firmware (log.c, protocol v2): the table of
    contents, then :data:`MONITOR_VARS` in block :data:`MONITOR_BLOCK` at 100 Hz. It asks one
    thing at a time and asks again after 50 ms without an answer."""

    RETRY_S = 0.05

    def __init__(self) -> None:
        self.toc: dict[str, tuple[int, int]] = {}  # "group.name" -> (id, type)
        self.n_items: int | None = None
        self.next_item = 0
        self.fields: list[tuple[str, str]] = []  # (name, struct format) in block order
        self.stage = "info"  # info, items, create, start, running
        self.sent_s = -math.inf
        self.missing: list[str] = []

    @property
    def running(self) -> bool:
        return self.stage == "running"

    def request(self, now: float) -> bytes | None:
        """The next request to send, or None (waiting for an answer, or running)."""
        if self.stage == "running" or now - self.sent_s < self.RETRY_S:
            return None
        self.sent_s = now
        if self.stage == "info":
            return bytes([header(PORT_LOG, LOG_TOC_CH), CMD_GET_INFO_V2])
        if self.stage == "items":
            return bytes([header(PORT_LOG, LOG_TOC_CH), CMD_GET_ITEM_V2]) + struct.pack("<H", self.next_item)
        if self.stage == "create":
            spec = b"".join(struct.pack("<BH", t << 4 | t, i) for i, t in (self.toc[n] for n, _ in self.fields))
            return bytes([header(PORT_LOG, LOG_CONTROL_CH), CONTROL_CREATE_BLOCK_V2, MONITOR_BLOCK]) + spec
        return bytes([header(PORT_LOG, LOG_CONTROL_CH), CONTROL_START_BLOCK, MONITOR_BLOCK, MONITOR_PERIOD_10MS])

    def restart_block(self) -> None:
        """The client reset the firmware's logging: create the block again."""
        if self.stage in ("start", "running"):
            self.stage, self.sent_s = "create", -math.inf

    def answer(self, ch: int, data: bytes) -> bool:
        """Take an answer meant for the monitor; False when it is not one (relay it)."""
        if ch == LOG_TOC_CH and self.stage in ("info", "items") and data:
            if self.stage == "info" and data[0] == CMD_GET_INFO_V2 and len(data) >= 7:
                self.n_items = struct.unpack_from("<H", data, 1)[0]
                self.stage, self.sent_s = "items", -math.inf
                return True
            if self.stage == "items" and data[0] == CMD_GET_ITEM_V2 and len(data) >= 4:
                ident, t = struct.unpack_from("<HB", data, 1)
                if ident != self.next_item:
                    return True  # a repeated answer
                group, name = data[4:].split(b"\0")[:2]
                self.toc[f"{group.decode()}.{name.decode()}"] = (ident, t & 0x0F)
                self.next_item += 1
                self.sent_s = -math.inf
                if self.n_items is not None and self.next_item >= self.n_items:
                    self.fields = [(n, LOG_TYPES[self.toc[n][1]]) for n in MONITOR_VARS if n in self.toc]
                    self.missing = [n for n in MONITOR_VARS if n not in self.toc]
                    self.stage = "create"
                return True
            return False
        if ch == LOG_CONTROL_CH and len(data) >= 3 and data[1] == MONITOR_BLOCK:
            if data[0] == CONTROL_CREATE_BLOCK_V2 and self.stage == "create":
                self.stage, self.sent_s = "start", -math.inf  # (17, EEXIST: it is there already)
            elif data[0] == CONTROL_START_BLOCK and self.stage == "start" and data[2] == 0:
                self.stage = "running"
            return True
        return ch == LOG_DATA_CH and len(data) >= 4 and data[0] == MONITOR_BLOCK

    def decode(self, data: bytes) -> dict[str, float]:
        """A data packet of the block: its variables by name, and the firmware's time ``t_fw_ms``."""
        out = {"t_fw_ms": float(data[1] | data[2] << 8 | data[3] << 16)}
        k = 4
        for name, fmt in self.fields:
            n = struct.calcsize(fmt)
            out[name] = float(struct.unpack_from(fmt, data, k)[0])
            k += n
        return out
