"""The Crazyflie link guard: the one process that holds a drone's radio link.

    python -m agents.cf_guard --uri URI [--link-timeout S] [--no-replies]

An agent flying a real Crazyflie starts this as a child in its own session and writes
msgpack frames to its standard input. The frames, with units:

* ``["sp", roll_deg, pitch_deg, yawrate_dps, thrust]``: a setpoint for cflib's
  ``Commander.send_setpoint``, with thrust the 16-bit command;
* ``["pose", x, y, z, qx, qy, qz, qw]``: the motion-capture pose [m, world] for
  ``Localization.send_extpose``;
* ``["stop"]``: the stop setpoint (motors off, as after landing);
* ``["estop", reason]``: an emergency stop;
* ``["bye"]``: a clean end. The guard sends the stop setpoint and exits.

The guard sends an emergency stop by itself in three cases:

* its standard input closes without ``bye``: the agent died, even by SIGKILL;
* the link reports an error;
* no packet has come back for ``--link-timeout`` seconds. The guard polls the link with
  null packets every 50 ms, as cflib's radio driver does; the radio acknowledges every
  packet, and so does the test stand-in. ``--no-replies`` turns this check off.

It writes ``READY`` and ``LINK_LOST <reason>`` lines to its standard output for the agent.

An emergency stop goes out both ways, the supervisor's command (protocol 12 and later)
and the older localization packet, each three times. A firmware ignores the form it
does not know.
"""

from __future__ import annotations

import argparse
import struct
import sys
import threading
import time
from typing import Any

import msgpack


class _Shim:
    """The part of cflib's ``Crazyflie`` that ``Commander`` and ``Localization`` use."""

    def __init__(self, driver: Any) -> None:
        self.driver = driver
        self.lock = threading.Lock()

    def send_packet(self, pk: Any) -> None:
        with self.lock:
            self.driver.send_packet(pk)

    def add_port_callback(self, port: int, cb: Any) -> None:
        pass


def main(uri: str, link_timeout_s: float, expect_replies: bool) -> int:
    import cflib.crtp
    from cflib.crazyflie.commander import Commander
    from cflib.crazyflie.localization import Localization
    from cflib.crazyflie.supervisor import CMD_EMERGENCY_STOP, SUPERVISOR_CH_COMMAND
    from cflib.crtp.crtpstack import CRTPPacket, CRTPPort

    out_lock = threading.Lock()

    def say(line: str) -> None:
        with out_lock:
            sys.stdout.write(line + "\n")
            sys.stdout.flush()

    lost = threading.Event()
    link_errors: list[str] = []
    cflib.crtp.init_drivers()
    driver = cflib.crtp.get_link_driver(uri, link_error_callback=lambda msg: link_errors.append(str(msg)))
    if driver is None:
        say(f"LINK_LOST no driver for {uri}")
        return 2
    cf = _Shim(driver)
    commander, loc = Commander(cf), Localization(cf)

    def estop(reason: str) -> None:
        for _ in range(3):
            pk = CRTPPacket()
            pk.set_header(CRTPPort.SUPERVISOR, SUPERVISOR_CH_COMMAND)
            pk.data = struct.pack("<B", CMD_EMERGENCY_STOP)
            cf.send_packet(pk)
            legacy = CRTPPacket()
            legacy.set_header(CRTPPort.LOCALIZATION, Localization.GENERIC_CH)
            legacy.data = struct.pack("<B", Localization.EMERGENCY_STOP)
            cf.send_packet(legacy)
        print(f"cf_guard {uri}: emergency stop ({reason})", file=sys.stderr)

    def watch_link() -> None:
        """Poll the link with null packets (as the radio driver does) and watch replies."""
        last_rx = time.monotonic()
        while not lost.is_set():
            cf.send_packet(CRTPPacket(0xFF))  # a null packet: port 15, channel 3, no data
            pk = driver.receive_packet(0.05)
            now = time.monotonic()
            while pk is not None:
                last_rx = now
                pk = driver.receive_packet(0)
            reason = None
            if link_errors:
                reason = f"link error: {link_errors[0]}"
            elif expect_replies and now - last_rx > link_timeout_s:
                reason = f"no reply for {now - last_rx:.2f} s"
            if reason:
                lost.set()
                estop(f"link lost: {reason}")
                say(f"LINK_LOST {reason}")

    watcher = threading.Thread(target=watch_link, daemon=True)
    watcher.start()
    say("READY")
    unpacker = msgpack.Unpacker(raw=False)
    clean = False
    stdin = sys.stdin.buffer
    while True:
        chunk = stdin.read1(4096) if hasattr(stdin, "read1") else stdin.read(4096)
        if not chunk:
            break
        unpacker.feed(chunk)
        for frame in unpacker:
            kind = frame[0] if isinstance(frame, list) and frame else None
            if kind == "sp":
                commander.send_setpoint(float(frame[1]), float(frame[2]), float(frame[3]), int(frame[4]))
            elif kind == "pose":
                loc.send_extpose([float(v) for v in frame[1:4]], [float(v) for v in frame[4:8]])
            elif kind == "stop":
                commander.send_stop_setpoint()
            elif kind == "estop":
                estop(str(frame[1]) if len(frame) > 1 else "asked")
            elif kind == "bye":
                commander.send_stop_setpoint()
                clean = True
                break
            else:
                print(f"cf_guard {uri}: unknown frame {frame!r} dropped", file=sys.stderr)
        if clean:
            break
    if not clean:
        estop("the agent is gone (its pipe closed)")
    lost.set()
    time.sleep(0.05)  # let the last packets leave the socket or radio
    driver.close()
    return 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--uri", required=True)
    ap.add_argument("--link-timeout", type=float, default=0.5)
    ap.add_argument("--no-replies", action="store_true")
    args = ap.parse_args()
    sys.exit(main(args.uri, args.link_timeout, not args.no_replies))
