"""Flying a real Crazyflie from an agent: the link to its guard process, the flight
phases (take off, mission, hold, land) and the safety stops.

The agent computes the same filtered command as for a simulated drone: the thrust
vector, turned into roll, pitch [rad], yaw rate [rad/s] and thrust [N] by
``swarm.control.setpoint_from_thrust_vector``. This module turns that into the
Crazyflie's legacy RPYT setpoint:

* roll and pitch in degrees. Positive roll moves the drone to its right. Positive pitch
  moves it forward: the thrust tilts towards +x of the body. That is what cflib's
  ``send_setpoint`` expects; cflib itself negates pitch on the wire.
* yaw rate in degrees per second, negated: the firmware inverts the legacy yaw-rate input
  (``attitudeRate.yaw = -values->yaw``, crtp_commander_rpyt.c), so a counter-clockwise
  (z up) rate goes out negative (:func:`swarm.crazyflie_fw.wire_yaw_rate_dps`);
* thrust as a 16-bit command, through the config's calibration (:func:`thrust_command`),
  by default the firmware's own thrust map (linear for a release on a drone, quadratic for
  CrazySim's simulated motors).

Fly a new setup with the propellers off first, and check these signs against the
client's attitude display.

The radio belongs to the machine's link guard (:mod:`swarm.agents.cf_guard`), one process
that serves every real drone on the machine, since a Crazyradio can be shared only
within one process. When the agent dies, even by SIGKILL, its connection closes and
the guard sends the emergency stop. The agent stops the drone itself on:

* Ctrl-C;
* a filter fault;
* leaving the geofence;
* its motion-capture body going missing;
* the world's liveliness disappearing.
"""

from __future__ import annotations

import math
import socket
import subprocess
import sys
import threading
import time
from enum import StrEnum
from pathlib import Path

import msgpack
import numpy as np

from swarm.agents.cf_guard import default_socket
from swarm.config import AgentConfig, CrazyflieSettings, ThrustCalibration
from swarm.control import PathTracker
from swarm.crazyflie_fw import wire_yaw_rate_dps
from swarm.rotation import FloatArray


def thrust_command(thrust_N: float, cal: ThrustCalibration) -> int:
    """Collective thrust [N] to the 16-bit thrust command, clipped to ``[0, max_pwm]``."""
    if not math.isfinite(thrust_N):
        return 0
    return int(round(min(max(cal.map.command(thrust_N), 0.0), cal.max_pwm)))


def rpyt(roll_rad: float, pitch_rad: float, yaw_rate_radps: float, thrust_N: float, cal: ThrustCalibration) -> tuple:
    """Our attitude setpoint (yaw rate counter-clockwise) as the arguments of cflib's
    ``Commander.send_setpoint``."""
    return (
        math.degrees(roll_rad),
        math.degrees(pitch_rad),
        wire_yaw_rate_dps(math.degrees(yaw_rate_radps)),
        thrust_command(thrust_N, cal),
    )


class Phase(StrEnum):
    """Where a real drone is in its flight."""

    TAKEOFF = "takeoff"  # climbing to the start height at takeoff speed
    MISSION = "mission"  # flying the configured path (then holding its goal)
    LAND = "land"  # descending at land speed; below landed height the motors stop
    LANDED = "landed"  # motors off
    STOPPED = "stopped"  # emergency stop sent


class FlightPlan:
    """Which path tracker flies the drone now (pure: positions in, a tracker out)."""

    def __init__(self, me: AgentConfig) -> None:
        if me.crazyflie is None:
            raise ValueError(f"agent {me.id}: not a real Crazyflie")
        self.me, self.cf = me, me.crazyflie
        self.mission = PathTracker(me.path(), me.speed_mps)
        self.phase = Phase.MISSION
        self._takeoff: PathTracker | None = None
        self._land: PathTracker | None = None
        self._first = True

    def tracker(self, x_w: FloatArray) -> PathTracker | None:
        """The tracker for this tick (None once landed or stopped)."""
        start = np.asarray(self.me.start, dtype=float)
        if self._first:  # only the first measurement decides: on the ground below its start, take off
            self._first = False
            if x_w[2] < start[2] - 0.1:
                self.phase = Phase.TAKEOFF
                self._takeoff = PathTracker([x_w, [x_w[0], x_w[1], start[2]], start], self.cf.takeoff_speed_mps)
        if self.phase is Phase.TAKEOFF:
            assert self._takeoff is not None
            if np.linalg.norm(x_w - start) < 0.1:
                self.phase = Phase.MISSION
            else:
                return self._takeoff
        if self.phase is Phase.MISSION:
            return self.mission
        if self.phase is Phase.LAND:
            if x_w[2] < self.cf.landed_height_m:
                self.phase = Phase.LANDED
                return None
            if self._land is None:
                self._land = PathTracker([x_w, [x_w[0], x_w[1], 0.0]], self.cf.land_speed_mps)
            return self._land
        return None

    def land(self) -> None:
        if self.phase in (Phase.TAKEOFF, Phase.MISSION):
            self.phase = Phase.LAND

    def outside_geofence(self, x_w: FloatArray) -> bool:
        lo, hi = np.asarray(self.cf.geofence_min_m), np.asarray(self.cf.geofence_max_m)
        return bool(np.any(x_w < lo) or np.any(x_w > hi))


class CrazyflieLink:
    """The agent's connection to the machine's link guard (:mod:`swarm.agents.cf_guard`),
    started here in a session of its own if none is running."""

    def __init__(self, settings: CrazyflieSettings, name: str, socket_path: Path | None = None) -> None:
        self.settings, self.name = settings, name
        self.path = socket_path or default_socket()
        self.ready = threading.Event()
        self.lost = threading.Event()
        self.lost_reason = ""
        self.stopped = False
        self._lock = threading.Lock()
        self.sock = self._connect()
        threading.Thread(target=self._read, daemon=True).start()
        self._send(["hello", settings.uri, settings.link_timeout_s, settings.expect_replies, settings.on_agent_loss])

    def _connect(self, timeout_s: float = 15.0) -> socket.socket:
        started = False
        deadline = time.monotonic() + timeout_s
        while True:
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                s.connect(str(self.path))
                return s
            except OSError:
                s.close()
            if not started:  # no guard on this machine yet: start one that outlives us
                subprocess.Popen(
                    [sys.executable, "-m", "swarm.agents.cf_guard", "--serve", str(self.path), "--exit-when-idle"],
                    stdin=subprocess.DEVNULL,
                    start_new_session=True,
                )
                started = True
            if time.monotonic() > deadline:
                raise RuntimeError(f"agent {self.name}: no Crazyflie link guard at {self.path}")
            time.sleep(0.02)  # waiting for the guard's socket to appear

    def _read(self) -> None:
        unpacker = msgpack.Unpacker(raw=False)
        while True:
            try:
                chunk = self.sock.recv(4096)
            except OSError:
                chunk = b""
            if not chunk:
                break
            unpacker.feed(chunk)
            for frame in unpacker:
                if frame == ["ready"]:
                    self.ready.set()
                elif isinstance(frame, list) and frame[:1] == ["lost"]:
                    self.lost_reason = str(frame[1]) if len(frame) > 1 else "lost"
                    self.lost.set()
        if not self.stopped:
            self.lost_reason = self.lost_reason or "the link guard closed the connection"
            self.lost.set()

    def _send(self, frame: list) -> None:
        with self._lock:
            try:
                self.sock.sendall(msgpack.packb(frame))
            except OSError:
                self.lost.set()

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait until the guard says the drone answered (True), or it is lost or ``timeout_s``
        passes (False; :attr:`lost_reason` says why)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.ready.wait(0.05):
                return True
            if self.lost.is_set():
                return False
        self.lost_reason = self.lost_reason or f"the link guard did not answer within {timeout_s:.0f} s"
        return False

    def setpoint(self, roll_rad: float, pitch_rad: float, yaw_rate_radps: float, thrust_N: float) -> None:
        if not self.stopped:
            self._send(["sp", *rpyt(roll_rad, pitch_rad, yaw_rate_radps, thrust_N, self.settings.thrust)])

    def pose(self, x_w: FloatArray, q: FloatArray) -> None:
        if self.settings.send_external_pose and not self.stopped:
            self._send(["pose", *map(float, x_w), *map(float, q)])

    def motors_off(self) -> None:
        self._send(["stop"])

    def emergency_stop(self, reason: str) -> None:
        print(f"agent {self.name}: EMERGENCY STOP: {reason}", file=sys.stderr)
        self._send(["estop", reason])
        self.stopped = True

    def close(self) -> None:
        """A clean end: the guard sends the stop setpoint and closes the link."""
        self.stopped = True
        self._send(["bye"])
        try:
            self.sock.shutdown(socket.SHUT_WR)
        except OSError:
            pass
        self.sock.close()
