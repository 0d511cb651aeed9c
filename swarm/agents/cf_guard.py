"""The Crazyflie link guard: the one process on a machine that holds the radio links.

    python -m swarm.agents.cf_guard --serve SOCKET [--exit-when-idle]

A Crazyradio is one USB device. cflib can share it among several links, but only
within one process. So every real drone on a machine talks through one guard server,
and each agent connects to it over a Unix socket. Drones on one radio must share the
channel and data rate and differ in address, e.g. ``radio://0/80/2M/E7E7E7E701`` and
``.../E7E7E7E702``.

The first agent that finds no server starts one, in a session of its own; it outlives
the agent. With ``--exit-when-idle`` the server ends 2 s after its last connection
closes.

Each connection flies one drone. The agent sends msgpack frames, with units:

* ``["hello", uri, link_timeout_s, expect_replies, on_agent_loss]``: first, opens the
  link; ``on_agent_loss`` is ``"estop"`` or ``"watchdog"`` (below);
* ``["sp", roll_deg, pitch_deg, yawrate_dps, thrust]``: cflib's
  ``Commander.send_setpoint``, with thrust the 16-bit command;
* ``["pose", x, y, z, qx, qy, qz, qw]``: the motion-capture pose [m, world], sent with
  ``Localization.send_extpose``;
* ``["stop"]``: the stop setpoint (motors off, as after landing);
* ``["estop", reason]``: an emergency stop;
* ``["bye"]``: a clean end. The server sends the stop setpoint and closes the link.

The server answers ``["ready"]`` once the drone has answered a packet (within
``CONNECT_TIMEOUT_S``), or ``["lost", reason]`` when it does not or the link goes.

The firmware's rules it follows (``swarm.crazyflie_fw`` cites them):

* on opening it sends zero-thrust setpoints: the RPYT commander starts with its thrust
  locked and unlocks only on a setpoint of thrust 0 (crtp_commander_rpyt.c);
* after the stop setpoint (motors off) it keeps sending zero-thrust setpoints every
  ``KEEPALIVE_S`` until the connection ends, and on a clean end for at least
  ``LANDED_AFTER_S`` after the last thrust before it hands the drone back with
  ``send_notify_setpoint_stop``: the supervisor counts a drone as flying for 2 s after
  its motors stop, and one flying without setpoints levels out after 500 ms and is locked
  after 2 s (supervisor.c), which only a reboot undoes.

It sends an emergency stop by itself in three cases:

* the connection closes without ``bye``: the agent died, even by SIGKILL (with
  ``on_agent_loss: watchdog`` it goes silent instead and leaves the drone to the
  firmware's watchdog: level out after 500 ms, motors off and locked after 2 s);
* the link reports an error;
* no packet has come back for ``link_timeout_s``. The server polls each link every
  50 ms with a packet the link answers: on a Crazyradio (``radio://``) a null packet, as
  cflib's radio driver polls, which the radio acknowledges; on a link without
  acknowledgements (``udp://`` to a software-in-the-loop firmware, ``usb://``) a link
  echo (CRTP port 15 channel 0), which the firmware sends back (crtpservice.c ``linkEcho``):
  a firmware answers nothing it is not asked (``swarm.world.sitl_fw`` answers it itself, as
  the drone's radio chip would acknowledge it). Set ``expect_replies`` false to turn this
  check off.

An emergency stop goes out both ways, three times 50 ms apart: the supervisor's command
(CRTP port 9, from protocol 12, firmware 2025.09) and the older localization packet
(``Localization.EMERGENCY_STOP``, crtp_localization_service.c). A firmware that does not
know one form ignores it; in CrazySim's software-in-the-loop build (protocol 7) port 9
carries the simulator's sensors, so there the localization packet is the one that stops it.
The repeats are spread because a link without acknowledgements loses packets in bursts: the
software-in-the-loop firmware queues 5 received packets and drops any that come while the
queue is full (socketlink.c: ``xQueueCreate(5, ...)``, ``xQueueSend(..., 0)``), so a firmware
busy for a few milliseconds loses a back-to-back burst whole.
"""

from __future__ import annotations

import argparse
import os
import socket
import struct
import sys
import threading
import time
from pathlib import Path
from typing import Any

import msgpack

CONNECT_TIMEOUT_S = 3.0  # the drone must answer within this after the link opens
KEEPALIVE_S = 0.05  # zero-thrust setpoints while the motors are off
POLL_S = 0.05  # one poll of the link per this period, however fast it answers
LANDED_AFTER_S = 2.5  # > the supervisor's 2 s flying hysteresis (supervisor.c IS_FLYING_HYSTERESIS_THRESHOLD)
ESTOP_ROUNDS = 3  # the emergency stop's repeats, ...
ESTOP_SPACING_S = 0.05  # ... this far apart: a busy firmware drops what comes meanwhile (socketlink.c)


def default_socket() -> Path:
    """The machine's guard socket (one per user)."""
    return Path(os.environ.get("C3SWARM_CF_SOCKET", f"/tmp/c3swarm-cf-{os.getuid()}.sock"))


def poll_packet(uri: str) -> Any:
    """The packet that polls a link every 50 ms: a null packet (port 15, channel 3, no data)
    on a Crazyradio, which acknowledges every packet; elsewhere a link echo (port 15,
    channel 0), which the firmware sends back (crtpservice.c)."""
    from cflib.crtp.crtpstack import CRTPPacket, CRTPPort

    if uri.startswith("radio://"):
        return CRTPPacket(0xFF)
    pk = CRTPPacket()
    pk.set_header(CRTPPort.LINKCTRL, 0)
    pk.data = b"\x00"
    return pk


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


class _Drone:
    """One connection: one drone's link. :meth:`serve` runs its phases: :meth:`_open`
    (the hello frame, the cflib driver, the thrust unlock, the link-watch thread),
    :meth:`_fly` (the agent's frames until ``bye`` or the connection closes) and
    :meth:`_close` (the emergency stop or silence when the agent is gone)."""

    def __init__(self, conn: socket.socket) -> None:
        self.conn = conn
        self.send_lock = threading.Lock()
        self.lost = threading.Event()
        self.answered = threading.Event()  # the drone answered a packet
        self.uri = "?"
        self.link_timeout_s = 0.0
        self.expect_replies = True
        self.silent_on_loss = False  # on_agent_loss: watchdog
        self.errors: list[str] = []  # the link's error callbacks
        self.motors_off = True  # zero-thrust keep-alive while off
        self.thrust_t = 0.0  # monotonic s of the last thrust
        self.keepalive_t = 0.0  # monotonic s of the last keep-alive setpoint
        self.driver: Any = None
        self.cf: Any = None  # the _Shim over the driver
        self.commander: Any = None
        self.loc: Any = None

    def reply(self, frame: list) -> None:
        with self.send_lock:
            try:
                self.conn.sendall(msgpack.packb(frame))
            except OSError:
                pass

    def serve(self) -> None:
        frames = self._frames(msgpack.Unpacker(raw=False))
        if not self._open(next(frames, None)):
            return
        clean = self._fly(frames)
        self._close(clean)

    def _open(self, hello: Any) -> bool:
        """Open the link the hello frame names; False (after saying why) when it cannot."""
        import cflib.crtp
        from cflib.crazyflie.commander import Commander
        from cflib.crazyflie.localization import Localization

        if not (isinstance(hello, list) and len(hello) == 5 and hello[0] == "hello"):
            self.reply(["lost", f"expected hello, got {hello!r}"])
            return False
        self.uri, self.link_timeout_s, self.expect_replies = str(hello[1]), float(hello[2]), bool(hello[3])
        self.silent_on_loss = hello[4] == "watchdog"
        self.driver = cflib.crtp.get_link_driver(self.uri, link_error_callback=lambda msg: self.errors.append(str(msg)))
        if self.driver is None:
            self.reply(["lost", f"no cflib driver for {self.uri}"])
            return False
        self.cf = _Shim(self.driver)
        self.commander, self.loc = Commander(self.cf), Localization(self.cf)
        for _ in range(3):
            self.commander.send_setpoint(0.0, 0.0, 0.0, 0)  # unlock the RPYT commander's thrust
        threading.Thread(target=self._watch_link, daemon=True).start()
        if self.expect_replies and not self.answered.wait(CONNECT_TIMEOUT_S):
            self.lost.set()
            self.reply(["lost", f"{self.uri} did not answer within {CONNECT_TIMEOUT_S:.0f} s"])
            self.driver.close()
            return False
        self.reply(["ready"])
        return True

    def _estop(self, reason: str) -> None:
        """The emergency stop both ways (supervisor command, legacy localization packet),
        :data:`ESTOP_ROUNDS` times :data:`ESTOP_SPACING_S` apart (returns after the last)."""
        from cflib.crazyflie.localization import Localization
        from cflib.crazyflie.supervisor import CMD_EMERGENCY_STOP, SUPERVISOR_CH_COMMAND
        from cflib.crtp.crtpstack import CRTPPacket, CRTPPort

        for i in range(ESTOP_ROUNDS):
            if i:
                time.sleep(ESTOP_SPACING_S)
            pk = CRTPPacket()
            pk.set_header(CRTPPort.SUPERVISOR, SUPERVISOR_CH_COMMAND)
            pk.data = struct.pack("<B", CMD_EMERGENCY_STOP)
            self.cf.send_packet(pk)
            legacy = CRTPPacket()
            legacy.set_header(CRTPPort.LOCALIZATION, Localization.GENERIC_CH)
            legacy.data = struct.pack("<B", Localization.EMERGENCY_STOP)
            self.cf.send_packet(legacy)
        print(f"cf_guard {self.uri}: emergency stop ({reason})", file=sys.stderr, flush=True)

    def _watch_link(self) -> None:
        """The link thread: a poll every 50 ms (:func:`poll_packet`), the keep-alive while the
        motors are off, and the emergency stop when the link reports an error or stops answering."""
        last_rx = next_poll = time.monotonic()
        while not self.lost.is_set():
            if time.monotonic() >= next_poll:
                self.cf.send_packet(poll_packet(self.uri))
                next_poll = time.monotonic() + POLL_S
            # (an answer ends the wait at once: the next poll waits for the rest of the period)
            pk = self.driver.receive_packet(max(0.0, next_poll - time.monotonic()))
            now = time.monotonic()
            while pk is not None:
                last_rx = now
                self.answered.set()
                pk = self.driver.receive_packet(0)
            if self.motors_off and now - self.keepalive_t >= KEEPALIVE_S:
                self.commander.send_setpoint(0.0, 0.0, 0.0, 0)  # unlocks the thrust; keeps the watchdog fed
                self.keepalive_t = now
            reason = None
            if self.errors:
                reason = f"link error: {self.errors[0]}"
            elif self.expect_replies and now - last_rx > self.link_timeout_s:
                reason = f"no reply for {now - last_rx:.2f} s"
            if reason and not self.lost.is_set():
                self.lost.set()
                self._estop(f"link lost: {reason}")
                self.reply(["lost", reason])

    def _fly(self, frames: Any) -> bool:
        """Pass the agent's frames to the drone; True on a clean ``bye``."""
        for frame in frames:
            kind = frame[0] if isinstance(frame, list) and frame else None
            if kind == "sp":
                self.motors_off = int(frame[4]) == 0
                if not self.motors_off:
                    self.thrust_t = time.monotonic()
                self.commander.send_setpoint(float(frame[1]), float(frame[2]), float(frame[3]), int(frame[4]))
            elif kind == "pose":
                self.loc.send_extpose([float(v) for v in frame[1:4]], [float(v) for v in frame[4:8]])
            elif kind == "stop":
                self.commander.send_stop_setpoint()
                self.motors_off = True
            elif kind == "estop":
                self._estop(str(frame[1]) if len(frame) > 1 else "asked")
            elif kind == "bye":
                self.commander.send_stop_setpoint()
                self.motors_off = True
                while time.monotonic() - self.thrust_t < LANDED_AFTER_S and not self.lost.is_set():
                    time.sleep(KEEPALIVE_S)  # (the link thread sends the zero setpoints)
                self.commander.send_notify_setpoint_stop()
                return True
            else:
                print(f"cf_guard {self.uri}: unknown frame {frame!r} dropped", file=sys.stderr)
        return False

    def _close(self, clean: bool) -> None:
        """End the link: after an unclean end an emergency stop, or silence for the firmware's watchdog."""
        if not clean and self.silent_on_loss:
            self.motors_off = False  # no keep-alive either: the firmware's watchdog takes over
            print(
                f"cf_guard {self.uri}: the agent is gone; silent, the firmware's watchdog decides",
                file=sys.stderr,
                flush=True,
            )
        elif not clean:
            self._estop("the agent is gone (its connection closed)")
        self.lost.set()
        time.sleep(0.05)  # let the last packets leave the socket or radio
        self.driver.close()

    def _frames(self, unpacker: msgpack.Unpacker) -> Any:
        while True:
            try:
                chunk = self.conn.recv(4096)
            except OSError:
                return
            if not chunk:
                return
            unpacker.feed(chunk)
            yield from unpacker


def serve(path: Path, exit_when_idle: bool) -> int:
    import cflib.crtp

    cflib.crtp.init_drivers()
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    bound = False
    try:
        if path.exists():
            probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                probe.connect(str(path))
                probe.close()
                print(f"cf_guard: a server already answers at {path}", file=sys.stderr)
                return 0
            except OSError:
                path.unlink()  # left by a server that died
        srv.bind(str(path))
        bound = True
    except OSError as exc:  # another one won the race
        print(f"cf_guard: cannot serve at {path}: {exc}", file=sys.stderr)
        srv.close()
        return 0
    srv.listen(64)
    srv.settimeout(0.2)
    active: list[threading.Thread] = []
    idle_since = time.monotonic()
    print(f"cf_guard: serving at {path}", file=sys.stderr, flush=True)
    try:
        while True:
            try:
                conn, _ = srv.accept()
            except TimeoutError:
                active = [t for t in active if t.is_alive()]
                if active:
                    idle_since = time.monotonic()
                elif exit_when_idle and time.monotonic() - idle_since > 2.0:
                    return 0
                continue
            t = threading.Thread(target=_Drone(conn).serve, daemon=True)
            t.start()
            active.append(t)
    finally:
        srv.close()
        if bound:
            try:
                path.unlink()
            except OSError:
                pass


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--serve", type=Path, default=default_socket(), help="Unix socket path")
    ap.add_argument("--exit-when-idle", action="store_true")
    args = ap.parse_args()
    sys.exit(serve(args.serve, args.exit_when_idle))
