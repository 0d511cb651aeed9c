"""Software-in-the-loop Crazyflies that run the Crazyflie firmware itself.

    python -m swarm.world.sitl_fw --cf2 PATH --mocap-port 19900 \\
        --drone real1,19850,1.0,0.3,0.0,20 [--drone ...] [--telemetry DIR] [--until-handed-back]

``cf2`` is CrazySim's build of the Crazyflie firmware for Linux (``bash
../shared/crazyflie-sitl/build.sh OUT_DIR``, or CrazySim's own ``sitl_make``): the
firmware's commander, supervisor, Kalman estimator, PID controller and power
distribution, on the FreeRTOS POSIX port. Without ``--cf2`` the path comes from the
environment variable ``C3SWARM_CF2``. Each ``--drone NAME,PORT,X,Y,Z,YAW_DEG`` starts one
firmware process and plays everything around it, as CrazySim's Gazebo plugin does:

* **Its link.** ``cf2 FW_PORT 127.0.0.1`` is a UDP client of this process: it sends
  ``0xF3`` and waits for ``0xF3`` back, then every datagram is one CRTP packet, and it
  answers whoever sent it the last one (``src/hal/src/socketlink.c``). So this process is
  its only peer: it binds 127.0.0.1:PORT for cflib's UDP driver (``udp://127.0.0.1:PORT``)
  and relays cflib's packets to the firmware and the firmware's answers back. The
  firmware's link queue holds 5 packets (``socketlink.c``): at most :data:`FORWARD_PER_TICK`
  client packets go in per millisecond, behind the sensor packet. On a busy machine the
  firmware still leaves a request unanswered now and then (one in several hundred on a 2-core
  machine running other tests' swarms, with no drop on either socket: lost inside the
  firmware, where exactly was not found), and cflib asks nothing again
  over UDP (``udpdriver.py``: ``needs_resending`` False): 1 to 7 full connections in 25
  stalled for good so, none in 50 once the relay asked again. The relay therefore asks
  again as cflib does over a radio (``Crazyflie.send_packet``: after
  :data:`RESEND_AFTER_S` without an answer): a client packet on a port and channel the
  firmware answers (:data:`ANSWERED`) is sent again, up to :data:`RESENDS` times, until the
  firmware sends something on that port and channel. The firmware and cflib take a repeated
  request as they do over a radio (cflib ignores an answer it no longer waits for; a log
  block created twice is "already exists", which ``log.py`` takes as created). A lone null
  packet (``0xFF``, cflib's UDP scan probe) from an address that has sent nothing else is
  answered here once the drone is ready. A link echo (CRTP port 15 channel 0, the link guard's
  poll) is answered here too, at once, while the firmware process runs, as a Crazyflie's radio
  chip acknowledges every packet in its interrupt handler whatever the main MCU is busy with
  (crazyflie2-nrf-firmware ``src/esb.c``, ``esbInterruptHandler``); the firmware's own echo
  comes from its lowest-priority task (``crtpservice.c``), which a busy machine can leave
  unscheduled past the guard's timeout. Everything else goes to the firmware, which answers what it
  is asked (a log request, a parameter) and nothing more.
* **Its body.** The firmware sends four motor PWM values on CRTP port 9 every stabilizer
  tick; they fly a Crazyflie body (``swarm.world.fw_body``: the firmware's quadratic motor
  map, yaw torque and motor layout, the simulated rotors' lag, the project's rigid body,
  the floor).
* **Its sensors.** Every millisecond of wall-clock time (the firmware's stabilizer runs
  once per sensor packet and assumes 1 kHz, ``src/modules/src/stabilizer.c``) one
  accelerometer-and-gyro packet goes in on port 9 (``src/hal/src/sensors_sitl.c``). A
  late tick steps the body as often as it missed but sends one packet: a burst would
  overflow the link queue (the counters say how many were missed). No barometer: the
  Kalman estimator of this build does not use it. Its position comes, as in a
  motion-capture lab, from the external pose the client relays (``extpos``).
* **Its motion capture.** The bodies' poses go out at 100 Hz as the ``sitl`` capture source
  (``swarm.world.mocap.SitlMocap``), as from the stand-in (``swarm.world.sitl_cf``).
* **What the firmware says.** Once its gyro bias is found (it says so on port 9) this
  process reads the firmware's log table of contents and logs, at 100 Hz under block id
  :data:`MONITOR_BLOCK` (cflib never uses it), the supervisor's ``supervisor.info`` bits,
  the setpoint it flies (``ctrltarget.roll``, ``.pitch``, ``.yaw``, ``stabilizer.thrust``)
  and its position estimate (``stateEstimateZ``); a client that resets the firmware's
  logging gets its block back. Those samples, the body, every setpoint relayed and the
  notable packets go to ``DIR/NAME.jsonl`` (``swarm.world.fw_trace.read_trace`` reads it).

The drone counts as ready, and answers probes, once the firmware has its gyro bias and
the monitor is logging. With ``--until-handed-back`` the process ends when every drone has
been handed back by its client (``send_notify_setpoint_stop``, CRTP port 7 channel 1, as
crtp_commander.c reads it) and landed as its supervisor sees it, or rests on the floor, motors
off, with its client silent for 3 s after talking (:meth:`FirmwareDrone.done`); SIGTERM ends it too.
"""

from __future__ import annotations

import argparse
import math
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import msgpack
import numpy as np
import orjson

from swarm.world.fw_body import FirmwareBody
from swarm.world.fw_crtp import (
    ANSWERED,
    CONTROL_RESET,
    LOG_CONTROL_CH,
    LOG_DATA_CH,
    PORT_LINK,
    PORT_LOG,
    PORT_SIM,
    RESEND_AFTER_S,
    RESENDS,
    FwState,
    fw_state,
    header,
)
from swarm.world.fw_monitor import LogMonitor
from swarm.world.fw_process import CF2_ENV, cpu_s, die_with_parent, find_cf2

PHYSICS_HZ = 1000.0  # the firmware's stabilizer rate (stabilizer.c: one loop per sensor packet)
MOCAP_HZ = 100.0
FORWARD_PER_TICK = 1  # client and monitor packets into the firmware per millisecond, beside the sensor packet:
# its link queue holds 5, and the task that fills it and the one that empties it share a priority (config.h), so
# they take turns at the 1 ms tick
OUTBOX_MAX = 400  # queued client packets beyond this are dropped (counted)
HANDED_BACK_SILENT_S = 3.0
HANDED_BACK_SETTLE_S = 4.0  # at most this long after a hand-back for the supervisor to stop counting it flying
BOOT_TIMEOUT_S = 5.0  # a firmware without its gyro bias this long after its hello is restarted (about 1 s normally)


@dataclass
class Counters:
    restarts: int = 0  # firmware processes restarted after stalling at boot
    sensor_packets: int = 0
    late_ticks: int = 0  # ticks that stepped the body more than once (the loop was late) ...
    missed_packets: int = 0  # ... and the sensor packets not sent for it
    client_in: int = 0  # packets from the client
    forwarded: int = 0  # client packets into the firmware
    resent: int = 0  # requests sent again for want of an answer (RESEND_AFTER_S) ...
    unanswered: int = 0  # ... and given up after RESENDS
    outbox_dropped: int = 0
    to_client: int = 0  # firmware packets relayed to the client
    probes_answered: int = 0
    echoes_answered: int = 0  # link echoes answered here, as the radio acknowledges (FirmwareDrone.firmware_runs)


@dataclass
class FirmwareDrone:
    """One firmware process, its two sockets and its body."""

    name: str
    port: int
    x_w: list[float]
    yaw_deg: float
    cf2: Path
    trace: IO[bytes] | None = None
    body: FirmwareBody = field(init=False)
    fw_sock: socket.socket = field(init=False)
    cl_sock: socket.socket = field(init=False)
    proc: subprocess.Popen[bytes] | None = None
    log: IO[bytes] | int = subprocess.DEVNULL  # the firmware's console
    hello_s: float = math.inf  # monotonic time of the firmware's hello
    fw_addr: tuple[str, int] | None = None
    client: tuple[str, int] | None = None
    calibrated: bool = False  # the firmware found its gyro bias
    ready: bool = False  # calibrated and the monitor logging (then it stays ready)
    monitor: LogMonitor = field(default_factory=LogMonitor)
    outbox: deque[tuple[bytes, bool]] = field(default_factory=deque)  # (packet, a new request of the client's)
    asked: dict[int, tuple[bytes, float, int]] = field(default_factory=dict)  # header: (request, sent s, resends left)
    counters: Counters = field(default_factory=Counters)
    talked_s: float = -math.inf  # monotonic time of the client's newest packet
    setpoint_s: float = -math.inf  # ... and of its newest setpoint (RPYT or the stop)
    handed_back: bool = False
    handed_back_s: float = math.inf  # monotonic time of the hand-back
    last_sample: dict[str, float] = field(default_factory=dict)
    state: FwState = FwState.NOT_READY
    events: list[tuple[float, str]] = field(default_factory=list)  # (monotonic s, FwState) transitions
    cpu_s: float = 0.0  # the firmware process's CPU time [s], read once a second and at the end

    def __post_init__(self) -> None:
        self.body = FirmwareBody(np.asarray(self.x_w, float), math.radians(self.yaw_deg))
        self.fw_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.fw_sock.bind(("127.0.0.1", 0))
        self.fw_sock.setblocking(False)
        self.cl_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.cl_sock.bind(("127.0.0.1", self.port))
        self.cl_sock.setblocking(False)

    def done(self, now: float) -> bool:
        """Its client is done with it: it handed the drone back and the supervisor no longer
        counts it flying (or :data:`HANDED_BACK_SETTLE_S` after the hand-back), or it fell silent
        for :data:`HANDED_BACK_SILENT_S` after talking while the drone rests on the floor with
        its motors off. The supervisor counts a drone flying for 2 s after its last thrust on the
        firmware's clock (supervisor.c ``IS_FLYING_HYSTERESIS_THRESHOLD``), which a busy machine
        slows against the wall clock the client waits on: the trace then still ends with the
        drone landed. A client that stalls mid-flight does not count: the relay carries the other
        drones' links, and ending it would refuse them (cflib's UDP socket is connected: its
        next receive fails with ``ConnectionRefusedError``)."""
        if self.handed_back:
            return self.state is not FwState.FLYING or now - self.handed_back_s > HANDED_BACK_SETTLE_S
        silent = self.talked_s > -math.inf and now - self.talked_s > HANDED_BACK_SILENT_S
        return silent and self.body.resting

    def start(self, log: IO[bytes] | int) -> None:
        """Start the firmware, a UDP client of :attr:`fw_sock` (it dies with this process)."""
        self.log = log
        argv = [str(self.cf2), str(self.fw_sock.getsockname()[1]), "127.0.0.1"]
        stdbuf = shutil.which("stdbuf")  # its console (printf) line by line into the log
        self.proc = subprocess.Popen(
            ([stdbuf, "-oL"] if stdbuf else []) + argv,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            preexec_fn=die_with_parent,
        )

    def firmware_runs(self) -> bool:
        """Its firmware process is up (it said hello) and has not ended: what a Crazyflie's radio
        needs to acknowledge a packet (its power on), whatever its firmware is busy with."""
        return self.fw_addr is not None and self.proc is not None and self.proc.poll() is None

    def check_boot(self, now: float) -> None:
        """Restart a firmware that has not found its gyro bias :data:`BOOT_TIMEOUT_S` after its
        hello: a few boots in a hundred of this build on two busy cores stall there, spinning
        (the FreeRTOS POSIX port), and never would."""
        if self.calibrated or now - self.hello_s < BOOT_TIMEOUT_S or self.proc is None:
            return
        print(f"sitl_fw: the firmware of {self.name} stalled at boot (no gyro bias in {BOOT_TIMEOUT_S:.0f} s): "
              "restarting it", flush=True)  # fmt: skip
        self.proc.kill()
        self.proc.wait()
        self.fw_addr, self.hello_s, self.monitor = None, math.inf, LogMonitor()
        self.body.pwm[:] = 0.0
        self.counters.restarts += 1
        self.write({"k": "pkt", "t": now, "what": "firmware_restarted"})
        self.start(self.log)

    def write(self, record: dict[str, Any]) -> None:
        if self.trace is not None:
            self.trace.write(orjson.dumps(record, option=orjson.OPT_SERIALIZE_NUMPY) + b"\n")

    def _fw_send(self, pk: bytes) -> None:
        if self.fw_addr is not None:
            try:
                self.fw_sock.sendto(pk, self.fw_addr)
            except OSError:
                pass

    def poll(self, now: float) -> None:
        """Everything waiting on both sockets (until one would block, or fails)."""
        for sock, take in ((self.fw_sock, self._from_firmware), (self.cl_sock, self._from_client)):
            while True:
                try:
                    pk, addr = sock.recvfrom(64)
                except OSError:  # (BlockingIOError: nothing more waiting)
                    break
                take(pk, addr, now)

    def _from_firmware(self, pk: bytes, addr: tuple[str, int], now: float) -> None:
        if self.fw_addr is None:
            if pk == b"\xf3":  # the firmware's hello (socketlink.c): answered, then it talks CRTP
                self.fw_addr, self.hello_s = addr, now
                self.fw_sock.sendto(b"\xf3", addr)
            return
        if not pk or addr != self.fw_addr:  # (a restarted firmware's predecessor)
            return
        port, ch, data = pk[0] >> 4, pk[0] & 0x03, pk[1:]
        if port == PORT_SIM:  # the simulator's port: motor PWM, or "gyro bias found" (one byte)
            if len(data) == 8:
                self.body.pwm[:] = struct.unpack("<4H", data)
            elif len(data) == 1 and data[0]:
                self.calibrated = True
            return
        if port == PORT_LOG and self.monitor.answer(ch, data):
            if ch == LOG_DATA_CH:
                self._sample(now, self.monitor.decode(data))
            return
        self.asked.pop(pk[0] | 0x0C, None)  # (its answer: the link bits set, as a client sends them)
        if self.client is not None:
            try:
                self.cl_sock.sendto(pk, self.client)
                self.counters.to_client += 1
            except OSError:
                pass

    def _from_client(self, pk: bytes, addr: tuple[str, int], now: float) -> None:
        if pk == b"\xff" and addr != self.client:  # a scan probe (cflib udpdriver.py scan_interface)
            if self.ready:
                self.cl_sock.sendto(b"\xff", addr)
                self.counters.probes_answered += 1
            return
        self.client = addr
        self.talked_s = now
        self.counters.client_in += 1
        if pk[:1] == bytes([header(PORT_LINK, 0)]) and self.firmware_runs():  # a link echo: the radio's answer
            self.cl_sock.sendto(pk, addr)
            self.counters.echoes_answered += 1
            return
        self._inspect(pk, now)
        if len(self.outbox) >= OUTBOX_MAX:
            self.counters.outbox_dropped += 1
            return
        self.outbox.append((pk, (pk[0] >> 4, pk[0] & 0x03) in ANSWERED))

    def _inspect(self, pk: bytes, now: float) -> None:
        """Record the client's setpoints and stops; watch for the end of the flight."""
        port, ch, data = pk[0] >> 4, pk[0] & 0x03, pk[1:]
        if port == 3 and ch == 0 and len(data) == 14:  # crtp_commander_rpyt.c: roll, pitch, yaw rate, thrust
            r, p, y, thrust = struct.unpack("<fffH", data)
            self.setpoint_s = now
            self.write({"k": "sp", "t": now, "roll": r, "pitch": p, "yaw": y, "thrust": thrust})
        elif port == 7 and ch == 1 and data[:1] == b"\x00":  # crtp_commander.c metaNotifySetpointsStop
            if not self.handed_back:
                self.handed_back, self.handed_back_s = True, now
            self.write({"k": "pkt", "t": now, "what": "notify_stop"})
        elif port == 7 and ch == 0 and data[:1] == b"\x00":  # crtp_commander_generic.c stopType
            self.setpoint_s = now
            self.write({"k": "pkt", "t": now, "what": "stop"})
        elif port == 6 and ch == 1 and data[:1] == b"\x08" and len(data) == 29:  # ... EXT_POSE: x, y, z, quaternion
            self.write({"k": "pose", "t": now, "x": struct.unpack("<fff", data[1:13])})
        elif port == 6 and ch == 1 and data[:1] == b"\x03":  # crtp_localization_service.c EMERGENCY_STOP
            self.write({"k": "pkt", "t": now, "what": "estop"})
        elif port == PORT_SIM and ch == 1 and data[:1] == b"\x03":  # the newer supervisor port's form
            self.write({"k": "pkt", "t": now, "what": "estop_supervisor_port"})
        elif port == PORT_LOG and ch == LOG_CONTROL_CH and data[:1] == bytes([CONTROL_RESET]):
            self.monitor.restart_block()

    def _sample(self, now: float, values: dict[str, float]) -> None:
        self.last_sample = values
        state = fw_state(
            int(values.get("supervisor.info", 0)),
            values.get("ctrltarget.roll", math.nan),
            values.get("ctrltarget.pitch", math.nan),
            values.get("ctrltarget.yaw", math.nan),
            values.get("stabilizer.thrust", 0.0),
            now - self.setpoint_s,
        )
        if state is not self.state:
            self.state = state
            self.events.append((now, state.value))
        self.write({"k": "fw", "t": now, "state": state.value, **values})

    def tick(self, now: float, steps: int, dt_s: float) -> None:
        """``steps`` physics steps of ``dt_s``, then one sensor packet and the next queued packets."""
        for _ in range(steps):
            self.body.step(dt_s)
        if self.fw_addr is None:
            return
        imu = self.body.imu
        self._fw_send(struct.pack("<BBhhhhhh", header(PORT_SIM, 0), 0, imu[0], imu[1], imu[2], imu[3], imu[4], imu[5]))
        self.counters.sensor_packets += 1
        room = FORWARD_PER_TICK
        if not self.ready:  # the client's packets wait until the firmware is calibrated and logged
            req = self.monitor.request(now) if self.calibrated else None
            if req is not None:
                self._fw_send(req)
            self.ready = self.calibrated and self.monitor.running
            return
        if not self.monitor.running:  # after a client reset the firmware's logging: behind its packets
            req = self.monitor.request(now)
            if req is not None:
                self.outbox.append((req, False))
        for head, (pk, sent_s, left) in list(self.asked.items()):
            if now - sent_s < RESEND_AFTER_S:
                continue
            if left == 0:
                del self.asked[head]
                self.counters.unanswered += 1
                continue
            self.asked[head] = (pk, now, left - 1)
            self.outbox.appendleft((pk, False))  # (first: it goes now)
            self.counters.resent += 1
        while room > 0 and self.outbox:
            pk, request = self.outbox.popleft()
            self._fw_send(pk)
            self.counters.forwarded += 1
            room -= 1
            if request:
                self.asked[pk[0] | 0x0C] = (pk, now, RESENDS)

    def body_record(self, now: float) -> None:
        b = self.body
        self.write({"k": "body", "t": now, "x": b.x_w, "q": b.q, "v": b.s[3:6], "w": b.s[10:13], "pwm": b.pwm,
                    "thrust_N": b.thrust_N})  # fmt: skip

    def sample_cpu(self) -> None:
        """Read the firmware process's CPU time (while it lives: a run's end signals its whole group)."""
        if self.proc is not None and self.proc.poll() is None:
            cpu = cpu_s(self.proc.pid)
            self.cpu_s = cpu if math.isfinite(cpu) else self.cpu_s

    def finish(self) -> None:
        """Stop the firmware (reading its CPU time first) and close the sockets."""
        self.sample_cpu()
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(2.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.write({"k": "end", "state": self.state.value, "events": self.events, "cpu_s": self.cpu_s,
                    "missing": self.monitor.missing, **self.counters.__dict__})  # fmt: skip
        self.fw_sock.close()
        self.cl_sock.close()


def run(drones: list[FirmwareDrone], mocap_port: int, stop: threading.Event, until_handed_back: bool) -> None:
    """The 1 kHz loop: poll the sockets, step the bodies, send the sensor packets and the
    queued ones; the poses at :data:`MOCAP_HZ`. Ends on ``stop`` or, with
    ``until_handed_back``, once every drone's client is done with it."""
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    dt = 1.0 / PHYSICS_HZ
    every = round(PHYSICS_HZ / MOCAP_HZ)
    t0 = time.monotonic()
    k = 0  # ticks done
    while not stop.is_set():
        now = time.monotonic()
        steps = max(1, int((now - t0) / dt) - k)  # the ticks due by now: a late loop steps the bodies to now
        if steps > 1:
            for d in drones:
                d.counters.late_ticks += 1
                d.counters.missed_packets += steps - 1
        k += steps
        for d in drones:
            d.poll(now)
            d.tick(now, steps, dt)
        if k // every != (k - steps) // every:
            frame = [[d.name, *map(float, d.body.x_w), *map(float, d.body.q)] for d in drones]
            try:
                out.sendto(msgpack.packb(frame), ("127.0.0.1", mocap_port))
            except OSError:
                pass
            for d in drones:
                d.body_record(now)
                if k // PHYSICS_HZ != (k - steps) // PHYSICS_HZ:  # once a second
                    d.sample_cpu()
                d.check_boot(now)
                if d.proc is not None and d.proc.poll() is not None:
                    raise RuntimeError(f"the firmware of {d.name} exited with {d.proc.returncode}")
            if until_handed_back and all(d.done(now) for d in drones):
                break
        wait = t0 + (k + 1) * dt - time.monotonic()
        if wait > 0:
            time.sleep(wait)
    out.close()


def _handshake(drones: list[FirmwareDrone], timeout_s: float) -> None:
    """Wait for every firmware's hello; raise naming the one that never sent it."""
    deadline = time.monotonic() + timeout_s
    while any(d.fw_addr is None for d in drones):
        for d in drones:
            if d.proc is not None and d.proc.poll() is not None:
                raise RuntimeError(f"the firmware of {d.name} exited with {d.proc.returncode} before its hello")
            d.poll(time.monotonic())
        if time.monotonic() > deadline:
            late = [d.name for d in drones if d.fw_addr is None]
            raise RuntimeError(f"no hello from the firmware of {late} within {timeout_s:.0f} s")
        time.sleep(0.002)


def parse_drone(text: str) -> tuple[str, int, list[float], float]:
    name, port, x, y, z, yaw = text.split(",")
    return name, int(port), [float(x), float(y), float(z)], float(yaw)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--drone", action="append", required=True, help="NAME,PORT,X,Y,Z,YAW_DEG (repeatable)")
    ap.add_argument("--mocap-port", type=int, required=True)
    ap.add_argument("--cf2", default=None, help=f"the firmware binary (default: ${CF2_ENV})")
    ap.add_argument("--telemetry", type=Path, default=None, help="write DIR/NAME.jsonl and DIR/NAME.cf2.log")
    ap.add_argument("--until-handed-back", action="store_true", help="end once every client is done")
    ap.add_argument("--start-timeout-s", type=float, default=20.0)
    args = ap.parse_args(argv)
    try:
        cf2 = find_cf2(args.cf2)
    except FileNotFoundError as exc:
        print(f"sitl_fw: {exc}", flush=True)
        return 2
    if args.telemetry is not None:
        args.telemetry.mkdir(parents=True, exist_ok=True)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())  # swarm run ends it with SIGTERM: a clean end
    fleet: list[FirmwareDrone] = []
    code = 0
    wall0, cpu0 = time.monotonic(), time.process_time()
    FirmwareBody(np.zeros(3), 0.0).step(0.001)  # load the compiled step now, not in the 1 kHz loop (about 1 s)
    try:
        for n, p, x, yaw in map(parse_drone, args.drone):
            trace = open(args.telemetry / f"{n}.jsonl", "wb") if args.telemetry else None
            d = FirmwareDrone(n, p, x, yaw, cf2, trace)
            fleet.append(d)
            log = open(args.telemetry / f"{n}.cf2.log", "wb") if args.telemetry else subprocess.DEVNULL
            d.start(log)
        _handshake(fleet, args.start_timeout_s)
        print(
            "sitl_fw: " + ", ".join(f"{d.name} at udp://127.0.0.1:{d.port}" for d in fleet)
            + f"; firmware {cf2}; poses to :{args.mocap_port}",
            flush=True,
        )  # fmt: skip
        run(fleet, args.mocap_port, done, args.until_handed_back)
    except (RuntimeError, OSError) as exc:
        print(f"sitl_fw: {exc}", flush=True)
        code = 1
    except KeyboardInterrupt:
        pass
    finally:
        for d in fleet:
            d.finish()
            if d.trace is not None:
                d.trace.close()
            print(
                f"sitl_fw: {d.name} ended {d.state.value}; supervisor events {d.events}; "
                f"firmware cpu {d.cpu_s:.1f} s; {d.counters}",
                flush=True,
            )
        summary = {"wall_s": time.monotonic() - wall0, "relay_cpu_s": time.process_time() - cpu0,
                   "firmware_cpu_s": {d.name: d.cpu_s for d in fleet}}  # fmt: skip
        print("SITL_FW_SUMMARY " + orjson.dumps(summary).decode(), flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
