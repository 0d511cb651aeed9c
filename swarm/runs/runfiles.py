"""Reading a run folder: ``run.mcap``, ``config.yaml``, ``metrics.json``."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from struct import error as struct_error
from typing import Any

from mcap.exceptions import McapError
from mcap.records import Channel, Footer, Message
from mcap.stream_reader import StreamReader

from swarm.config import ScenarioConfig, load
from swarm.errors import InputError
from swarm.ledger import summaries
from swarm.net.messages import expand_record
from swarm.offline.metrics import compute


@dataclass(frozen=True)
class Recording:
    """What a ``run.mcap`` holds, read in file order with mcap's stream reader, so a file
    cut short (a killed recorder, a full disk) gives every whole record before the cut."""

    records: list[dict[str, Any]]  # decoded messages with their ``topic`` (see read_records)
    complete: bool  # the file ends with its footer: the recorder finished it
    bytes_total: int  # size of the file [bytes]
    bytes_unread: int  # bytes after the last whole record (a record cut in two, or garbage)
    last_log_time_s: float | None  # sim time [s] of the last message read
    error: str | None  # why reading stopped before the footer, or None

    messages: int | None = None  # messages read (None: len(records))

    def describe(self) -> str:
        """One line: whole, or how much is missing."""
        n = len(self.records) if self.messages is None else self.messages
        if self.complete:
            return f"complete ({n} messages)"
        until = "no message" if self.last_log_time_s is None else f"messages up to t = {self.last_log_time_s:.3f} s"
        return (
            f"cut short: {n} messages recovered ({until}); the last {self.bytes_unread} of "
            f"{self.bytes_total} bytes are not a whole record and the summary is missing ({self.error})"
        )


class RecordingStream:
    """The whole messages of a ``run.mcap``, read once in file order as they are iterated
    (as :func:`read_recording` gives them), without holding them: for a recording too large
    for memory (an hour of flight). Once iterated to its end, :meth:`recording` says whether
    the file is whole (its ``records`` left empty)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.count = 0  # messages given so far (a clock's bundled measurements included)
        self._done: Recording | None = None

    def __iter__(self) -> Iterator[dict[str, Any]]:
        topics: dict[int, str] = {}
        total = self.path.stat().st_size
        good, last_ns, complete, error = 0, None, False, None
        with open(self.path, "rb") as f:
            # a length past the end of the file is a cut or garbage, not a record to allocate
            reader = StreamReader(f, record_size_limit=total)
            try:
                for record in reader.records:
                    if isinstance(record, Channel):
                        # the swarm's JSON messages; not the scene's protobuf channels (swarm.runs.foxglove_scene)
                        topics[record.id] = record.topic if record.message_encoding == "json" else "/dropped"
                    elif isinstance(record, Message) and topics.get(record.channel_id, "/dropped") != "/dropped":
                        rec = json.loads(record.data)
                        rec["topic"] = topics[record.channel_id]
                        for r in expand_record(rec):
                            self.count += 1
                            yield r
                        last_ns = record.log_time
                    elif isinstance(record, Footer):
                        complete = True
                    good = f.tell()
            except (McapError, EOFError, ValueError, struct_error) as exc:
                error = f"{type(exc).__name__}: {exc}"[:200]
        if complete:
            good = total
        last_s = None if last_ns is None else last_ns / 1e9
        self._done = Recording([], complete, total, total - good, last_s, error, self.count)

    def recording(self) -> Recording:
        """Whether the file is whole, and how much of it was read (after iterating to the end)."""
        if self._done is None:
            raise InputError(f"{self.path}: read the stream to its end first")
        return self._done


def read_recording(path: Path) -> Recording:
    """Every whole message of ``path``, and whether the file is whole.

    Each clock is followed by the measurements and obstacles it carries
    (:func:`expand_record`); ``/dropped`` (what the recorder could not decode) and the
    scene's channels (``/tf``, ``/scene``, ``/log``) are left out."""
    stream = RecordingStream(path)
    records = list(stream)
    done = stream.recording()
    return dataclasses.replace(done, records=records, messages=None)


def read_records(path: Path) -> list[dict[str, Any]]:
    """Every recorded message as a dict (with its ``topic``), in file order; a clock is
    followed by the measurements and obstacles it carries (:func:`expand_record`). A file
    cut short gives what it holds (:func:`read_recording` says how much is missing)."""
    return read_recording(path).records


def read_config(run_dir: Path) -> ScenarioConfig:
    return load(run_dir / "config.yaml")


def write_metrics(run_dir: Path, stop_reason: str | None = None, **extra: Any) -> dict[str, Any]:
    """Compute ``metrics.json`` of a run folder from what its ``run.mcap`` holds (a file
    cut short included) and write it. ``complete`` is true only when the file is whole, the
    world reported the end of the run and no stream has a hole (``recording_gaps``, also
    against what each process says in its log it sent); ``recording`` says how much is missing.
    ``stop_reason`` (default: the one an earlier ``metrics.json`` gives) and ``extra``
    are stored as they are."""
    cfg = read_config(run_dir)
    rec_info = run_dir / "recorder.json"
    dropped = json.loads(rec_info.read_text())["dropped"] if rec_info.exists() else 0
    path = run_dir / "run.mcap"
    stream = RecordingStream(path) if path.exists() else None
    old = run_dir / "metrics.json"
    if stop_reason is None and old.exists():
        try:
            stop_reason = json.loads(old.read_text()).get("stop_reason")
        except ValueError:
            stop_reason = None
    metrics = compute(cfg, stream if stream else [], dropped, summaries(run_dir / "logs"))
    rec = stream.recording() if stream else None
    whole = rec is not None and rec.complete and metrics["finished"] and not metrics["lost_messages"]
    metrics["complete"] = bool(whole)
    metrics["recording"] = (
        {"complete": False, "summary": "no run.mcap"}
        if rec is None
        else {
            "complete": rec.complete,
            "summary": rec.describe(),
            "bytes": rec.bytes_total,
            "bytes_unread": rec.bytes_unread,
            "recorded_until_s": rec.last_log_time_s,
        }
    )
    metrics["stop_reason"] = stop_reason
    metrics.update(extra)
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics
