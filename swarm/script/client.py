"""A Python client for a running swarm: a script's side of ``script.enabled`` (docs/scripting.md).

    from swarm.script import Swarm

    with Swarm.connect("runs/s1") as swarm:          # the run folder `swarm run` writes
        swarm.takeoff(1.0, duration_s=2.5).wait()
        swarm.go_to("cf1", [1.0, 0.0, 1.0]).wait(timeout_s=20)
        swarm.land().wait()
        swarm.end("done")

The client is a Zenoh session of the run's ``script`` user, linked to the run's router with
the run's credentials (``<run>/secrets``, or a copy on another machine). It hears the world's
clock (every simulated drone's measurement, each tick) and the real drones' motion capture,
sends orders to the agents (``swarm.agents.orders``) and hears their reports. It cannot fly
anything itself: each order only moves the reference of a drone's agent, whose safety filter
still decides every command, and the router refuses the ``script`` user everything but orders
for the drones ``script.drones`` names, the run's end and its own liveliness.

Every wait is in the run's time (sim time, which in a lockstep run goes at the swarm's
pace), ends when the run ends, and raises :class:`swarm.errors.ArrivalTimeoutError` at its limit.
Blocking calls have ``async`` forms (``await orders``, :meth:`Swarm.asleep`,
:meth:`Swarm.astream`) for an asyncio script.
"""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections.abc import AsyncIterator, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from swarm.agents.orders import Action, check_point, cruise_speed, steerable
from swarm.config import ScenarioConfig, load
from swarm.errors import ArrivalTimeoutError, RefusedError, ScriptError
from swarm.net import access
from swarm.net import transport as tp
from swarm.net.messages import CLOCK_MEAS, encode
from swarm.rotation import FloatArray

RUN_FILE = "run.json"  # in a run folder: the run's id (swarm.runs.launch)
POLL_S = 0.002  # wall time between looks at what arrived while waiting [s]
SILENT_S = 30.0  # a wait fails when no clock has arrived for this long (wall time) [s]


class DroneState(NamedTuple):
    """One drone's measured state at run time ``t_s`` [s]."""

    t_s: float
    pos_w: FloatArray  # (3,) m, world
    vel_w: FloatArray  # (3,) m/s, world
    quat: FloatArray  # (4,) attitude (x, y, z, w), body to world


class Snapshot(NamedTuple):
    """Every drone's newest state at one tick of the run."""

    t_s: float  # run time [s]
    k: int  # control tick
    drones: dict[str, DroneState]


class Report(NamedTuple):
    """An agent's report on an order: ``taken`` (``goal_w`` the goal it flies to),
    ``refused`` (``why``) or ``arrived`` (within ``goal_tolerance_m`` of it), at run time ``t_s``."""

    drone: str
    order: int
    action: str
    state: str
    goal_w: FloatArray  # (3,) m, world
    t_s: float
    why: str = ""


@dataclass
class Orders:
    """The orders of one call, one per drone (``order`` numbers). :meth:`wait` blocks until
    every drone has arrived; ``await orders`` is its async form."""

    swarm: Swarm
    sent: dict[str, int]  # drone -> order number
    t0_s: float  # run time they were sent [s]
    reports: dict[str, Report] = field(default_factory=dict)  # each drone's newest

    def wait(self, timeout_s: float = 60.0) -> dict[str, Report]:
        """Each drone's ``arrived`` report, once every one has arrived; raises
        :class:`RefusedError` if a drone refused its order, :class:`ArrivalTimeoutError` when
        ``timeout_s`` [s, run time] passes first and :class:`ScriptError` if the run ends."""
        until = self.swarm.now_s + timeout_s
        while not self.done():
            self.swarm.pump_until(until, lambda: self.done(), f"{self.waiting()} to arrive")
        return self.reports

    def done(self) -> bool:
        self.reports.update(self.swarm.reports_on(self.sent))
        for r in self.reports.values():
            if r.state == "refused":
                raise RefusedError(f"{r.drone} refused order {r.order} ({r.action}): {r.why}")
        return all(r.state == "arrived" for r in self.reports.values()) and len(self.reports) == len(self.sent)

    def waiting(self) -> str:
        late = [d for d in self.sent if self.reports.get(d, None) is None or self.reports[d].state != "arrived"]
        return ", ".join(late)

    async def wait_async(self, timeout_s: float = 60.0) -> dict[str, Report]:
        """:meth:`wait` without blocking the event loop (it polls every few milliseconds)."""
        until = self.swarm.now_s + timeout_s
        while not self.done():
            self.swarm.pump()
            self.swarm.check_until(until, f"{self.waiting()} to arrive")
            await asyncio.sleep(POLL_S)
        return self.reports

    def __await__(self) -> Any:
        return self.wait_async().__await__()


class Swarm:
    """A client of one running swarm: :meth:`connect` to it, then read its drones' states and
    send them orders. Orders go to one drone, a group (a list of ids) or every drone the
    script may steer (``None``)."""

    def __init__(self, cfg: ScenarioConfig, run: str, session: Any) -> None:
        self.cfg, self.run, self.session = cfg, run, session
        keys = tp.Keys(run)
        self.keys = keys
        self.counter = tp.Counter()
        self._clock = tp.open_ring(session, keys.clock, 256)
        self._real = tp.open_ring(session, f"{keys.root}/world/*/measurement", 256)
        self._reports = tp.open_channel(session, keys.all_reports, 4096)
        self._alive = tp.liveliness_subscriber(session, keys.all_alive)
        self._pubs = {d: session.declare_publisher(keys.order(d)) for d in cfg.steerable}
        self._token = tp.declare_liveliness(session, keys.alive(access.SCRIPT))
        self.latest: Snapshot | None = None
        self.over = False  # the world said the run is over, or its liveliness went
        self.live: set[str] = set()
        self._seen_world = False
        self._last_clock_wall = time.monotonic()
        self._reports_by: dict[tuple[str, int], Report] = {}
        self._order = 0
        self._seq = 0
        self._snapshots: list[Snapshot] = []  # what arrived since the last stream() step
        self._handle: Any = None  # a run this client started (launch)

    # --- joining ----------------------------------------------------------------
    @classmethod
    def connect(
        cls,
        run_dir: str | Path | None = None,
        *,
        config: str | Path | ScenarioConfig | None = None,
        run: str | None = None,
        secrets: str | Path | None = None,
        host: str | None = None,
        port: int | None = None,
        timeout_s: float = 60.0,
        ready: bool = True,
    ) -> Swarm:
        """Join a running swarm. Locally give its run folder (``swarm run ... --out DIR``: its
        ``config.yaml``, ``run.json`` and ``secrets/``, waited for up to ``timeout_s`` [s, wall]
        while the run starts). Across machines give the ``config``, the ``run`` id, the copied
        ``secrets`` folder and the router's ``host`` and ``port`` (as ``swarm agent`` takes
        them). With ``ready`` it then waits until every drone the script may steer is live.

        Raises :class:`ScriptError` when the router is not reached or refuses the credentials."""
        deadline = time.monotonic() + timeout_s
        if run_dir is not None:
            folder = Path(run_dir)
            while not ((folder / RUN_FILE).exists() and (folder / "config.yaml").exists()):
                if time.monotonic() > deadline:
                    raise ScriptError(f"{folder}: no running swarm there ({RUN_FILE} and config.yaml not written)")
                time.sleep(0.05)
            config = config or folder / "config.yaml"
            run = run or json.loads((folder / RUN_FILE).read_text())["run"]
            secrets = secrets or folder / "secrets"
        if config is None or run is None:
            raise ScriptError("give a run folder, or the config and the run id")
        cfg = config if isinstance(config, ScenarioConfig) else load(config)
        net = cfg.network.model_copy(update={k: v for k, v in (("host", host), ("port", port)) if v is not None})
        cfg = cfg.model_copy(update={"network": net})
        if not cfg.script.enabled:
            raise ScriptError(f"run {run!r} takes no script (its config has script.enabled: false)")
        if not cfg.network.port:
            raise ScriptError("the router's port is not known: give port (the run's network.port)")
        acc = None
        if cfg.network.access_control:
            if secrets is None:
                raise ScriptError("the run has access control: give its secrets folder")
            acc = tp.Access(run, access.SCRIPT, Path(secrets), tuple(a.id for a in cfg.agents))
        conf = tp.process_config(cfg, tp.Role.SCRIPT, acc)
        wait_ms = int(max(1.0, deadline - time.monotonic()) * 1000)
        conf.insert_json5("connect/timeout_ms", json.dumps({"client": wait_ms}))
        conf.insert_json5("connect/exit_on_failure", json.dumps({"client": True}))
        where = f"{cfg.network.host}:{cfg.network.port}"
        try:
            session = tp.open_session(conf)
        except Exception as exc:  # zenoh.ZError: unable to connect (refused, or no router there)
            raise ScriptError(
                f"run {run!r}: its router at {where} refused this client or is not there ({exc}); "
                "check the run's credentials (secrets) and address"
            ) from None
        swarm = cls(cfg, run, session)
        if ready:
            try:
                swarm.wait_ready(max(1.0, deadline - time.monotonic()))
            except BaseException:
                swarm.close()
                raise
        return swarm

    @classmethod
    def launch(cls, config: str | Path | ScenarioConfig, out: str | Path, timeout_s: float = 120.0) -> Swarm:
        """Start the run of ``config`` into the folder ``out`` (as ``swarm run``) and join it;
        :meth:`close` (or the ``with`` block's end) ends the run and writes its metrics."""
        from swarm.runs.launch import RunHandle

        cfg = config if isinstance(config, ScenarioConfig) else load(config)
        handle = RunHandle.start(cfg, Path(out))
        try:
            swarm = cls.connect(handle.out, timeout_s=timeout_s)
        except BaseException:
            handle.finish("the script could not join")
            raise
        swarm._handle = handle
        return swarm

    def wait_ready(self, timeout_s: float) -> None:
        """Until the world and every steerable drone are live and a clock has arrived
        (``timeout_s`` [s, wall])."""
        deadline = time.monotonic() + timeout_s
        want = {"world", *self.cfg.steerable}
        while not (want <= self.live and self.latest is not None):
            self.pump()
            if self.over:
                raise ScriptError(f"run {self.run} is over")
            if time.monotonic() > deadline:
                missing = ", ".join(sorted(want - self.live)) or "the first clock"
                raise ScriptError(f"run {self.run}: not ready within {timeout_s:.0f} s (waiting for {missing})")
            time.sleep(POLL_S)

    # --- what the run says -------------------------------------------------------------
    @property
    def drones(self) -> list[str]:
        """Every drone of the run (``steerable``: those the script may steer)."""
        return [a.id for a in self.cfg.agents]

    @property
    def steerable(self) -> list[str]:
        return list(self.cfg.steerable)

    @property
    def now_s(self) -> float:
        """The run's time [s] of the newest clock (0 before the first)."""
        return self.latest.t_s if self.latest is not None else 0.0

    def pump(self) -> None:
        """Take what has arrived: clocks, motion capture, reports, liveliness."""
        real: dict[str, DroneState] = {}
        for s in tp.drain(self._real):
            m = tp.decode_sample(s, self.run, self.counter, ("measurement",))
            if m is not None:
                real[str(s.key_expr).split("/")[-2]] = DroneState(m.t, m["x"], m["v"], m["q"])
        for s in tp.drain(self._clock):
            m = tp.decode_sample(s, self.run, self.counter, ("clock",), ("meas_ids", "meas", "done"))
            if m is None:
                continue
            meas = np.asarray(m["meas"]).reshape(-1, CLOCK_MEAS)
            drones = {
                d: DroneState(m.t, row[0:3].copy(), row[3:6].copy(), row[6:10].copy())
                for d, row in zip(m["meas_ids"], meas, strict=True)
            }
            before = self.latest.drones if self.latest is not None else {}
            snap = Snapshot(m.t, m.k, {**before, **real, **drones})
            self.latest = snap
            self._snapshots.append(snap)
            del self._snapshots[:-256]
            self._last_clock_wall = time.monotonic()
            self.over |= bool(m["done"])
        if real and self.latest is not None:
            self.latest = self.latest._replace(drones={**self.latest.drones, **real})
        for s in tp.drain(self._reports):
            m = tp.decode_sample(s, self.run, self.counter, ("report",))
            if m is None:
                continue
            r = Report(m.src, int(m["order"]), m["action"], m["state"], m["x"], m.t, m["why"])
            old = self._reports_by.get((r.drone, r.order))
            if old is None or old.state != "arrived":  # (arrived is final)
                self._reports_by[(r.drone, r.order)] = r
        for name, up in tp.liveliness_events(self._alive):
            if up:
                self.live.add(name)
                self._seen_world |= name == "world"
            else:
                self.live.discard(name)
                self.over |= name == "world"

    def reports_on(self, sent: dict[str, int]) -> dict[str, Report]:
        """The newest report on each of ``sent`` (drone -> order number) that has arrived."""
        self.pump()
        return {d: r for d, n in sent.items() if (r := self._reports_by.get((d, n))) is not None}

    def check_until(self, until_s: float, what: str) -> None:
        """Raise if the run is over, has gone silent, or its time is past ``until_s`` [s]."""
        if self.now_s > until_s:
            raise ArrivalTimeoutError(f"run {self.run}: still waiting for {what} at t = {self.now_s:.2f} s")
        if self.over:
            raise ScriptError(f"run {self.run} ended while waiting for {what}")
        if time.monotonic() - self._last_clock_wall > SILENT_S:
            raise ScriptError(f"run {self.run}: no clock for {SILENT_S:.0f} s while waiting for {what}")

    def pump_until(self, until_s: float, ok: Any, what: str) -> None:
        while True:
            self.pump()
            if ok():
                return
            self.check_until(until_s, what)
            time.sleep(POLL_S)

    def state(self, drone: str) -> DroneState:
        """``drone``'s newest measured state."""
        self.pump()
        if drone not in self.drones:
            raise RefusedError(f"no drone {drone!r} in run {self.run} (drones: {', '.join(self.drones)})")
        if self.latest is None or drone not in self.latest.drones:
            raise ScriptError(f"no state of {drone} yet")
        return self.latest.drones[drone]

    def states(self) -> Snapshot:
        """Every drone's newest state."""
        self.pump()
        if self.latest is None:
            raise ScriptError("no state yet")
        return self.latest

    def stream(self, duration_s: float | None = None) -> Iterator[Snapshot]:
        """Every tick's snapshot as it arrives (a slow reader skips ticks: the newest 256
        are kept), for ``duration_s`` [s, run time] or until the run ends."""
        until = self._stream_until(duration_s)
        while not self.over and self.now_s <= until:
            snaps, done = self._due(until)
            yield from snaps
            if done:
                return
            time.sleep(POLL_S)

    async def astream(self, duration_s: float | None = None) -> AsyncIterator[Snapshot]:
        """:meth:`stream` for asyncio."""
        until = self._stream_until(duration_s)
        while not self.over and self.now_s <= until:
            snaps, done = self._due(until)
            for snap in snaps:
                yield snap
            if done:
                return
            await asyncio.sleep(POLL_S)

    def _stream_until(self, duration_s: float | None) -> float:
        """A stream's start: the snapshots heard so far forgotten; its end [s, run time]."""
        self.pump()
        self._snapshots.clear()
        return math.inf if duration_s is None else self.now_s + duration_s

    def _due(self, until: float) -> tuple[list[Snapshot], bool]:
        """The snapshots heard since the last call up to ``until`` [s, run time], and whether
        one past it came (the stream's end)."""
        self.pump()
        out: list[Snapshot] = []
        while self._snapshots:
            snap = self._snapshots.pop(0)
            if snap.t_s > until:
                return out, True
            out.append(snap)
        return out, False

    def sleep(self, duration_s: float) -> None:
        """Wait ``duration_s`` [s] of the run's time (Crazyswarm2's ``timeHelper.sleep``)."""
        until = self.now_s + duration_s
        self.pump_until(math.inf, lambda: self.now_s >= until or self.over, f"t = {until:.2f} s")

    async def asleep(self, duration_s: float) -> None:
        until = self.now_s + duration_s
        while self.now_s < until and not self.over:
            self.pump()
            await asyncio.sleep(POLL_S)

    # --- orders ---------------------------------------------------------------------
    def _group(self, drones: str | Iterable[str] | None) -> list[str]:
        group = self.steerable if drones is None else [drones] if isinstance(drones, str) else list(drones)
        if not group:
            raise RefusedError("no drone to order")
        for d in group:
            steerable(self.cfg, d)
        return group

    def _send(self, orders: dict[str, tuple[Action, FloatArray, float, float]]) -> Orders:
        """Put one order per drone (all checked before any is sent)."""
        self.pump()
        sent = {}
        for d, (action, x, yaw, speed) in orders.items():
            self._order += 1
            self._seq += 1
            body = encode(
                "order", self.run, access.SCRIPT, self._seq, self.now_s, 0,
                order=self._order, action=action.value, x=np.asarray(x, float), yaw=float(yaw), speed=float(speed),
            )  # fmt: skip
            self._pubs[d].put(body)
            sent[d] = self._order
        return Orders(self, sent, self.now_s)

    def _here(self, d: str) -> FloatArray:
        return np.asarray(self.state(d).pos_w, dtype=float)

    def takeoff(
        self, height_m: float, duration_s: float | None = None, drones: str | Iterable[str] | None = None
    ) -> Orders:
        """Climb straight up to ``height_m`` [m, world z] in about ``duration_s`` [s] (None:
        at each drone's own speed)."""
        group = self._group(drones)
        out = {}
        for d in group:
            here = self._here(d)
            goal = check_point(self.cfg, d, np.array([here[0], here[1], height_m]), "take-off height")
            speed = cruise_speed(
                self.cfg.agent(d), abs(goal[2] - here[2]), duration_s, None, self.cfg.script.min_speed_mps
            )
            out[d] = (Action.TAKEOFF, goal, 0.0, speed)
        return self._send(out)

    def go_to(
        self,
        drone: str,
        goal_w: Any,
        yaw_rad: float = 0.0,
        duration_s: float | None = None,
        speed_mps: float | None = None,
    ) -> Orders:
        """Fly ``drone`` to ``goal_w`` [m, world] in about ``duration_s`` [s] or at
        ``speed_mps`` [m/s] (at most its own ``speed_mps``; neither: its own). ``yaw_rad`` is
        taken and recorded but not flown (the drones hold their yaw)."""
        return self.go_to_many({drone: goal_w}, yaw_rad, duration_s, speed_mps)

    def go_to_many(
        self,
        goals_w: dict[str, Any],
        yaw_rad: float = 0.0,
        duration_s: float | None = None,
        speed_mps: float | None = None,
    ) -> Orders:
        """:meth:`go_to` for several drones at once (``{drone: goal_w}``); all are checked
        before any is sent."""
        if not math.isfinite(yaw_rad):
            raise RefusedError(f"yaw {yaw_rad} rad is not finite")
        out = {}
        for d in self._group(list(goals_w)):
            goal = check_point(self.cfg, d, goals_w[d])
            dist = float(np.linalg.norm(goal - self._here(d)))
            speed = cruise_speed(self.cfg.agent(d), dist, duration_s, speed_mps, self.cfg.script.min_speed_mps)
            out[d] = (Action.GOTO, goal, yaw_rad, speed)
        return self._send(out)

    def land(self, drones: str | Iterable[str] | None = None) -> Orders:
        """Straight down: a real Crazyflie lands (motors off), a simulated drone descends to
        its floor (``filter.floor_z_m``)."""
        return self._send({d: (Action.LAND, np.zeros(3), 0.0, 0.0) for d in self._group(drones)})

    def stop(self, drones: str | Iterable[str] | None = None) -> Orders:
        """Hold where they are (arrived at once)."""
        return self._send({d: (Action.STOP, np.zeros(3), 0.0, 0.0) for d in self._group(drones)})

    def end(self, reason: str = "the script is done") -> None:
        """End the run (every process stops; the run's metrics say ``completed``)."""
        self._seq += 1
        self.session.put(
            self.keys.script_done, encode("end", self.run, access.SCRIPT, self._seq, self.now_s, 0, reason=reason)
        )

    # --- leaving ----------------------------------------------------------------------
    def close(self) -> None:
        """Leave the run. A run this client started (:meth:`launch`) is ended first (if the
        script has not ended it) and its metrics written."""
        handle, self._handle = self._handle, None
        try:
            if handle is not None and not self.over:
                self.end("the script that started the run left")
            self._token.undeclare()
        finally:
            self.session.close()
            if handle is not None:
                handle.wait(timeout_s=60.0)

    def __enter__(self) -> Swarm:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
