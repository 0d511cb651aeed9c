"""Software-in-the-loop Crazyflies: CRTP over cflib's UDP driver, the firmware's rules, a body.

    python -m swarm.world.sitl_cf --mocap-port 19900 --drone real1,19850,1.0,0.3,0.0,20 [--drone ...]

Each ``--drone NAME,PORT,X,Y,Z,YAW_DEG`` binds 127.0.0.1:PORT, where cflib's UDP driver
(``udp://127.0.0.1:PORT``) finds it, and starts at rest at (X, Y, Z) [m, world] with yaw
YAW_DEG [deg, counter-clockwise]. Every CRTP packet (one per datagram: a header byte
``port << 4 | 3 << 2 | channel``, then up to 30 data bytes) is decoded, and answered only
where the firmware answers (a firmware over UDP acknowledges nothing: CrazySim's, which
``swarm.world.sitl_fw`` runs, is the reference):

* a lone null packet (``0xFF``) from an address that has sent nothing else: a scan probe
  (cflib's udpdriver.py ``scan_interface``, ``swarm run``'s readiness check), answered;
* port 15 channel 0: a link echo, sent back; channel 1: the link source, "Bitcraze
  Crazyflie" (crtpservice.c), which cflib's ``PlatformService`` asks before the version;
* port 13 channel 1 command 0: the CRTP protocol version, ``protocol`` (platformservice.c);
* port 3 channel 0, ``<fffH``: a legacy RPYT setpoint, given to :class:`swarm.crazyflie_fw.Firmware`
  as it arrives (thrust lock, inverted yaw rate, the release's thrust map, the cap);
* port 7 (generic commander) channel 0 type 0: the stop setpoint; channel 1 type 0:
  notify-stop (crtp_commander.c ``META_COMMAND_CHANNEL``, ``metaNotifySetpointsStop``);
* port 6 channel 1 type 8, ``<Bfffffff``: an external pose (recorded; the body is ground truth);
* port 5 (logging): the TOC (v2) of :data:`LOG_TOC` and its blocks: the decoded setpoint
  (``ctrltarget.roll``, ``.pitch``, ``.yaw``, as stabilizer.c logs them, and the thrust
  command, ``stabilizer.thrust``) and the supervisor's bits (``supervisor.info``);
* port 9, from protocol 12 (crtp_supervisor.c): channel 1 command 3 (emergency stop) or
  2 (recover, answered); channel 0 command 0x0C: the state bitfield, answered. Before
  protocol 12 the port is not the supervisor's and nothing there is answered; a crash
  recovery comes on port 13 channel 0 command 2 (platformservice.c), answered;
* port 6 channel 1 type 3: the older emergency stop.

The firmware's supervisor (watchdog 500 ms / 2 s, locked, crashed) decides what the
motors do; an attitude controller of the stand-in's own (the geometric SO(3) law of
``swarm.control``, tracking the firmware's roll, pitch and integrated yaw setpoint)
turns that into rotor thrusts, and RK4 integrates the Crazyflie 2.1 body at 500 Hz in
wall-clock time, with the ground at z = 0. The bodies' poses go out as the ``sitl``
motion-capture source (``swarm.world.mocap.SitlMocap``, what the world's relay reads for
``mocap.type: sitl``) to 127.0.0.1:``--mocap-port`` at 100 Hz: one datagram per frame,
msgpack ``[[name, x, y, z, qx, qy, qz, qw], ...]``.
"""

from __future__ import annotations

import argparse
import math
import signal
import socket
import struct
import sys
import threading
import time
from dataclasses import dataclass, field

import msgpack
import numpy as np

from swarm.control import AttitudeController
from swarm.crazyflie_fw import Firmware
from swarm.model import QuadModel, QuadState, step_rk4
from swarm.rotation import euler_to_quat, quat_to_R

PHYSICS_HZ = 500.0
MOCAP_HZ = 100.0
LOG_TOC = [
    ("ctrltarget", "roll", 7),  # (group, name, log.h type: 7 float, 2 uint16)
    ("ctrltarget", "pitch", 7),
    ("ctrltarget", "yaw", 7),
    ("stabilizer", "thrust", 7),
    ("supervisor", "info", 2),
]
"""The log variables the stand-in serves: the decoded setpoint and the supervisor's bits."""
LOG_TOC_CRC = 0x5C3F0002
LOG_FORMATS = {7: "f", 2: "H"}


@dataclass
class Setpoint:
    """A legacy setpoint as it arrived, for tests: roll [deg], pitch [deg] as the caller of
    cflib's ``send_setpoint`` meant it (cflib negates it on the wire), yaw rate [deg/s] as
    on the wire, thrust command."""

    t: float
    roll_deg: float
    pitch_deg: float
    yawrate_dps: float
    thrust: int


@dataclass
class SitlDrone:
    """One stand-in Crazyflie: its socket, its firmware and its body. Without :func:`run`
    stepping it, it still decodes, answers and records every packet (the tests' stand-in)."""

    name: str
    sock: socket.socket
    firmware: Firmware
    state: QuadState
    model: QuadModel
    att: AttitudeController
    yaw_sp_rad: float
    packets: int = 0
    setpoints: list[Setpoint] = field(default_factory=list)
    poses: list[tuple[float, ...]] = field(default_factory=list)
    stops: list[float] = field(default_factory=list)  # monotonic times of stop setpoints
    estops: list[float] = field(default_factory=list)  # and of emergency stops
    notify_stops: int = 0
    last_packet_s: float = 0.0  # monotonic time of the newest packet
    _deaf: threading.Event = field(default_factory=threading.Event)
    lock: threading.Lock = field(default_factory=threading.Lock)
    _done: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _addr: tuple = ("127.0.0.1", 0)  # the client's address (cflib's UDP socket)
    protocol: int = 12  # the CRTP protocol version it reports (12: a 2025.09 or later firmware)
    log_blocks: dict[int, list[int]] = field(default_factory=dict)  # block id -> TOC ids
    log_running: dict[int, tuple[float, float, tuple]] = field(default_factory=dict)  # id -> (period s, next t, addr)

    @classmethod
    def start(
        cls,
        name: str = "cf",
        port: int = 0,
        x_w: list[float] | None = None,
        yaw_deg: float = 0.0,
        firmware: str = "2026.04",
        protocol: int = 12,
    ) -> SitlDrone:
        """Bind 127.0.0.1:``port`` (0: a free one, see :attr:`uri`) and serve it as a firmware
        of CRTP protocol ``protocol``."""
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", port))
        s.settimeout(0.05)
        model = QuadModel()
        yaw = math.radians(yaw_deg)
        x0 = np.zeros(3) if x_w is None else np.asarray(x_w, float)
        state = QuadState(x0, np.zeros(3), euler_to_quat(0.0, 0.0, yaw), np.zeros(3))
        d = cls(name, s, Firmware(firmware), state, model, AttitudeController(model), yaw, protocol=protocol)
        d._thread = threading.Thread(target=d._serve, name=f"sitl-{name}", daemon=True)
        d._thread.start()
        return d

    def deaf(self) -> None:
        """Stop answering: to cflib the link is lost (the packets still arrive)."""
        self._deaf.set()

    def wait_for(self, what: str, n: int = 1, timeout_s: float = 20.0) -> bool:
        """Wait until ``len(self.<what>) >= n`` (polling its own list, not the network)."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self.lock:
                if len(getattr(self, what)) >= n:
                    return True
            time.sleep(0.01)
        return False

    def close(self) -> None:
        """End the serving thread, which releases the port."""
        self._done.set()
        if self._thread is not None:
            self._thread.join(1.0)

    @property
    def uri(self) -> str:
        return f"udp://127.0.0.1:{self.sock.getsockname()[1]}"

    def _serve(self) -> None:
        while not self._done.is_set():
            try:
                data, addr = self.sock.recvfrom(64)
            except TimeoutError:
                continue
            except OSError:
                break
            if not data:
                continue
            deaf = self._deaf.is_set()  # (a deaf drone still hears: it decodes and records, and answers nothing)
            if data == b"\xff" and addr != self._addr:  # a scan probe: answered (cflib udpdriver.py)
                if not deaf:
                    self.sock.sendto(b"\xff", addr)
                continue
            self._addr = addr
            answer = self.decode(data, time.monotonic())
            if answer is not None and not deaf:
                self.sock.sendto(answer, addr)
        self.sock.close()

    def decode(self, data: bytes, now: float) -> bytes | None:
        """Act on one packet; returns the firmware's answer packet, if it sends one."""
        h, body = data[0], data[1:]
        port, ch = (h >> 4) & 0x0F, h & 0x03
        fw = self.firmware
        with self.lock:
            self.packets += 1
            self.last_packet_s = now
            if port == 15 and ch == 0:  # link echo (crtpservice.c linkEcho)
                return data
            if port == 15 and ch == 1:  # link source (crtpservice.c linkSource)
                return bytes([data[0]]) + b"Bitcraze Crazyflie".ljust(30, b"\0")
            if port == 13 and ch == 1 and body[:1] == b"\x00":  # platformservice.c getProtocolVersion
                return bytes([data[0], 0, self.protocol])
            if port == 13 and ch == 0 and body[:1] == b"\x02":  # platformservice.c recoverSystem
                ok = fw.recover(now, self.tilt_rad() > math.radians(60))
                return bytes([data[0], 2, ok, fw.state.value != "crashed"])
            if port == 9 and self.protocol < 12:  # no supervisor port before protocol 12
                return None
            if port == 3 and ch == 0 and len(body) == 14:
                r, p, y, thr = struct.unpack("<fffH", body)
                self.setpoints.append(Setpoint(now, r, -p, y, thr))
                fw.rpyt(now, r, p, y, thr)
            elif port == 7 and ch == 0 and body[:1] == b"\x00":
                self.stops.append(now)
                fw.stop(now)
            elif port == 7 and ch == 1 and body[:1] == b"\x00":
                self.notify_stops += 1  # crtp_commander.c META_COMMAND_CHANNEL, metaNotifySetpointsStop
            elif port == 6 and ch == 1 and body[:1] == b"\x08" and len(body) == 29:
                self.poses.append(struct.unpack("<Bfffffff", body)[1:])
            elif (port == 9 and ch == 1 and body[:1] == b"\x03") or (port == 6 and ch == 1 and body[:1] == b"\x03"):
                self.estops.append(now)
                fw.emergency_stop(now)
            elif port == 9 and ch == 1 and body[:1] == b"\x02":  # crtp_supervisor.c: [cmd | 0x80, success, !crashed]
                ok = fw.recover(now, self.tilt_rad() > math.radians(60))
                return bytes([0x90 | 0x0C | 1, 0x82, ok, fw.state.value != "crashed"])
            elif port == 9 and ch == 0 and body[:1] == b"\x0c":  # CMD_GET_STATE_BITFIELD: [0x8C, uint16 LE]
                return bytes([0x90 | 0x0C | 0, 0x8C]) + struct.pack("<H", self.bitfield(now))
            elif port == 5:
                return self._log(ch, body, now)
        return None

    def _log(self, ch: int, body: bytes, now: float) -> bytes | None:
        """The logging port as log.c serves it: the TOC (v2) of :data:`LOG_TOC`, blocks
        created, started, stopped and reset; the data go out in :meth:`log_data`."""
        hdr = bytes([0x50 | 0x0C | ch])
        if ch == 0 and body[:1] == b"\x03":  # CMD_GET_INFO_V2: items (uint16), CRC (uint32), limits
            return hdr + struct.pack("<BHIBB", 3, len(LOG_TOC), LOG_TOC_CRC, 16, 16)
        if ch == 0 and body[:1] == b"\x02" and len(body) >= 3:  # CMD_GET_ITEM_V2: id, type, group\0name\0
            i = struct.unpack("<H", body[1:3])[0]
            if i < len(LOG_TOC):
                group, name, kind = LOG_TOC[i]
                return hdr + struct.pack("<BHB", 2, i, kind) + group.encode() + b"\0" + name.encode() + b"\0"
        if ch == 1 and body[:1] == b"\x05":  # reset: every block gone
            self.log_blocks.clear()
            self.log_running.clear()
            return hdr + bytes([5, 0, 0])
        if ch == 1 and body[:1] in (b"\x06", b"\x00") and len(body) >= 2:  # create (v2: 3 bytes per variable)
            block, spec = body[1], body[2:]
            self.log_blocks[block] = [struct.unpack("<H", spec[k + 1 : k + 3])[0] for k in range(0, len(spec) - 2, 3)]
            return hdr + bytes([body[0], block, 0])
        if ch == 1 and body[:1] == b"\x03" and len(body) >= 3:  # start, period in 10 ms
            self.log_running[body[1]] = (max(body[2], 1) * 0.01, now, self._addr)
            return hdr + bytes([3, body[1], 0])
        if ch == 1 and body[:1] in (b"\x04", b"\x02") and len(body) >= 2:  # stop, delete
            self.log_running.pop(body[1], None)
            return hdr + bytes([body[0], body[1], 0])
        return None

    def log_data(self, now: float) -> None:
        """Send each started block's values when its period is due (channel 2)."""
        for block, (period, due, addr) in list(self.log_running.items()):
            if now < due:
                continue
            self.log_running[block] = (period, due + period, addr)
            ms = int(now * 1000) & 0xFFFFFF
            ids = self.log_blocks.get(block, [])
            values = [self._log_value(i, now) for i in ids]
            fmt = "<" + "".join(LOG_FORMATS[LOG_TOC[i][2]] for i in ids)
            pk = bytes([0x50 | 0x0C | 2, block, ms & 0xFF, (ms >> 8) & 0xFF, ms >> 16]) + struct.pack(fmt, *values)
            try:
                self.sock.sendto(pk, addr)
            except OSError:
                pass

    def _log_value(self, i: int, now: float) -> float | int:
        group, name, _ = LOG_TOC[i]
        if group == "supervisor":
            return self.bitfield(now)
        return self.firmware.ctrltarget[name]

    def bitfield(self, now: float) -> int:
        """The supervisor's info bits (crtp_supervisor.c, cflib's Supervisor.STATES order)."""
        st = self.firmware.state.value
        tumbled = self.tilt_rad() > math.radians(60)
        bits = {
            0: st == "ready" and not tumbled,
            2: True,  # auto-armed, as the Crazyflie 2.x is
            3: st in ("ready", "flying", "level_out", "landed"),
            4: st in ("flying", "level_out"),
            5: tumbled,
            6: st == "locked",
            7: st == "crashed",
        }
        return sum(1 << b for b, on in bits.items() if on)

    def handed_back(self, now: float) -> bool:
        """Its client is done with it: handed back (notify-stop), or silent for 3 s after talking
        (probes do not count: a client may connect long after ``swarm run`` probed the drone)."""
        return self.notify_stops > 0 or (self.packets > 0 and now - self.last_packet_s > 3.0)

    def tilt_rad(self) -> float:
        return math.acos(max(-1.0, min(1.0, float(quat_to_R(self.state.q)[2, 2]))))

    def step(self, now: float, dt: float) -> None:
        """The firmware's decision and the body's motion over ``dt`` [s], under the lock
        from reading the state to writing it back: a change another thread makes to the
        state (a test knocking the drone over) is never overwritten by a step begun before."""
        with self.lock:
            self._step_locked(now, dt)

    def _step_locked(self, now: float, dt: float) -> None:
        out = self.firmware.step(now, self.tilt_rad())
        s = self.state
        if out.motors_on:
            self.yaw_sp_rad += out.yaw_rate_radps * dt
            cr, sr, cp, sp = (
                math.cos(out.roll_rad),
                math.sin(out.roll_rad),
                math.cos(out.pitch_rad),
                math.sin(out.pitch_rad),
            )
            cy, sy = math.cos(self.yaw_sp_rad), math.sin(self.yaw_sp_rad)
            R_des = np.array(
                [
                    [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                    [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                    [-sp, cp * sr, cp * cr],
                ]
            )
            f = self.att.rotor_thrusts(s, R_des, out.thrust_N)
        else:
            f = np.zeros(4)
        s = step_rk4(self.model, s, f, dt)
        if s.x_w[2] <= 0.0:  # the ground: it stops what pushes into it
            s.x_w[2] = 0.0
            if s.v_w[2] < 0.0:
                s.v_w = np.zeros(3)
                s.Omega_b = np.zeros(3)
        self.state = s


def run(drones: list[SitlDrone], mocap_port: int, stop: threading.Event) -> None:
    """Step every body at ``PHYSICS_HZ`` of wall-clock time and send the poses at ``MOCAP_HZ``,
    until ``stop`` or every drone has been handed back by its client (then the firmware has
    seen the end of the flight, and the process ends by itself)."""
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    dt = 1.0 / PHYSICS_HZ
    t0 = time.monotonic()
    k = 0
    every = round(PHYSICS_HZ / MOCAP_HZ)
    while not stop.is_set():
        k += 1
        now = t0 + k * dt
        for d in drones:
            d.step(now, dt)
            d.log_data(now)
        if k % every == 0:
            frame = [[d.name, *map(float, d.state.x_w), *map(float, d.state.q)] for d in drones]
            try:
                out.sendto(msgpack.packb(frame), ("127.0.0.1", mocap_port))
            except OSError:
                pass
        if k % every == 0 and all(d.handed_back(now) for d in drones):
            break
        lag = now - time.monotonic()
        if lag > 0:
            time.sleep(lag)
        elif lag < -0.5:  # far behind (a stalled machine): do not burst to catch up
            t0 += -lag
    for d in drones:
        d.close()


def parse_drone(text: str) -> tuple[str, int, list[float], float]:
    name, port, x, y, z, yaw = text.split(",")
    return name, int(port), [float(x), float(y), float(z)], float(yaw)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drone", action="append", required=True, help="NAME,PORT,X,Y,Z,YAW_DEG (repeatable)")
    ap.add_argument("--mocap-port", type=int, required=True)
    ap.add_argument("--firmware", default="2026.04", help="the release whose thrust map the drones have")
    args = ap.parse_args()
    fleet = [SitlDrone.start(n, p, x, yaw, args.firmware) for n, p, x, yaw in map(parse_drone, args.drone)]
    print("sitl: " + ", ".join(f"{d.name} at {d.uri}" for d in fleet) + f"; poses to :{args.mocap_port}", flush=True)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())  # swarm run ends it with SIGTERM: a clean end
    try:
        run(fleet, args.mocap_port, done)
    except KeyboardInterrupt:
        pass
    for d in fleet:
        print(f"sitl: {d.name} ended {d.firmware.state.value}; supervisor events {d.firmware.events}", flush=True)
    sys.exit(0)
