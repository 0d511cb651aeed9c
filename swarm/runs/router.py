"""The router process of ``network.topology: router``: a Zenoh router session, and with
``neighbours.interest: bundle`` the bundles of the agents' states.

    swarm router CONFIG [--run RUN] [--port P] [--secrets DIR]

Every other process of the run is a Zenoh client linked to this router alone; the router
forwards each message to the sessions whose subscriptions match its key (Zenoh's own key
matching), and its access-control rules accept from each client only that client's own
keys (``swarm.net.access.acl`` with ``router="router"``). It declares the liveliness token
``alive/router`` and runs until SIGTERM or SIGINT.

With ``neighbours.interest: bundle`` it also hears every agent's state (each on that
agent's own key, which only that agent may publish) and sends each agent, once per tick,
one bundle of the states within its interest radius (:mod:`swarm.net.bundle`), under
``router/bundle/<id>``, a key no client may publish. It takes from each agent only
plausible states, one per tick and in order (:class:`swarm.net.bundle.Intake`), and says
at the end, in its ``ROUTER_SUMMARY`` line, what it dropped from whom.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import numpy as np

from swarm.config import ScenarioConfig, TimeMode
from swarm.errors import DecodeError
from swarm.net import statewire
from swarm.net import transport as tp
from swarm.net.bundle import Bundler, Intake
from swarm.shutdown import StopFlag


class BundleRelay:
    """The router's bundles: phases :meth:`listen` (states and liveliness in) and
    :meth:`send` (the due bundles out)."""

    def __init__(self, cfg: ScenarioConfig, run: str, session: Any) -> None:
        self.run, self.keys = run, tp.Keys(run)
        ids = [a.id for a in cfg.agents]
        lockstep = cfg.time.mode is TimeMode.LOCKSTEP
        # how long the bundles of a tick wait for a late agent: half a control period in
        # realtime; in lockstep the share of the world's timeout after which a tick is a stall
        wait_s = cfg.time.stall_warn_fraction * cfg.time.lockstep_timeout_s if lockstep else 0.5 / cfg.time.control_hz
        self.bundler = Bundler(ids, [cfg.interest_radius_m(a) for a in ids], lockstep, wait_s)
        # the world's status (10 Hz) says how far the run is; a state may be a second ahead of it
        self.intake = Intake(statewire.Plausible.of(cfg), 1.1)
        self.state_keys = {self.keys.state(a): a for a in ids}
        self.status = tp.open_channel(session, self.keys.status, 1024)
        self.inbox = tp.Inbox(session, self.keys.all_states)
        self.live_sub = tp.liveliness_subscriber(session, self.keys.all_alive)
        self.pubs = {a: session.declare_publisher(self.keys.bundle(a)) for a in ids}
        self.counter = tp.Counter()
        self.seq = 0
        self.sent = 0

    def listen(self, wake_s: float) -> None:
        """Wait until the next bundles can be due (every awaited state here, their deadline,
        or ``wake_s``), then take the states and liveliness changes."""
        b = self.bundler
        now = time.monotonic()
        deadline = min(b.deadline_s() or now + wake_s, now + wake_s)
        self.inbox.wait_for(max(1, b.waiting_for()), deadline)
        for s in tp.drain(self.status):  # first: how far the run is, for the states that came with it
            m = tp.decode_sample(s, self.run, self.counter, ("status",), ("done",))
            if m is not None:
                self.intake.run_at(m.t)
        for s in self.inbox.drain():
            self._take(s)
        for name, up in tp.liveliness_events(self.live_sub):
            b.set_live(name, up)

    def _take(self, sample: Any) -> None:
        self.take(str(sample.key_expr), tp.payload(sample))

    def take(self, key: str, data: bytes) -> None:
        """One state message's bytes, as heard on ``key``: checked, and taken or dropped and
        counted."""
        self.counter.rx_bytes += len(data)
        sender = self.state_keys.get(key)
        if sender is None:
            self.counter.drop("state: on no agent's key")
            return
        t = statewire.record_time(data) if len(data) == statewire.STATE.itemsize else None
        early = None if t is None else self.intake.early(sender, t)
        if early is not None:  # (a flood's repeats: no more work)
            self._drop(sender, early)
            return
        try:
            f = statewire.read_state(data, self.run)
        except DecodeError as exc:
            self._drop(sender, str(exc))
            return
        if f[16].rstrip(b"\0").decode() != sender:  # (only the agent may publish on its key)
            self._drop(sender, "state: sender is not its key's agent")
            return
        if not self.intake.admit(sender, f[6], f[7:10], f[10:13], f[13]):
            self.counter.drop("state: implausible")
            return
        self.bundler.add(sender, f[5], np.array(f[7:10]), data, time.monotonic())

    def _drop(self, sender: str, reason: str) -> None:
        self.counter.drop(reason)
        self.intake.reject(sender, reason)

    def send(self) -> None:
        """Every bundle that is due now."""
        b = self.bundler
        while b.due(time.monotonic()):
            k, bundles = b.take(time.monotonic())
            for dst, records in bundles:
                self.seq += 1
                t = statewire.record_time(records[0]) if records else 0.0
                self.pubs[dst].put(statewire.encode_bundle(self.run, dst, self.seq, t, k, records))
                self.sent += 1


def main(run: str, conf: Any, cfg: ScenarioConfig | None = None) -> int:
    """Route the run's traffic until stopped (and bundle its states, if ``cfg`` asks)."""
    stop = StopFlag()
    try:
        session = tp.open_session(conf)
    except Exception as exc:  # zenoh raises its own ZError when the port cannot be listened on
        print(f"router: cannot start: {exc}", file=sys.stderr)
        return 2
    relay = BundleRelay(cfg, run, session) if cfg is not None and cfg.uses_bundles else None
    token = tp.declare_liveliness(session, tp.Keys(run).alive("router"))
    print("router: listening" + (" and bundling the agents' states" if relay else ""), file=sys.stderr, flush=True)
    startup_cpu_s = time.process_time()  # s: the process's CPU, all threads, until it listened
    while not stop:
        if relay is None:
            time.sleep(0.1)  # nothing to do: Zenoh's own threads route; this only waits for a signal
            continue
        relay.listen(0.1)
        relay.send()
    token.undeclare()
    if relay is not None:
        c = relay.counter
        print(f"router: sent {relay.sent} bundles; dropped {c.dropped} {c.reasons}", file=sys.stderr)
        summary = {
            "bundles": relay.sent, "dropped": c.dropped, "rejected": relay.intake.rejected,
            "cpu_s": time.process_time(), "startup_cpu_s": startup_cpu_s,
        }  # fmt: skip
        print("ROUTER_SUMMARY " + json.dumps(summary), file=sys.stderr)
    return 0
