"""The recorder process: every message under ``swarm/<run>/**`` into ``run.mcap``.

    swarm record CONFIG --out DIR [--run RUN] [--port P] [--live PORT]

Messages are decoded (checked) and written as JSON, one MCAP channel per key expression
(less its ``swarm/<run>/`` prefix, so that a layout fits every run: ``/agent/cf1/command``),
each with its kind's JSON schema (``swarm.net.messages.json_schema``: every field with its
unit), so Foxglove lists and plots the fields by name; orjson writes them. Next to them go
the run's 3-D scene and its log (``swarm.runs.foxglove_scene``: ``/tf`` ``foxglove.FrameTransforms``,
``/scene`` ``foxglove.SceneUpdate``, ``/log`` ``foxglove.Log``, schemas from foxglove-sdk).
The log lines are the processes' own, read from ``DIR/logs`` as they are written (stamped
with the sim time at which the recorder read them). Undecodable messages are counted and
written raw to ``/dropped``. The file is flushed every ``FLUSH_S`` seconds: a crash loses
at most that much.

It never stops while a process of the run may still have something for it: it ends once
the world has reported done (or is gone), every agent's liveliness is gone (each sends its
last command before it goes, on the same link) and nothing has arrived for ``TAIL_S``; or
``tp.SEND_DRAIN_S`` after the world, if an agent hangs on. Every stream is checked for holes
as it is written (:class:`swarm.ledger.Ledger`); ``recorder.json`` lists them.

With ``live_port`` the same channels also go to Foxglove's WebSocket server
(foxglove-sdk's, on 127.0.0.1): Foxglove's "Open connection" shows the run as it goes.
The server lives in this process, which is pinned apart from the agents and the world.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import orjson
from mcap.writer import CompressionType, Writer

from swarm.ledger import Ledger
from swarm.net import transport as tp
from swarm.net.messages import DecodeError, decode, json_schema, record_of
from swarm.runs.foxglove_scene import SCHEMAS as SCENE_SCHEMAS
from swarm.runs.foxglove_scene import Scene
from swarm.shutdown import StopFlag

FLUSH_S = 0.5
BATCH_S = 0.02  # s: the recorder handles what arrived every BATCH_S
QUEUE = 1 << 16  # samples Zenoh holds for the recorder between batches (36 per batch at 16 agents)
TAIL_S = 0.3  # s: at the end, stop once nothing has arrived for this long


class Sinks:
    """``run.mcap`` (the mcap library's writer) and, optionally, Foxglove's live server:
    one channel per topic in each, registered on first use."""

    def __init__(self, f: Any, live_port: int | None = None) -> None:
        self.writer = Writer(f, compression=CompressionType.NONE, use_chunking=False)
        self.writer.start(profile="", library="c3swarm")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._live: dict[str, Any] = {}
        self.server = None
        if live_port is not None:
            import foxglove

            self.server = foxglove.start_server(host="127.0.0.1", port=live_port, name="c3swarm")

    def _schema(self, name: str, encoding: str, data: bytes) -> int:
        if name not in self._schemas:
            self._schemas[name] = self.writer.register_schema(name, encoding, data)
        return self._schemas[name]

    def channel(self, topic: str, encoding: str, schema: tuple[str, str, bytes]) -> int:
        """The MCAP channel id of ``topic`` (``schema`` = name, encoding, data)."""
        ch = self._channels.get(topic)
        if ch is None:
            ch = self._channels[topic] = self.writer.register_channel(topic, encoding, self._schema(*schema))
            if self.server is not None:
                import foxglove

                self._live[topic] = foxglove.Channel(
                    topic,
                    message_encoding=encoding,
                    schema=foxglove.Schema(name=schema[0], encoding=schema[1], data=schema[2]),
                )
        return ch

    def write(self, ch: int, topic: str, data: bytes, log_ns: int, now_ns: int, seq: int = 0) -> None:
        self.writer.add_message(ch, log_ns, data, now_ns, sequence=seq)
        live = self._live.get(topic)
        if live is not None:
            live.log(data, log_time=log_ns)

    def close(self) -> None:
        self.writer.finish()
        if self.server is not None:
            self.server.stop()


_RAW = ("c3swarm.raw", "jsonschema", json.dumps({"type": "object"}).encode())


class LogTail:
    """New lines of the run's process logs (``logs/<name>.log``), read as they grow."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._offset: dict[Path, int] = {}

    def lines(self) -> list[tuple[str, str]]:
        """(process name, line) of every complete line written since the last call."""
        out = []
        for path in sorted(self.folder.glob("*.log")) if self.folder.is_dir() else ():
            at = self._offset.get(path, 0)
            try:
                with open(path, "rb") as f:
                    f.seek(at)
                    chunk = f.read()
            except OSError:
                continue
            end = chunk.rfind(b"\n") + 1
            self._offset[path] = at + end
            out += [(path.stem, ln) for ln in chunk[:end].decode(errors="replace").splitlines() if ln.strip()]
        return out


class Recorder:
    """One recording: :meth:`handle` each sample, :meth:`tail_logs` now and then, :meth:`close`."""

    def __init__(self, run: str, out_dir: Path, live_port: int | None = None, ledger: Ledger | None = None) -> None:
        self.run = run
        self.ledger = ledger or Ledger(1)
        self._prefix = f"swarm/{run}/"
        self._by_key: dict[str, tuple[int, str]] = {}  # key expression -> (MCAP channel, topic)
        out_dir.mkdir(parents=True, exist_ok=True)
        self.f = open(out_dir / "run.mcap", "wb")  # closed in close()
        self.sinks = Sinks(self.f, live_port)
        self.scene = Scene()
        self.logs = LogTail(out_dir / "logs")
        self.counter = tp.Counter()
        self.count = 0
        self.sim_t = 0.0
        self.done = False  # the world's status said the run is over
        self.clocks = 0
        self.startup_cpu_s = 0.0  # CPU [s] spent before the first sample (imports, session)
        self._fg = {
            t: (c.get_schema().name, c.get_schema().encoding, c.get_schema().data) for t, c in SCENE_SCHEMAS.items()
        }
        for topic, schema in self._fg.items():  # before any client connects: a live client that
            self.sinks.channel(topic, "protobuf", schema)  # subscribes at once to a channel
            # advertised while the server registers it is refused ("unknown channel")

    def handle(self, key: str, data: bytes, now_ns: int) -> None:
        """Decode one sample and write it, and the scene messages it makes."""
        try:
            m = decode(data, self.run)
        except DecodeError as exc:
            self.counter.drop(str(exc))
            rec = {"key": key, "reason": str(exc), "hex": data[:256].hex()}
            ch = self.sinks.channel("/dropped", "json", _RAW)
            self.sinks.write(ch, "/dropped", json.dumps(rec).encode(), now_ns, now_ns)
            return
        known = self._by_key.get(key)
        if known is None:
            topic = "/" + key.removeprefix(self._prefix)  # /agent/cf1/command: the same in every run
            known = self._by_key[key] = (
                self.sinks.channel(topic, "json", (f"c3swarm.{m.kind}", "jsonschema", _schema_bytes(m.kind))),
                topic,
            )
        ch, topic = known
        log_ns = int(m.t * 1e9)
        rec = record_of(m)
        self.sinks.write(
            ch, topic, orjson.dumps(rec, option=orjson.OPT_SERIALIZE_NUMPY), log_ns, now_ns, m.seq & 0xFFFFFFFF
        )
        self.count += 1
        self.sim_t = max(self.sim_t, m.t)
        skipped = int(m["skipped"]) if m.kind == "clock" else 0
        self.ledger.see(m.kind, m.src, m.seq, m.k, m.kind == "status" and bool(m["done"]), skipped)
        if m.kind == "clock":
            self.clocks += 1
            self._scene(self.scene.on_clock(rec), log_ns, now_ns)
        elif m.kind == "collision":
            self._scene(self.scene.on_collision(rec), log_ns, now_ns)
        elif m.kind == "status" and m["done"]:
            self.done = True

    def _scene(self, messages: list[tuple[str, Any]], log_ns: int, now_ns: int) -> None:
        for topic, msg in messages:
            ch = self.sinks.channel(topic, "protobuf", self._fg[topic])
            self.sinks.write(ch, topic, msg.encode(), log_ns, now_ns)

    def tail_logs(self) -> None:
        """The processes' new log lines, stamped with the latest sim time seen."""
        now_ns = time.time_ns()
        for name, line in self.logs.lines():
            self._scene([Scene.log(self.sim_t, name, line)], int(self.sim_t * 1e9), now_ns)

    def flush(self) -> None:
        self.tail_logs()
        self.f.flush()

    def close(self, out_dir: Path) -> None:
        self.tail_logs()
        self.sinks.close()
        self.f.close()
        (out_dir / "recorder.json").write_text(
            json.dumps(
                {
                    "messages": self.count,
                    "dropped": self.counter.dropped,
                    "reasons": self.counter.reasons,
                    "clocks": self.clocks,
                    "streams": self.ledger.counts(),
                    "done_seen": self.ledger.done_k is not None,
                    "gaps": [g.as_dict() for g in self.ledger.gaps()],
                    "cpu_s": time.process_time(),
                    "startup_cpu_s": self.startup_cpu_s,
                }
            )
        )


_SCHEMA_BYTES: dict[str, bytes] = {}


def _schema_bytes(kind: str) -> bytes:
    if kind not in _SCHEMA_BYTES:
        _SCHEMA_BYTES[kind] = json.dumps(json_schema(kind)).encode()
    return _SCHEMA_BYTES[kind]


def main(
    run: str,
    out_dir: Path,
    conf,
    linger_s: float = 0.0,
    live_port: int | None = None,
    agent_ids: tuple[str, ...] = (),
    ledger: Ledger | None = None,
) -> int:
    """Record until the world has said done (and ``linger_s`` more: how long real drones
    may take to land after the end) or is gone, the agents ``agent_ids`` are gone and the
    links are quiet (see the module docstring)."""
    keys = tp.Keys(run)
    stop = StopFlag()
    rec = Recorder(run, out_dir, live_port, ledger)
    session = tp.open_session(conf)
    # channels, not callbacks: between batches Zenoh queues the samples itself, no Python
    # runs per message. Not the agents' states, their bundles or the world's tick messages:
    # the clock carries every drone's measured state and the obstacles already
    subs = [tp.open_channel(session, key, QUEUE) for key in keys.recorded]
    live_sub = tp.liveliness_subscriber(session, keys.all_alive)
    token = tp.declare_liveliness(session, keys.alive("recorder"))
    rec.startup_cpu_s = time.process_time()
    end = EndOfRun(set(agent_ids), linger_s)
    last_flush = time.monotonic()
    try:
        while not stop:
            # wake every BATCH_S, not for each message: a wake per command would take the
            # CPU from the agents just when they compute their next one
            time.sleep(BATCH_S)
            got = 0
            for sub in subs:
                for s in tp.drain(sub):
                    rec.handle(str(s.key_expr), tp.payload(s), time.time_ns())
                    got += 1
            now = time.monotonic()
            for name, up in tp.liveliness_events(live_sub):
                end.liveliness(name, up, now)
            if now - last_flush > FLUSH_S:
                rec.flush()
                last_flush = now
            if end.over(rec.done, got, now):
                break
    finally:
        rec.close(out_dir)
        token.undeclare()
    return 0


class EndOfRun:
    """When the recorder may stop (pure: fed liveliness changes, batch sizes and wall times
    [s, ``time.monotonic``])."""

    def __init__(self, agent_ids: set[str], linger_s: float) -> None:
        self.agents = agent_ids
        self.linger_s = linger_s
        self.live: set[str] = set()
        self.end_at: float | None = None  # the world said done (+ linger), or went
        self.quiet_since = math.inf  # wall time of the first empty batch since the last message

    def liveliness(self, name: str, up: bool, now: float) -> None:
        (self.live.add if up else self.live.discard)(name)
        if name == "world" and not up:
            self.end_at = min(self.end_at if self.end_at is not None else math.inf, now)

    def over(self, done: bool, got: int, now: float) -> bool:
        """After a batch of ``got`` messages: is the recording over?"""
        if done and self.end_at is None:
            self.end_at = now + self.linger_s
        self.quiet_since = math.inf if got else min(self.quiet_since, now)
        if self.end_at is None or now < self.end_at:
            return False
        waiting = bool(self.live & self.agents) and now - self.end_at < tp.SEND_DRAIN_S
        return not waiting and now - self.quiet_since >= TAIL_S
