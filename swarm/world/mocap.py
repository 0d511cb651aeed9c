"""Motion-capture relay: rigid bodies from libmotioncapture to agent measurements.

:class:`PoseDifferentiator` (pure) turns timed poses into a full measurement: linear
velocity [m/s, world] by differencing positions, body rates [rad/s, body] from the
relative rotation of consecutive frames, both low-passed with one time constant. It also
counts dropped frames (a gap longer than 1.5 nominal periods). Frames are timed by the
relay's monotonic clock when they arrive, so thread-scheduling jitter shows up as noise
in the differences; the low-pass (``mocap.velocity_filter_s``) takes most of it out. :class:`MocapRelay` runs
the capture loop in a thread (``waitForNextFrame`` blocks until the system's next frame),
keeps one differentiator per tracked body, hands every frame to a callback (the world
publishes the measurements from it, at the capture rate), and reports a body lost when
it has not been seen for ``lost_after_s``.

Quaternions are scalar-last (x, y, z, w) as everywhere in swarm (``swarm.rotation``);
libmotioncapture's ``Quaternion`` has named fields and is converted here.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarm.rotation import FloatArray, quat_to_R


@dataclass
class BodyEstimate:
    """One tracked body at one frame."""

    t_s: float  # capture time [s] on the relay's clock
    x_w: FloatArray  # (3,) m, world
    q: FloatArray  # (4,) x, y, z, w
    v_w: FloatArray  # (3,) m/s, world
    Omega_b: FloatArray  # (3,) rad/s, body


def _log_SO3(R: FloatArray) -> FloatArray:
    """Rotation vector of ``R`` [rad] (angle times unit axis)."""
    c = max(-1.0, min(1.0, (float(np.trace(R)) - 1.0) / 2.0))
    angle = math.acos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-6:
        return 0.5 * w
    return angle / (2.0 * math.sin(angle)) * w


@dataclass
class PoseDifferentiator:
    """Velocity and body rates of one rigid body from its timed poses."""

    period_s: float  # nominal frame period [s]
    filter_s: float = 0.02  # low-pass time constant [s] (0: raw differences)
    dropped: int = 0  # frames missed (gaps longer than 1.5 periods, counted in periods)
    last: BodyEstimate | None = field(default=None)

    def update(self, t_s: float, x_w: FloatArray, q: FloatArray) -> BodyEstimate:
        x_w = np.asarray(x_w, dtype=float)
        q = np.asarray(q, dtype=float)
        q = q / np.linalg.norm(q)
        prev = self.last
        if prev is None:
            est = BodyEstimate(t_s, x_w, q, np.zeros(3), np.zeros(3))
        elif t_s <= prev.t_s:  # no time has passed: a repeated frame keeps the rates it had
            return BodyEstimate(prev.t_s, x_w, q, prev.v_w, prev.Omega_b)
        else:
            dt = t_s - prev.t_s
            if dt > 1.5 * self.period_s:
                self.dropped += round(dt / self.period_s) - 1
            v_raw = (x_w - prev.x_w) / dt
            R0, R1 = quat_to_R(prev.q), quat_to_R(q)
            w_raw = _log_SO3(R0.T @ R1) / dt  # body rates: R1 = R0 exp(Omega dt)
            a = dt / (self.filter_s + dt) if self.filter_s > 0 else 1.0
            est = BodyEstimate(
                t_s, x_w, q, prev.v_w + a * (v_raw - prev.v_w), prev.Omega_b + a * (w_raw - prev.Omega_b)
            )
        self.last = est
        return est


class SitlMocap:
    """The ``sitl`` motion-capture source: libmotioncapture's interface
    (``waitForNextFrame``, ``rigidBodies`` with ``position`` and ``rotation.x/y/z/w``) over
    the software-in-the-loop stand-in's pose datagrams (``swarm.world.sitl_cf``) on
    127.0.0.1:``port``: msgpack ``[[name, x, y, z, qx, qy, qz, qw], ...]`` per frame."""

    @dataclass
    class Rotation:
        x: float
        y: float
        z: float
        w: float

    @dataclass
    class Body:
        position: FloatArray
        rotation: SitlMocap.Rotation

    def __init__(self, port: int, timeout_s: float = 1.0) -> None:
        import socket

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(timeout_s)
        self.rigidBodies: dict[str, SitlMocap.Body] = {}

    def waitForNextFrame(self) -> None:  # libmotioncapture's name
        import msgpack

        data = self.sock.recv(65536)  # a TimeoutError is a broken stream to the relay
        self.rigidBodies = {
            str(b[0]): self.Body(np.array(b[1:4], float), self.Rotation(*map(float, b[4:8])))
            for b in msgpack.unpackb(data, raw=False)
        }


def connect(kind: str, hostname: str | None, options: dict[str, str]) -> Any:
    """Open a libmotioncapture connection (``mock`` needs no hardware), or the
    software-in-the-loop stand-in's poses (``sitl``, ``options["port"]``)."""
    if kind == "sitl":
        return SitlMocap(int(options["port"]))
    import motioncapture

    cfg = dict(options)
    if hostname:
        cfg["hostname"] = hostname
    return motioncapture.connect(kind, cfg)


class MocapRelay:
    """The capture loop in a thread. ``on_frame(name, estimate)`` is called for every
    tracked body in every frame; ``on_lost(name)`` once when a body goes missing."""

    def __init__(
        self,
        source: Any,
        bodies: dict[str, str],  # rigid-body name -> agent id
        rate_hz: float,
        lost_after_s: float,
        filter_s: float,
        on_frame: Callable[[str, BodyEstimate], None],
        on_lost: Callable[[str], None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.source, self.bodies, self.lost_after_s = source, bodies, lost_after_s
        self.on_frame, self.on_lost, self.clock = on_frame, on_lost, clock
        self.est = {a: PoseDifferentiator(1.0 / rate_hz, filter_s) for a in bodies.values()}
        self.seen_s = {a: clock() for a in bodies.values()}
        self.lost: set[str] = set()
        self.frames = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mocap", daemon=True)

    def latest(self, agent_id: str) -> BodyEstimate | None:
        return self.est[agent_id].last

    @property
    def dropped_frames(self) -> int:
        return max((e.dropped for e in self.est.values()), default=0)

    def start(self) -> MocapRelay:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)

    def step(self) -> None:
        """One frame: wait for it, update every body in it, check for lost bodies."""
        self.source.waitForNextFrame()
        now = self.clock()
        self.frames += 1
        for name, rb in self.source.rigidBodies.items():
            aid = self.bodies.get(name)
            if aid is None:
                continue
            p = np.asarray(rb.position, dtype=float)
            r = rb.rotation
            q = np.array([r.x, r.y, r.z, r.w], dtype=float)
            if not (np.isfinite(p).all() and np.isfinite(q).all()) or np.linalg.norm(q) < 0.5:
                continue  # an occluded body comes as NaN in some systems: not seen
            self.seen_s[aid] = now
            if aid in self.lost:
                self.lost.discard(aid)
                self.est[aid].last = None  # do not difference across the gap
                print(f"mocap: body {name} ({aid}) found again", file=sys.stderr)
            self.on_frame(aid, self.est[aid].update(now, p, q))
        for aid, seen in self.seen_s.items():
            if aid not in self.lost and now - seen > self.lost_after_s:
                self.lost.add(aid)
                print(f"mocap: body of {aid} lost (not seen for {now - seen:.3f} s)", file=sys.stderr)
                self.on_lost(aid)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.step()
            except Exception as exc:  # a broken capture stream: every body is lost
                print(f"mocap: capture failed: {exc!r}", file=sys.stderr)
                for aid in self.est:
                    if aid not in self.lost:
                        self.lost.add(aid)
                        self.on_lost(aid)
                return
