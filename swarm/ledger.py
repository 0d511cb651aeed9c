"""What a recording should hold and what it lacks: the recorder's ledger (pure, no I/O).

The recorder checks every stream it records for holes, as it records (``recorder.json``),
and ``swarm metrics`` checks the file again (``metrics.json``):

* the world's clock: one per tick, ticks 0, 1, 2, ... with no tick missing (but those a clock
  says the world flew unpublished before it: its ``skipped``), and at the end the status that
  says the run is done;
* each agent's commands: its sequence number advances by the same step for every command
  it sends (1, or 2 where it publishes its state before each command: ``neighbours.source:
  agents``), so a jump of more than one step is that many commands lost, between the ticks
  of the commands on either side;
* the real drones' motion-capture measurements: one sequence of their own, step 1.

What each sender says it sent (its summary line, :func:`summaries`, :func:`sent_counts`) closes the books: a
sender that sent more than the recording holds lost the rest after its last recorded
message (a tail), which no sequence number can show. Each hole is a :class:`Gap` with the
ticks it spans.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from ddsketch import DDSketch

from swarm.config import ScenarioConfig


@dataclass(frozen=True)
class Gap:
    """Messages of one stream the recording lacks."""

    stream: str  # "world/clock", "cf1/command", "world/measurement"
    from_k: int  # first tick without its message (inclusive)
    to_k: int | None  # last tick without it (inclusive); None: up to the end of the run
    messages: int  # how many are missing

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class _Stream:
    """One sender's stream of one kind: the newest message seen and the holes so far."""

    step: int  # how far the counter advances per message
    by_tick: bool  # counted by tick (the clock), else by sequence number
    last: int | None = None  # the newest counter value seen
    last_k: int = -1  # its tick
    seen: int = 0
    gaps: list[Gap] = field(default_factory=list)


class Ledger:
    """Streams of one run's recording; :meth:`see` each recorded message, then :meth:`gaps`."""

    def __init__(self, command_step: int) -> None:
        self.command_step = command_step
        self.streams: dict[str, _Stream] = {}
        self.done_k: int | None = None  # tick of the world's status that says the run is done

    @classmethod
    def of(cls, cfg: ScenarioConfig) -> Ledger:
        """The ledger of ``cfg``'s run: agents that publish their state step their sequence
        numbers by 2 per command."""
        return cls(2 if cfg.neighbours.source == "agents" else 1)

    def _stream(self, kind: str, src: str) -> _Stream | None:
        name = f"{src}/{kind}"
        s = self.streams.get(name)
        if s is None:
            if kind == "clock":
                s = _Stream(1, True, last=-1)  # the first clock is tick 0
            elif kind == "command":
                s = _Stream(self.command_step, False, last=0)  # an agent counts from 0: its first is one step on
            elif kind == "measurement":  # a real drone's, relayed from motion capture
                s = _Stream(1, False)
            else:
                return None
            self.streams[name] = s
        return s

    def see(self, kind: str, src: str, seq: int, k: int, done: bool = False, skipped: int = 0) -> None:
        """One recorded message: its kind, sender, sequence number and tick; ``done``: a
        status that says the run is over; ``skipped``: a clock's ticks before it that the world
        flew unpublished (none is missing)."""
        if kind == "status" and done:
            self.done_k = k
        s = self._stream(kind, src)
        if s is None:
            return
        n = k if s.by_tick else seq
        first = n - skipped  # (a clock stands for its skipped ticks too)
        s.seen += 1
        if s.last is not None and first > s.last + s.step:
            missing = (first - s.last) // s.step - 1
            s.gaps.append(Gap(f"{src}/{kind}", s.last_k + 1, max(s.last_k + 1, k - skipped - 1), missing))
        elif s.last is not None and n <= s.last:  # late: it fills part of a hole (not on one link)
            self._fill(s, n, k)
            return
        s.last, s.last_k = n, k

    @staticmethod
    def _fill(s: _Stream, n: int, k: int) -> None:
        for i, g in enumerate(s.gaps):
            if g.from_k <= k and (g.to_k is None or k <= g.to_k):
                s.gaps[i] = Gap(g.stream, g.from_k, g.to_k, g.messages - 1)
                if g.messages == 1:
                    del s.gaps[i]
                return

    def gaps(self, sent: dict[str, int] | None = None, last_k: int | None = None) -> list[Gap]:
        """Every hole seen and, given ``sent`` (stream name -> messages its sender says it
        sent, :func:`sent_counts`), the tails: what a sender sent after the last message of
        its stream the recording holds. ``last_k``: the run's last tick, where known (a
        world that died sent no more, and says nothing: no tail is made up for it)."""
        out = [g for s in self.streams.values() for g in s.gaps]
        for name, n_sent in (sent or {}).items():
            s = self.streams.get(name)
            seen = s.seen if s else 0
            held = seen + sum(g.messages for g in (s.gaps if s else []))
            if n_sent > held:
                from_k = s.last_k + 1 if s else 0
                if s.by_tick if s else name.endswith("/clock"):  # one per tick: the next ticks
                    to_k: int | None = from_k + n_sent - held - 1
                else:
                    to_k = last_k if last_k is not None and last_k >= from_k else None
                out.append(Gap(name, from_k, to_k, n_sent - held))
        return sorted(out, key=lambda g: (g.stream, g.from_k))

    def counts(self) -> dict[str, int]:
        """Messages recorded per stream."""
        return {name: s.seen for name, s in sorted(self.streams.items())}


SUMMARY_TAGS = ("WORLD_SUMMARY", "AGENT_SUMMARY", "ROUTER_SUMMARY")


def timing_sketch() -> DDSketch:
    """A sketch of a process's per-tick durations [s] for its summary line: percentiles within
    1 % (DataDog's DDSketch), in constant memory, where a list of every tick's duration would
    grow by 100 values a second for as long as the run lasts."""
    return DDSketch(relative_accuracy=0.01)


def summaries(logs: Path) -> dict[str, dict[str, Any]]:
    """The summary line each process of a run wrote last in its log (``logs/<process>.log``:
    ``WORLD_SUMMARY``, ``AGENT_SUMMARY``, ``ROUTER_SUMMARY``, then JSON), by process name.
    Processes without one (killed, or run elsewhere) are left out."""
    out: dict[str, dict[str, Any]] = {}
    for path in sorted(logs.glob("*.log")) if logs.is_dir() else ():
        try:
            text = path.read_text(errors="replace")
        except OSError:
            continue
        for line in text.splitlines():
            tag, _, body = line.partition(" ")
            if tag in SUMMARY_TAGS:
                try:
                    summary = json.loads(body)
                except ValueError:
                    continue
                if isinstance(summary, dict):
                    out[path.stem] = summary
    return out


def sent_counts(said: dict[str, dict[str, Any]]) -> dict[str, int]:
    """What each process says it sent (``said``: :func:`summaries`): the world's clocks
    (one per tick, 0 to its last, but the ticks it flew unpublished) and each agent's commands."""
    out: dict[str, int] = {}
    for name, summary in said.items():
        if name == "world" and isinstance(summary.get("ticks"), int):
            out["world/clock"] = summary["ticks"] + 1 - int(summary.get("skipped_ticks", 0))
        elif name.startswith("agent-") and isinstance(summary.get("ticks"), int):
            out[f"{summary.get('id', name.removeprefix('agent-'))}/command"] = summary["ticks"]
    return out
