"""The real drones' measurements, as the world publishes them: the motion-capture relay
(``swarm.world.mocap``) sees each real drone at the capture rate on its own thread, and
:class:`RealDroneFeed` stamps each frame in the world's time (:func:`mocap_stamp`) and publishes
it on the drone's measurement key; the world reads the newest pose of each (:meth:`RealDroneFeed.latest`)
to hold its kinematic body there."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

from swarm.config import ScenarioConfig
from swarm.net import transport as tp
from swarm.net.messages import encode
from swarm.world.mocap import BodyEstimate, MocapRelay, connect


def mocap_stamp(wall_s: float, physics_s: float, max_lag_s: float, behind_at_end_s: float | None) -> float:
    """The world's time [s] of a real drone's motion-capture frame taken ``wall_s`` after the
    run's start: the wall clock, but at most ``max_lag_s`` ahead of the physics at ``physics_s``
    while the ticks go on; once they are over (``behind_at_end_s`` given: :func:`behind_at_end`)
    the wall clock less what the world was behind it then, so the stamps go on from where they
    were at the wall clock's pace, without a jump."""
    if behind_at_end_s is None:
        return min(wall_s, physics_s + max_lag_s)
    return wall_s - behind_at_end_s


def behind_at_end(wall_s: float, physics_s: float, max_lag_s: float) -> float:
    """How far [s] the last frame's stamp (:func:`mocap_stamp`) was behind the wall clock when
    the last tick was flown, ``wall_s`` after the run's start, with the physics at ``physics_s``."""
    return max(0.0, wall_s - physics_s - max_lag_s)


class RealDroneFeed:
    """The measurements of the real drones ``real`` of ``cfg`` (none: nothing to do), for the run
    ``run`` whose physics' time [s] ``physics_t_s`` gives. :meth:`open` declares the publishers
    and starts the relay; :meth:`start` and :meth:`end` mark the ticks' beginning and end (wall
    clock), :meth:`stop` stops the relay."""

    def __init__(self, cfg: ScenarioConfig, run: str, real: set[str], physics_t_s: Callable[[], float]) -> None:
        self.cfg, self.run_id, self.real, self.physics_t_s = cfg, run, real, physics_t_s
        self.dt_ctrl = 1.0 / cfg.time.control_hz
        self.relay: MocapRelay | None = None
        self.pubs: dict[str, Any] = {}
        self.running = threading.Event()  # the relay publishes only while the run is on
        self.wall0 = time.monotonic()
        self._seq = 10**9  # the relay thread's own sequence numbers
        self._t: dict[str, float] = {}  # the relay thread's newest stamp per real drone [s]
        self.ticks_over = False  # the last tick is flown: the stamps on the wall clock alone ...
        self.behind_at_end_s = 0.0  # ... less what the world was behind it then [s]

    def open(self, session: Any, keys: tp.Keys) -> None:
        """Declare each real drone's measurement publisher and start the relay (the config
        requires motion capture when any drone is real)."""
        self.pubs = {aid: session.declare_publisher(keys.measurement(aid)) for aid in self.real}
        m = self.cfg.mocap
        if self.real and m is not None:
            bodies = {a.mocap_body: a.id for a in self.cfg.agents if a.id in self.real}
            self.relay = MocapRelay(
                connect(m.type, m.hostname, m.options),
                bodies,
                m.rate_hz,
                m.lost_after_s,
                m.velocity_filter_s,
                self._on_frame,
                lambda aid: None,
            ).start()

    def latest(self, aid: str) -> BodyEstimate | None:
        """The newest estimate of real drone ``aid`` (None: none yet, or no relay)."""
        return None if self.relay is None else self.relay.latest(aid)

    def start(self, wall0: float) -> None:
        """The ticks start at monotonic time ``wall0`` [s]: publish from now on."""
        self.wall0 = wall0
        self.running.set()

    def end(self, wall_s: float) -> None:
        """The last tick was flown ``wall_s`` [s] after the start: the stamps go on from where
        they were at the wall clock's pace (:func:`behind_at_end`)."""
        self.behind_at_end_s = behind_at_end(wall_s, self.physics_t_s(), self.cfg.time.max_lag_s)
        self.ticks_over = True

    def stop(self) -> None:
        """Publish no more, and stop the relay."""
        self.running.clear()
        if self.relay is not None:
            self.relay.stop()

    def summary(self) -> dict[str, Any] | None:
        """The relay's frames, dropped frames and lost drones (None without a relay)."""
        relay = self.relay
        if relay is None:
            return None
        return {"frames": relay.frames, "dropped_frames": relay.dropped_frames, "lost": sorted(relay.lost)}

    def _on_frame(self, aid: str, est: BodyEstimate) -> None:
        """The relay's thread: a real drone's measurement, at the capture rate, stamped on the
        wall clock, but never more than ``time.max_lag_s`` ahead of the physics while the
        ticks go on (a world that cannot keep the wall clock: ``World.catch_up``): the agents
        take their neighbours' states in the world's time, and no agent may hear of a state
        far ahead of the newest tick. Once the ticks are over (the real drones land) the stamps
        go on at the wall clock's pace from where they were, not from the wall clock itself: a
        world that ended seconds behind it would otherwise stamp the next frame seconds after the
        last, and a landing drone's agent would take that jump as its own (its flight plan's
        time, its disturbance estimate). A frame whose stamp would not be newer than its drone's
        last is not sent (the world has not moved on: there is nothing newer to say)."""
        if not self.running.is_set():
            return
        t = mocap_stamp(time.monotonic() - self.wall0, self.physics_t_s(), self.cfg.time.max_lag_s,
                        self.behind_at_end_s if self.ticks_over else None)  # fmt: skip
        if t <= self._t.get(aid, -math.inf):
            return
        self._t[aid] = t
        self._seq += 1
        self.pubs[aid].put(
            encode("measurement", self.run_id, "world", self._seq, t, int(t / self.dt_ctrl),
                   x=est.x_w, v=est.v_w, q=est.q, w=est.Omega_b)
        )  # fmt: skip
