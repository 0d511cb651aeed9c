"""The ROS 2 bridge process: the run as ROS 2 topics, and ROS 2 goals into the run.

    swarm ros2-bridge CONFIG --run RUN --secrets DIR

One process for the whole swarm, a client of the run's Zenoh router: it takes the world's
clock (every simulated drone's measurement and the obstacles, in one message per tick),
the real drones' motion-capture measurements and the agents' commands (their filter's
report), and publishes through the router, as rmw_zenoh would (:mod:`swarm.net.ros2.graph`):

* per drone, ``<ns>/<id>/pose`` (PoseStamped) and ``<ns>/<id>/velocity`` (TwistStamped),
  ``/tf`` (world -> every drone) and ``/clock`` (sim time) at ``ros2.rate_hz`` of wall
  time: when one is due it waits for the next clock and publishes that one at once;
* per drone ``<ns>/<id>/filter_status`` (DiagnosticStatus) and ``<ns>/obstacles``
  (MarkerArray) at ``ros2.status_hz``.

It holds a liveliness token for its node and each of its publishers and subscriptions, so
``ros2 topic list`` shows them. It subscribes to ``<ns>/<id>/goal`` (PoseStamped) and
``<ns>/all/land``, ``<ns>/all/stop`` (Empty), checks each (CDR, finite, frame, above the
drone's floor) and sends the agent a ``goal`` message under ``swarm/<run>/ros2/``; a bad one is
dropped and counted. It stops when the world's liveliness goes, or on SIGTERM.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarm.config import ScenarioConfig
from swarm.errors import DecodeError
from swarm.net import transport as tp
from swarm.net.access import ROS2_BRIDGE
from swarm.net.messages import CLOCK_MEAS, Message, encode, record_of
from swarm.net.ros2 import graph
from swarm.net.ros2.interfaces import deserialize, serialize, store
from swarm.net.ros2.topics import TYPES, Kind, Topic, run_topics
from swarm.ros2 import convert
from swarm.ros2.goals import GOAL, LAND, STOP
from swarm.shutdown import StopFlag

NODE_NAME = "c3swarm_bridge"
CLOCK_FIELDS = ("meas_ids", "meas", "items", "done")
STATUS_FIELDS = (
    "status",
    "intervention",
    "solve_us",
    "row_ids",
    "h_rows",
    "min_h",
    "infeasible",
    "goal_reached",
    "monitor",
    "breaches",
    "live_margin",
)


@dataclass
class Outlet:
    """One ROS 2 publisher: its Zenoh publisher, its GID (of its token) and sequence number."""

    pub: Any
    gid: bytes
    seq: int = 0

    @property
    def heard(self) -> bool:
        """Some subscriber matches this publisher now (Zenoh's matching status)."""
        return bool(self.pub.matching_status.matching)

    def put(self, msg: Any, ros_type: str) -> None:
        self.seq += 1
        self.pub.put(serialize(msg, ros_type), attachment=graph.attachment(self.seq, time.time_ns(), self.gid))


@dataclass
class Counts:
    published: int = 0  # ROS 2 messages
    ticks: int = 0  # clocks published
    goals: int = 0  # goal, land and stop messages sent to agents
    busy_s: float = 0.0  # wall time spent converting and publishing
    delay_s: list[float] | None = None  # clock arrival -> its poses sent [s]


class Bridge:
    """The bridge's state. Phases: :meth:`wait_clock` (the clock due next),
    :meth:`publish_tick` (poses, velocities, /tf, /clock), :meth:`report` (filter status,
    obstacles) and :meth:`steer` (ROS 2 goals to the agents)."""

    def __init__(self, cfg: ScenarioConfig, run: str, session: Any) -> None:
        r = cfg.ros2
        self.cfg, self.run, self.keys, self.session = cfg, run, tp.Keys(run), session
        self.frame = r.frame_id
        self.ids = [a.id for a in cfg.agents]
        self.lengths_m = {o.id: o.length_m for o in cfg.obstacles}
        self.counter = tp.Counter()
        self.counts = Counts(delay_s=[])
        store()  # rosbags' types and serializers, loaded before the first tick
        node = graph.Node(r.domain_id, str(session.info.zid()), 0, NODE_NAME, namespace=graph.fqn(r.namespace))
        self.tokens = [session.liveliness().declare_token(node.token())]
        self.out: dict[tuple[Kind, str | None], Outlet] = {}
        self.inbound: dict[str, Topic] = {}  # key -> topic
        self.in_subs: list[Any] = []
        for entity_id, t in enumerate(run_topics(r.namespace, self.ids), start=1):
            kind = graph.Entity.SUBSCRIPTION if t.inbound else graph.Entity.PUBLISHER
            token = node.endpoint_token(entity_id, kind, t.name, t.ros_type, t.qos)
            self.tokens.append(session.liveliness().declare_token(token))
            key = t.key(r.domain_id)
            if t.inbound:
                self.inbound[key] = t
                self.in_subs.append(tp.open_channel(session, key, 64))
            else:
                self.out[(t.kind, t.agent)] = Outlet(session.declare_publisher(key), graph.gid(token))
        keys = self.keys
        self.clocks = tp.Inbox(session, keys.clock)
        self.real_meas = tp.open_channel(session, f"{keys.root}/world/*/measurement", 256)
        self.commands: Any = None  # the agents' commands, subscribed while a filter_status is heard
        self.goal_pubs = {a: session.declare_publisher(keys.ros2_goal(a)) for a in self.ids}
        self.all_pub = session.declare_publisher(keys.ros2_all)
        self.live_sub = tp.liveliness_subscriber(session, keys.alive("world"))
        self.alive = tp.declare_liveliness(session, keys.alive("ros2"))
        self.seq = 0
        self.items: list[dict[str, Any]] = []
        self.real: dict[str, Message] = {}  # a real drone's newest measurement
        self.world_seen = False
        self.done = False

    def world_gone(self) -> bool:
        for _, up in tp.liveliness_events(self.live_sub):
            self.world_seen |= up
            if not up:
                return True
        return False

    def wait_clock(self, deadline: float) -> tuple[Message, float] | None:
        """The first clock to arrive from now on (the ones queued before are stale), and
        its arrival [s, ``time.monotonic``]; None at ``deadline``."""
        for _ in self.clocks.drain():
            pass
        s = self.clocks.get(deadline)
        if s is None:
            return None
        arrived = time.monotonic()
        m = tp.decode_sample(s, self.run, self.counter, ("clock",), CLOCK_FIELDS)
        return (m, arrived) if m is not None else None

    def publish_tick(self, clock: Message, arrived: float) -> None:
        """Poses, velocities, /tf and /clock of ``clock`` (and the real drones' newest)."""
        t0 = time.monotonic()
        ids = list(clock["meas_ids"])
        if clock["meas"].size != CLOCK_MEAS * len(ids):
            self.counter.drop("clock: meas does not match meas_ids")
            return
        meas = clock["meas"].reshape(-1, CLOCK_MEAS)
        for s in tp.drain(self.real_meas):
            m = tp.decode_sample(s, self.run, self.counter, ("measurement",))
            name = str(s.key_expr).split("/")[-2]
            if m is not None and name in self.ids:
                self.real[name] = m
        rows = [meas[i] for i in range(len(ids))]
        for name, m in self.real.items():
            ids.append(name)
            rows.append(np.concatenate([m["x"], m["v"], m["q"], m["w"]]))
        t, frame, out, sent = clock.t, self.frame, self.out, 0
        for name, row in zip(ids, rows, strict=True):  # (a topic nobody subscribes to costs nothing)
            x, v, q, w = row[0:3], row[3:6], row[6:10], row[10:13]
            if (o := out[(Kind.POSE, name)]).heard:
                o.put(convert.pose_stamped(t, frame, x, q), TYPES[Kind.POSE])
                sent += 1
            if (o := out[(Kind.VELOCITY, name)]).heard:
                o.put(convert.twist_stamped(t, frame, v, w, q), TYPES[Kind.VELOCITY])
                sent += 1
        if ids and (o := out[(Kind.TF, None)]).heard:
            xs = np.array([r[0:3] for r in rows])
            qs = np.array([r[6:10] for r in rows])
            o.put(convert.tf_message(t, frame, ids, xs, qs), TYPES[Kind.TF])
            sent += 1
        if (o := out[(Kind.CLOCK, None)]).heard:
            o.put(convert.clock(t), TYPES[Kind.CLOCK])
            sent += 1
        self.items = clock["items"]
        self.counts.published += sent
        self.counts.ticks += 1
        now = time.monotonic()
        self.counts.busy_s += now - t0
        if self.counts.delay_s is not None and len(self.counts.delay_s) < 100_000:
            self.counts.delay_s.append(now - arrived)
        self.done |= bool(clock["done"])

    def _follow_commands(self) -> bool:
        """Subscribe to the agents' commands while some filter_status is heard, and only
        then (each command through the router costs the router and this process about as
        much as all the rest of the bridge); whether subscribed."""
        heard = any(self.out[(Kind.STATUS, a)].heard for a in self.ids)
        if heard and self.commands is None:
            self.commands = tp.open_channel(self.session, self.keys.all_commands, 1 << 14)
        elif not heard and self.commands is not None:
            self.commands.undeclare()
            self.commands = None
        return self.commands is not None

    def report(self, t_s: float) -> None:
        """Each agent's newest filter report as its filter_status, and the obstacles."""
        t0 = time.monotonic()
        newest: dict[str, Any] = {}
        for s in tp.drain(self.commands) if self._follow_commands() else ():
            newest[str(s.key_expr)] = s  # (in order: the last is the newest)
        for key, s in newest.items():
            name = key.split("/")[-2]
            m = tp.decode_sample(s, self.run, self.counter, ("command",), STATUS_FIELDS)
            if m is None or name not in self.ids or m.src != name:
                continue
            self.out[(Kind.STATUS, name)].put(convert.filter_status(name, record_of(m)), TYPES[Kind.STATUS])
            self.counts.published += 1
        if self.items and (o := self.out[(Kind.OBSTACLES, None)]).heard:
            o.put(convert.marker_array(t_s, self.frame, self.items, self.lengths_m), TYPES[Kind.OBSTACLES])
            self.counts.published += 1
        self.counts.busy_s += time.monotonic() - t0

    def steer(self) -> None:
        """Every goal, land and stop that arrived from ROS 2, checked, to its agents."""
        for sub in self.in_subs:
            for s in tp.drain(sub):
                topic = self.inbound.get(str(s.key_expr))
                if topic is None:
                    self.counter.drop("ros2: a key the bridge does not take")
                    continue
                try:
                    self._steer(topic, tp.payload(s))
                except DecodeError as exc:
                    self.counter.drop(f"ros2 {topic.name}: {exc}")
                    print(f"ros2: dropped a message on {topic.name}: {exc}", file=sys.stderr, flush=True)

    def _steer(self, topic: Topic, data: bytes) -> None:
        try:
            msg = deserialize(data, topic.ros_type)
        except Exception as exc:  # rosbags raises several types on a short or garbled payload
            raise DecodeError(f"not a {topic.ros_type} ({type(exc).__name__})") from None
        self.seq += 1
        if topic.kind is Kind.GOAL:
            assert topic.agent is not None
            x = convert.goal_position(msg, self.frame)
            me = self.cfg.agent(topic.agent)
            floor = me.filter.floor_z_m if me.filter.enabled else None
            if x[2] < 0.0 or (floor is not None and x[2] < floor):
                raise DecodeError(f"goal: z = {x[2]:.3f} m is below {topic.agent}'s floor")
            body = encode("goal", self.run, ROS2_BRIDGE, self.seq, 0.0, 0, action=GOAL, x=x)
            self.goal_pubs[topic.agent].put(body)
            print(f"ros2: {topic.agent} goal {np.round(x, 3).tolist()}", file=sys.stderr, flush=True)
        else:
            action = LAND if topic.kind is Kind.LAND else STOP
            self.all_pub.put(encode("goal", self.run, ROS2_BRIDGE, self.seq, 0.0, 0, action=action, x=np.zeros(3)))
            print(f"ros2: {action} for all", file=sys.stderr, flush=True)
        self.counts.goals += 1

    def summary(self) -> dict[str, Any]:
        c = self.counts
        d = np.array(c.delay_s or [0.0]) * 1e3
        return {
            "ticks": c.ticks,
            "published": c.published,
            "goals": c.goals,
            "busy_s": c.busy_s,
            "delay_median_ms": float(np.median(d)),
            "delay_p99_ms": float(np.percentile(d, 99)),
            "cpu_s": time.process_time(),
            "dropped": self.counter.dropped,
            "reasons": self.counter.reasons,
        }


def main(cfg: ScenarioConfig, run: str, conf: Any) -> int:
    """Bridge the run until the world is gone or a signal stops it."""
    stop = StopFlag()
    session = tp.open_session(conf)
    bridge = Bridge(cfg, run, session)
    startup_cpu_s = time.process_time()
    period_s, status_s = 1.0 / cfg.ros2.rate_hz, 1.0 / cfg.ros2.status_hz
    next_tick = next_status = time.monotonic()
    print(f"ros2: bridging {len(bridge.ids)} drones on domain {cfg.ros2.domain_id}", file=sys.stderr, flush=True)
    while not stop and not bridge.done:
        bridge.steer()
        if bridge.world_gone():
            break
        now = time.monotonic()
        if now < next_tick:
            time.sleep(min(next_tick - now, 0.05))
            continue
        got = bridge.wait_clock(time.monotonic() + 0.1)
        if got is None:
            continue
        clock, arrived = got
        bridge.publish_tick(clock, arrived)
        next_tick = max(next_tick + period_s, arrived)
        if arrived >= next_status:
            bridge.report(clock.t)
            next_status = max(next_status + status_s, arrived)
    summary = bridge.summary() | {"startup_cpu_s": startup_cpu_s}
    print("ROS2_SUMMARY " + json.dumps(summary), file=sys.stderr, flush=True)
    bridge.alive.undeclare()
    for token in bridge.tokens:
        token.undeclare()
    return 0
