"""Zenoh wiring: session configs, key expressions, and draining channels once per tick.

The only module of ``swarm/`` that imports zenoh. Subscribers come in two kinds: FIFO
channel handlers (:func:`open_channel`, drained once per tick with :func:`drain`), and the
:class:`Inbox`, whose callback, run by Zenoh's receive thread, only enqueues each sample so
that a wait wakes as soon as enough have arrived. A process with a callback subscriber can
hang in ``session.close()`` or at interpreter exit, so the processes that own an Inbox (the
world, the agents, the router, the recorder) end with ``os._exit`` and never close their
session. Every blocking wait has a deadline.
"""

from __future__ import annotations

import fcntl
import json
import os
import queue
import socket
import struct
import sys
import termios
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import zenoh

from swarm.net import access
from swarm.net.messages import DecodeError, Message, decode

if TYPE_CHECKING:
    from swarm.config import ScenarioConfig


@dataclass(frozen=True)
class Keys:
    """Key expressions of one run, all under ``swarm/<run>/``."""

    run: str

    @property
    def root(self) -> str:
        return f"swarm/{self.run}"

    def measurement(self, agent_id: str) -> str:
        return f"{self.root}/world/{agent_id}/measurement"

    @property
    def clock(self) -> str:
        return f"{self.root}/world/clock"

    @property
    def status(self) -> str:
        return f"{self.root}/world/status"

    @property
    def collision(self) -> str:
        return f"{self.root}/world/collision"

    @property
    def stall(self) -> str:
        return f"{self.root}/world/stall"

    def tick(self, agent_id: str) -> str:
        """World -> one agent (``neighbours.interest: cells``): its measurement, the
        obstacles and the neighbours near it, at tick k."""
        return f"{self.root}/world/{agent_id}/tick"

    def state(self, agent_id: str) -> str:
        return f"{self.root}/agent/{agent_id}/state"

    @property
    def all_states(self) -> str:
        return f"{self.root}/agent/*/state"

    def bundle(self, agent_id: str) -> str:
        """Router -> one agent (``neighbours.interest: bundle``): the states near it."""
        return f"{self.root}/router/bundle/{agent_id}"

    def cell_state(self, cell: tuple[int, int, int], agent_id: str) -> str:
        """An agent's state, published under the cell of its body centre (swarm.net.cells)."""
        return f"{self.root}/cell/{cell[0]}/{cell[1]}/{cell[2]}/{agent_id}"

    @property
    def cell_prefix(self) -> str:
        """The start of every cell key (swarm.net.cells)."""
        return f"{self.root}/cell/"

    def cell(self, cell: tuple[int, int, int]) -> str:
        """Every state published in ``cell``."""
        return f"{self.root}/cell/{cell[0]}/{cell[1]}/{cell[2]}/*"

    def command(self, agent_id: str) -> str:
        return f"{self.root}/agent/{agent_id}/command"

    @property
    def all_commands(self) -> str:
        return f"{self.root}/agent/*/command"

    def alive(self, name: str) -> str:
        return f"{self.root}/alive/{name}"

    @property
    def all_alive(self) -> str:
        return f"{self.root}/alive/*"

    def ros2_goal(self, agent_id: str) -> str:
        """The ROS 2 bridge -> one agent: a new goal from ROS 2 (``swarm.ros2.goals``)."""
        return f"{self.root}/ros2/goal/{agent_id}"

    @property
    def ros2_all(self) -> str:
        """The ROS 2 bridge -> every agent: land, or stop where it is."""
        return f"{self.root}/ros2/all"

    @property
    def land(self) -> str:
        """The launcher -> the world and every agent: land every drone now and end the run
        once they are down (``swarm run``'s first Ctrl-C; ``swarm.landing``)."""
        return f"{self.root}/land"

    @property
    def everything(self) -> str:
        return f"{self.root}/**"

    @property
    def recorded(self) -> list[str]:
        """What the recorder records (:data:`RECORDED`)."""
        return [f"{self.root}/{k}" for k in RECORDED]

    @staticmethod
    def last(key: str) -> str:
        return key.rsplit("/", 1)[-1]


RECORDED = ("world/clock", "world/status", "world/collision", "world/stall", "world/*/measurement", "agent/*/command")
"""The keys under ``swarm/<run>/`` the recorder records: the world's clock, status, contacts,
stalls and real drones' measurements, and the agents' commands with their filter reports
(not states, bundles or ticks: the clock carries every measured state)."""


def session_config(
    *,
    mode: str = "peer",
    listen: list[str] | None = None,
    connect: list[str] | None = None,
    gossip: bool = True,
    lowlatency: bool = False,
) -> zenoh.Config:
    """A Zenoh config with multicast scouting off and explicit endpoints. Peers find each
    other through the endpoints they connect to (gossip), never by multicast; with
    ``gossip`` off they link only to the endpoints they connect to. ``lowlatency``: Zenoh's
    low-latency transport (QoS off, which it needs): a ``put`` is written to the socket in
    the calling thread, with no transmit thread to wake.

    Every put on a :data:`RECORDED` key waits for room in a full link rather than being
    dropped (Zenoh's congestion control ``block``; a put's default is ``drop``): a stalled
    recorder then holds its senders back once the link's queue and the kernel's buffers
    are full, instead of losing their messages. (The low-latency transport writes the
    socket in the caller and always waits.)"""
    conf = zenoh.Config()
    blocked = [{"key_exprs": [f"swarm/*/{k}" for k in RECORDED], "config": {"congestion_control": "block"}}]
    conf.insert_json5("qos/publication", json.dumps(blocked))
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if not gossip:
        conf.insert_json5("scouting/gossip/enabled", "false")
    else:
        # of two peers that gossip told about each other, only the one with the greater id
        # opens their link. Zenoh's default (both open it) makes a duplicate link, which with
        # user-password authentication is refused, now and then leaving the pair unlinked
        # (eclipse-zenoh/zenoh#2577)
        strategy = {"peer": {"to_router": "always", "to_peer": "greater-zid"}}
        conf.insert_json5("scouting/gossip/autoconnect_strategy", json.dumps(strategy))
    if lowlatency:
        conf.insert_json5("transport/unicast/lowlatency", "true")
        conf.insert_json5("transport/unicast/qos/enabled", "false")
    if mode in ("peer", "router"):
        conf.insert_json5("listen/endpoints", json.dumps(listen if listen is not None else ["tcp/127.0.0.1:0"]))
    conf.insert_json5("connect/endpoints", json.dumps(connect or []))
    return conf


def world_endpoint(host: str, port: int, proto: str = "tcp") -> str:
    return f"{proto}/{host}:{port}"


class Role(StrEnum):
    """The process a session belongs to; in a star it decides the session's links."""

    WORLD = "world"
    RECORDER = "recorder"
    LAUNCHER = "launcher"
    AGENT = "agent"
    OBSERVER = "observer"  # anything else that joins a run (a test, a user's tool)
    ROUTER = "router"  # the Zenoh router of network.topology: router
    ROS2 = "ros2-bridge"  # the run's ROS 2 bridge (swarm.ros2.bridge)


ROUTER_WAIT_S = 20.0  # how long a client tries to reach the router before its session fails to open
HUBS = (Role.WORLD, Role.RECORDER, Role.LAUNCHER, Role.ROUTER)  # a star's listeners, on port + 0..3


def star_hubs(cfg: ScenarioConfig) -> tuple[Role, ...]:
    """The hubs of ``cfg``'s star, hub i listening on ``network.port + i``
    (``ScenarioConfig.star_hubs``: the bundle relay only with agents as the neighbour source)."""
    return tuple(Role(h) for h in cfg.star_hubs)


@dataclass(frozen=True)
class Access:
    """The credentials one process of a run uses (:mod:`swarm.net.access`): its user name,
    the run's secrets folder, and what the access-control rules need to know."""

    run: str
    user: str
    secrets: Path  # the folder with users.txt (and the run's TLS files, if made per run)
    agent_ids: tuple[str, ...]

    @classmethod
    def of(cls, cfg: ScenarioConfig, run: str, role: Role, secrets: Path, agent_id: str | None = None) -> Access:
        user = access.agent_user(agent_id) if role is Role.AGENT and agent_id else role.value
        return cls(run, user, secrets, tuple(a.id for a in cfg.agents))


def _secure(conf: zenoh.Config, cfg: ScenarioConfig, acc: Access, listens: bool) -> None:
    """Add the run's authentication, access control and TLS to ``conf``."""
    auth: dict[str, str] = {"user": acc.user, "password": access.password(acc.secrets, acc.user)}
    if listens:  # who may link to this session: the run's processes alone
        auth["dictionary_file"] = str(acc.secrets / access.USERS_FILE)
    conf.insert_json5("transport/auth/usrpwd", json.dumps(auth))
    tls = cfg.network.tls
    identified = False
    if tls.enabled:
        files = tls.files(acc.secrets, acc.user)
        for key, path in (
            ("root_ca_certificate", files.root_ca),
            ("listen_certificate", files.certificate),
            ("listen_private_key", files.private_key),
            ("connect_certificate", files.certificate),
            ("connect_private_key", files.private_key),
        ):
            conf.insert_json5(f"transport/link/tls/{key}", json.dumps(str(path)))
        conf.insert_json5("transport/link/tls/enable_mtls", json.dumps(tls.mutual))
        conf.insert_json5("transport/link/tls/verify_name_on_connect", "true")
        identified = files.own and tls.mutual
    router = None
    if acc.user == access.ROUTER:  # a router, or a star's relay: it accepts every link it has
        router = "router"
    elif cfg.topology == "router":
        router = "client"
    ros2 = None
    if cfg.ros2.enabled:
        from swarm.net.ros2.topics import ros2_keys

        ros2 = ros2_keys(cfg.ros2.domain_id, cfg.ros2.namespace, list(acc.agent_ids))
    rules = access.acl(
        acc.run,
        list(acc.agent_ids),
        flies_commands=acc.user == access.WORLD,
        identified=identified,
        router=router,
        ros2=ros2,
    )
    conf.insert_json5("access_control", json.dumps(rules))


def process_config(cfg: ScenarioConfig, role: Role, acc: Access | None = None) -> zenoh.Config:
    """:func:`links`, with the run's credentials when ``acc`` is given (``swarm run``
    always gives them unless ``network.access_control`` is off)."""
    conf = links(cfg, role)
    if acc is not None:
        ends = json.loads(conf.get_json("listen/endpoints"))
        listens = bool(ends) and isinstance(ends, list)
        _secure(conf, cfg, acc, listens)
    return conf


def links(cfg: ScenarioConfig, role: Role) -> zenoh.Config:
    """Config of one process from the scenario's network settings and its resolved
    topology (``ScenarioConfig.topology``; ``NetworkSettings.topology`` says what each is).

    mesh: the world listens on ``host:port``; every other process connects to it (and to
    ``network.connect``) and listens on a free port, and gossip links every pair.

    star: hub i of :func:`star_hubs` listens on ``port + i`` and connects to the hubs after
    it (``swarm run`` starts the bundle relay, then the launcher, the recorder and the
    world: each connects to listeners already up); agents and observers connect to every
    hub and listen on nothing. Gossip is off, so exactly these links exist, and they use the
    low-latency transport. No process forwards for another: each message takes the one
    link from its publisher to each subscriber (an agent's state to the relay, the relay's
    bundle to the agent, a command to the world and the recorder).

    router: the router (``swarm router``) listens on ``host:port``; every other process is
    a client connecting to it alone (low-latency transport on both ends).
    (That transport left Zenoh 1.10.2's gossip mesh incomplete in 3 of 4 starts of 17
    peers; links made only by explicit connects in one direction came up complete in 40 of
    40.)"""
    network = cfg.network
    proto = "tls" if network.tls.enabled else "tcp"
    if cfg.topology == "router":
        endpoint = world_endpoint(network.host, network.port, proto)
        if role is Role.ROUTER:
            return session_config(mode="router", listen=[endpoint], connect=list(network.connect), lowlatency=True)
        conf = session_config(mode="client", connect=[endpoint], lowlatency=True)
        if role is Role.LAUNCHER:
            _wait_for_first(conf, "client")  # (the others start once the router is up)
        return conf
    if cfg.topology == "star":
        hubs = star_hubs(cfg)
        ends = [world_endpoint(network.host, network.port + i, proto) for i in range(len(hubs))]
        if role in hubs:
            i = hubs.index(role)
            conf = session_config(listen=[ends[i]], connect=ends[i + 1 :], gossip=False, lowlatency=True)
            if role is Role.LAUNCHER and Role.ROUTER in hubs:
                _wait_for_first(conf, "peer")
            return conf
        return session_config(listen=[], connect=ends, gossip=False, lowlatency=True)
    endpoint = world_endpoint(network.host, network.port, proto)
    if role is Role.WORLD:
        return session_config(mode="peer", listen=[endpoint], connect=list(network.connect))
    own = [f"{proto}/{network.host}:0"]
    return session_config(mode=network.mode, listen=own, connect=[endpoint, *network.connect])


def _wait_for_first(conf: zenoh.Config, mode: str) -> None:
    """``swarm run``'s own session, opened while the router (or the star's relay) it has
    just started comes up: Zenoh retries its links for :data:`ROUTER_WAIT_S`, then the
    open fails."""
    conf.insert_json5("connect/timeout_ms", json.dumps({mode: int(ROUTER_WAIT_S * 1000)}))
    conf.insert_json5("connect/exit_on_failure", json.dumps({mode: True}))
    conf.insert_json5(
        "connect/retry", json.dumps({"period_init_ms": 50, "period_max_ms": 1000, "period_increase_factor": 2})
    )


@dataclass
class Counter:
    """Messages dropped per reason (and, where the sender is known, per sender and reason)."""

    dropped: int = 0
    reasons: dict[str, int] = field(default_factory=dict)
    rx_bytes: int = 0  # payload bytes of every sample decoded (kept or dropped)
    rx_messages: int = 0  # samples decoded (kept or dropped)
    by_sender: dict[str, dict[str, int]] = field(default_factory=dict)

    def drop(self, reason: str, sender: str | None = None) -> None:
        self.dropped += 1
        key = reason.split(":")[0][:40]
        self.reasons[key] = self.reasons.get(key, 0) + 1
        if sender is not None:
            per = self.by_sender.setdefault(sender, {})
            per[reason] = per.get(reason, 0) + 1


def rejected(*by_sender: dict[str, dict[str, int]]) -> dict[str, dict[str, int]]:
    """Counts of dropped messages per sender and reason, summed over several counts."""
    out: dict[str, dict[str, int]] = {}
    for counts in by_sender:
        for sender, reasons in counts.items():
            per = out.setdefault(sender, {})
            for reason, n in reasons.items():
                per[reason] = per.get(reason, 0) + n
    return out


def state_sender(key: str) -> str | None:
    """The agent whose state a key carries (``.../agent/<id>/state``, ``.../cell/i/j/k/<id>``), or None."""
    parts = key.split("/")
    if len(parts) >= 4 and parts[-3] == "agent" and parts[-1] == "state":
        return parts[-2]
    if len(parts) >= 6 and parts[-5] == "cell":
        return parts[-1]
    return None


def open_channel(session: zenoh.Session, key: str, capacity: int = 4096) -> Any:
    """A subscriber whose samples queue in a FIFO channel (no callback)."""
    return session.declare_subscriber(key, zenoh.handlers.FifoChannel(capacity))


def drain(sub: Any) -> Iterator[Any]:
    """Every sample queued on ``sub`` right now, without blocking."""
    while True:
        s = sub.try_recv()
        if s is None:
            return
        yield s


def wait_sample(sub: Any, deadline: float, poll_s: float = 0.002) -> Any | None:
    """The next sample of a channel subscriber, or None at the wall-clock ``deadline``.

    No thread: it polls ``try_recv``, so it is safe in any process, including ones that
    must exit normally (a thread blocked in ``recv()`` cannot be stopped, and is killed
    at interpreter exit). Agents and the world use :class:`Inbox` instead."""
    while True:
        s = sub.try_recv()
        if s is not None or time.monotonic() >= deadline:
            return s
        time.sleep(poll_s)


def payload(sample: Any) -> bytes:
    return bytes(sample.payload.to_bytes())


def decode_sample(
    sample: Any, run: str, counter: Counter, kinds: tuple[str, ...] | None = None, fields: tuple[str, ...] | None = None
) -> Message | None:
    """Decode a sample (its ``fields`` only, if given: :func:`swarm.net.messages.decode`) or
    drop and count it."""
    data = payload(sample)
    counter.rx_bytes += len(data)
    counter.rx_messages += 1
    try:
        return decode(data, run, kinds, fields)
    except DecodeError as exc:
        counter.drop(str(exc), state_sender(str(sample.key_expr)))
        return None


class Inbox:
    """Samples of one or more subscribers in one queue, waited on with a deadline and
    without polling.

    Zenoh's receive thread runs a callback that only enqueues each sample (no pump
    thread per key); :meth:`get` wakes as soon as any arrives, and
    :meth:`wait_for` only once a given number has (a lockstep world waiting for 16
    commands wakes once, not 16 times). A process with a callback subscriber can hang in
    ``session.close()`` or at interpreter exit, so processes that own an Inbox end with
    ``os._exit`` and never close the session."""

    def __init__(self, session: zenoh.Session, keys: str | list[str]) -> None:
        self._q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._held: list[Any] = []  # taken from the queue by a wait for one sample, drained first
        self._lock = threading.Lock()
        self._want = _NEVER  # wake wait_for when the queue holds this many samples (a wait for several)
        self._enough = threading.Event()
        # indirect=False: Zenoh's receive thread runs the callback itself, instead of handing
        # each sample to a Python thread of its own first (one thread wake-up less per sample)
        self._session = session
        self.subs: dict[str, Any] = {}
        for key in [keys] if isinstance(keys, str) else keys:
            self.add(key)

    def add(self, key: str) -> None:
        """Also queue the samples of ``key`` (a subscriber declared now)."""
        if key not in self.subs:
            on_sample = zenoh.handlers.Callback(self._on_sample, indirect=False)
            self.subs[key] = self._session.declare_subscriber(key, on_sample)

    def _on_sample(self, sample: Any) -> None:
        self._q.put(sample)
        if self._want != _NEVER:  # a wait for several samples: count them under the lock
            with self._lock:
                if self._q.qsize() >= self._want:
                    self._enough.set()

    def get(self, deadline: float) -> Any | None:
        """Next sample, or None at the wall-clock ``deadline`` (``time.monotonic``)."""
        if self._held:
            return self._held.pop(0)
        try:
            return self._q.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            return None

    def wait_for(self, count: int, deadline: float) -> None:
        """Block until at least ``count`` samples are queued, or the wall-clock
        ``deadline`` (``time.monotonic``); then :meth:`drain` them.

        A wait for one sample blocks in the queue itself (its C lock: the receive thread's
        callback is one ``put``, no Python event); a wait for several counts them in the
        callback and wakes once, when the last one is queued."""
        if count <= 1:
            if not self._held:
                s = self.get(deadline)
                if s is not None:
                    self._held.append(s)
            return
        with self._lock:
            # (``_want`` is set before the count is read: a sample queued in between is
            # either counted here or sees ``_want`` in the callback)
            self._want = count - len(self._held)
            self._enough.clear()
            if self._q.qsize() >= self._want:
                self._want = _NEVER
                return
        self._enough.wait(max(0.0, deadline - time.monotonic()))
        with self._lock:
            self._want = _NEVER

    def drain(self) -> Iterator[Any]:
        """Every sample queued right now, without blocking."""
        while self._held:
            yield self._held.pop(0)
        while True:
            try:
                yield self._q.get_nowait()
            except queue.Empty:
                return


_NEVER = 1 << 62


class Channels:
    """Subscribers whose samples queue in Zenoh's own FIFO channels (no Python runs per
    sample), added and removed as keys come and go, drained together by the caller once it
    is awake for another reason (an agent's cells, drained when its tick arrives)."""

    def __init__(self, session: zenoh.Session, capacity: int = 256) -> None:
        self._session, self._capacity = session, capacity
        self.subs: dict[str, Any] = {}

    def add(self, key: str) -> None:
        if key not in self.subs:
            self.subs[key] = open_channel(self._session, key, self._capacity)

    def remove(self, key: str) -> None:
        sub = self.subs.pop(key, None)
        if sub is not None:
            sub.undeclare()

    def drain(self) -> Iterator[Any]:
        """Every sample queued on any of the subscribers right now, without blocking."""
        for sub in self.subs.values():
            while (s := sub.try_recv()) is not None:
                yield s


def liveliness_change(sample: Any) -> tuple[str, bool]:
    """(name, alive) of one liveliness sample: a token declared, or gone."""
    return Keys.last(str(sample.key_expr)), sample.kind == zenoh.SampleKind.PUT


def liveliness_events(sub: Any) -> Iterator[tuple[str, bool]]:
    """(name, alive) for every queued liveliness change."""
    for s in drain(sub):
        yield liveliness_change(s)


SEND_DRAIN_S = 10.0
"""How long a process of a run waits, before it exits, for its peers to take what it sent
(:func:`exit_when_sent`): longer than a stall a lab meets (a busy laptop, a slow disk)."""


def unsent_bytes() -> dict[str, int]:
    """Bytes this process has written to each of its TCP connections that the peer's kernel
    has not yet acknowledged (Linux's ``SIOCOUTQ``), by peer address; connections with none
    left out. Empty where the platform cannot say."""
    out: dict[str, int] = {}
    try:
        fds = os.listdir("/proc/self/fd")
    except OSError:
        return out
    for name in fds:
        try:
            if not os.readlink(f"/proc/self/fd/{name}").startswith("socket:"):
                continue
            s = socket.socket(fileno=os.dup(int(name)))
        except OSError:
            continue
        try:
            if s.family not in (socket.AF_INET, socket.AF_INET6) or s.type != socket.SOCK_STREAM:
                continue
            left = struct.unpack("i", fcntl.ioctl(s.fileno(), termios.TIOCOUTQ, b"\0\0\0\0"))[0]
            if left > 0:
                host, port = s.getpeername()[:2]
                out[f"{host}:{port}"] = out.get(f"{host}:{port}", 0) + left
        except OSError:  # a listening socket, or one closed meanwhile
            continue
        finally:
            s.close()  # (the duplicate only)
    return out


def wait_sent(timeout_s: float = SEND_DRAIN_S, poll_s: float = 0.01, settle: int = 3) -> dict[str, int]:
    """Block until every TCP connection of this process has delivered what was written to
    it (nothing unacknowledged at ``settle`` polls in a row, ``poll_s`` apart: Zenoh's own
    transmit queue refills the socket within that), or ``timeout_s``; returns
    :func:`unsent_bytes` then (empty: all delivered)."""
    deadline = time.monotonic() + timeout_s
    quiet = 0
    while True:
        left = unsent_bytes()
        quiet = 0 if left else quiet + 1
        if quiet >= settle or time.monotonic() >= deadline:
            return left
        time.sleep(poll_s)


def exit_when_sent(code: int, who: str, timeout_s: float = SEND_DRAIN_S) -> NoReturn:
    """``os._exit(code)`` once the peers have taken everything this process sent (at most
    ``timeout_s``; what is left is named on stderr).

    A process that exits with bytes still queued for a peer that is behind (a stopped
    recorder's full receive window) leaves them to its kernel, which drops them all when
    anything arrives from that peer on the closed socket (a keep-alive): Linux resets the
    connection (``TcpExtTCPAbortOnData``), and the peer reads what it had, then
    "connection reset". That lost the end of a star's recording behind a recorder stopped
    for 1 s (the world's last 226 kB, 3 s of the run)."""
    left = wait_sent(timeout_s)
    if left:
        unread = f"{sum(left.values())} bytes still unread by {sorted(left)}"
        print(f"{who}: {unread} after {timeout_s:.0f} s, exiting anyway", file=sys.stderr)
    sys.stderr.flush()
    os._exit(code)


def declare_liveliness(session: zenoh.Session, key: str) -> Any:
    return session.liveliness().declare_token(key)


def liveliness_subscriber(session: zenoh.Session, key: str) -> Any:
    """Liveliness changes under ``key``, including tokens alive now (history)."""
    return session.liveliness().declare_subscriber(key, zenoh.handlers.FifoChannel(1024), history=True)


# Zenoh's runtimes (zenoh-runtime: app, acc, tx, rx, net; RON, read once per process at the
# first session) all handed over to one worker thread: a run puts many processes on few
# cores, where each extra thread a message crosses is one more wake-up
ZENOH_RUNTIME = (
    "(app: (worker_threads: 1), acc: (handover: app), tx: (handover: app), rx: (handover: app), net: (handover: app))"
)


def runtime_env() -> None:
    """Set ``ZENOH_RUNTIME`` to :data:`ZENOH_RUNTIME` unless the user set it (an empty value,
    which makes zenoh panic, counts as unset)."""
    if not os.environ.get("ZENOH_RUNTIME"):
        os.environ["ZENOH_RUNTIME"] = ZENOH_RUNTIME


def open_session(conf: zenoh.Config) -> zenoh.Session:
    """Open a session whose own threads (receive, transmit, timers) run under Linux's
    ``SCHED_BATCH`` policy: a Zenoh thread that wakes then waits for the running thread's
    time slice instead of preempting it. The calling thread keeps its policy.

    With more processes than cores, a transmit thread woken by each command would otherwise
    preempt its agent's main thread, costing context switches and the main thread's caches
    (the measurements: docs/benchmarks.md, "Figures behind the code's choices"). The threads
    inherit the policy from the thread that starts them; where it cannot be set the session
    opens as usual."""
    runtime_env()
    set_policy = getattr(os, "sched_setscheduler", None)
    if set_policy is None:
        return zenoh.open(conf)
    own = os.sched_getscheduler(0)
    try:
        set_policy(0, os.SCHED_BATCH, os.sched_param(0))
    except OSError:
        return zenoh.open(conf)
    try:
        return zenoh.open(conf)
    finally:
        set_policy(0, own, os.sched_param(0))
