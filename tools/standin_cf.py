"""A stand-in Crazyflie for tests and demos: speaks CRTP over cflib's UDP link on loopback.

It binds a UDP port on 127.0.0.1, decodes every CRTP packet it receives (one per
datagram: a header byte ``port << 4 | 3 << 2 | channel``, then up to 30 data bytes),
records what a Crazyflie would act on, and acknowledges each packet with an empty one,
as the radio does. ``deaf()`` stops the acknowledgements: the link, seen from cflib, is lost.

Decoded, with the firmware's meaning:

* port 3 (commander), channel 0: ``<fffH`` roll [deg], pitch [deg] (cflib sends it
  negated), yaw rate [deg/s], thrust, a legacy RPYT setpoint;
* port 7 (generic commander), type 0: the stop setpoint;
* port 6 (localization), channel 1, type 8: ``<Bfffffff`` external pose;
* port 9 (supervisor), channel 1, command 3, and port 6, channel 1, type 3: an
  emergency stop.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from dataclasses import dataclass, field


@dataclass
class Setpoint:
    t: float
    roll_deg: float
    pitch_deg: float  # as the caller of cflib's send_setpoint meant it (un-negated)
    yawrate_dps: float
    thrust: int


@dataclass
class StandIn:
    sock: socket.socket
    setpoints: list[Setpoint] = field(default_factory=list)
    poses: list[tuple[float, ...]] = field(default_factory=list)
    estops: list[float] = field(default_factory=list)
    stops: list[float] = field(default_factory=list)
    packets: int = 0
    _deaf: threading.Event = field(default_factory=threading.Event)
    _done: threading.Event = field(default_factory=threading.Event)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    @classmethod
    def start(cls, port: int = 0) -> StandIn:
        """Listen on 127.0.0.1:``port`` (0: any free port; see :attr:`uri`)."""
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", port))
        s.settimeout(0.05)
        st = cls(s)
        threading.Thread(target=st._run, daemon=True).start()
        return st

    @property
    def uri(self) -> str:
        return f"udp://127.0.0.1:{self.sock.getsockname()[1]}"

    def deaf(self) -> None:
        self._deaf.set()

    def close(self) -> None:
        self._done.set()

    def wait_for(self, what: str, n: int = 1, timeout_s: float = 20.0) -> bool:
        """Wait until ``len(self.<what>) >= n`` (polling its own list, not the network)."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self._lock:
                if len(getattr(self, what)) >= n:
                    return True
            time.sleep(0.01)
        return False

    def _run(self) -> None:
        while not self._done.is_set():
            try:
                data, addr = self.sock.recvfrom(64)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                continue
            self._decode(data)
            if not self._deaf.is_set():
                self.sock.sendto(b"\xf3", addr)  # an empty packet back (port 15, channel 3)
        self.sock.close()

    def _decode(self, data: bytes) -> None:
        h, body, now = data[0], data[1:], time.monotonic()
        port, ch = (h >> 4) & 0x0F, h & 0x03
        with self._lock:
            self.packets += 1
            if port == 3 and ch == 0 and len(body) == 14:
                r, p, y, thr = struct.unpack("<fffH", body)
                self.setpoints.append(Setpoint(now, r, -p, y, thr))
            elif port == 7 and body[:1] == b"\x00":
                self.stops.append(now)
            elif port == 6 and ch == 1 and body[:1] == b"\x08" and len(body) == 29:
                self.poses.append(struct.unpack("<Bfffffff", body)[1:])
            elif (port == 9 and ch == 1 and body[:1] == b"\x03") or (port == 6 and ch == 1 and body[:1] == b"\x03"):
                self.estops.append(now)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="Stand-in Crazyflies on loopback (UDP), for demos without hardware.")
    ap.add_argument("--port", type=int, action="append", required=True, help="one stand-in per port (repeatable)")
    args = ap.parse_args()
    drones = [StandIn.start(p) for p in args.port]
    print("stand-ins at " + ", ".join(d.uri for d in drones) + " (Ctrl-C to end)", flush=True)
    try:
        while True:
            time.sleep(1.0)
            for d in drones:
                last = d.setpoints[-1] if d.setpoints else None
                print(f"{d.uri}: {len(d.setpoints)} setpoints, {len(d.poses)} poses, {len(d.estops)} emergency stops"
                      + (f"; last roll {last.roll_deg:+.1f} pitch {last.pitch_deg:+.1f} deg, thrust {last.thrust}"
                         if last else ""), flush=True)  # fmt: skip
    except KeyboardInterrupt:
        pass
