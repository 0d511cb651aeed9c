"""Which states each agent's bundle carries, and when a tick's bundles are due
(``neighbours.interest: bundle``; the run's router sends them, :mod:`swarm.runs.router`).

Every agent publishes its own state on its own key. The router hears them all and, once
per control tick, sends each agent one message: the states of the other agents whose
body centres lie within that agent's interest radius of its own (the same radius the
cells cover, :meth:`swarm.config.ScenarioConfig.interest_radius_m`), each record as its
sender published it. An agent then wakes once per tick for its neighbours, not once per
neighbour.

When tick k is due:

* lockstep: once every live agent has published its state of tick k (each agent's
  bundle then holds exactly the states of tick k, which its tick k + 1 uses), or
  ``wait_s`` after the first of them arrived (a stalled agent does not hold the others up).
  When its state of that tick comes after all, that tick's bundles go again at once, with
  it (the others' tick k + 1 waits for it: else every agent would wait for a state held
  here until the next tick's bundles, which wait for their tick k + 1, a deadlock until
  each agent's own deadline);
* realtime: once every live agent has published a state since the last bundles, or
  ``wait_s`` after the first of those; each bundle holds the newest state of each.

An agent the bundles went out without (at the deadline) is not waited for again until a
state of it is taken: a stopped agent, or one whose every state the relay drops
(:class:`Intake`), costs the others one deadline, not one per tick.

No I/O here: :class:`Bundler` takes states and the live set, and says what to send.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarm.net.statewire import AHEAD, OUT_OF_ORDER, REPEATED, Plausible
from swarm.rotation import FloatArray


@dataclass
class _Held:
    """One agent's states by tick (lockstep keeps a few, realtime the newest)."""

    by_k: dict[int, tuple[FloatArray, bytes]]  # tick -> (body centre [m, world], record)
    fresh: bool = False  # published since the last bundles


class Bundler:
    """The bundles of one run's agents; see the module docstring."""

    HISTORY = 4  # ticks of states kept per agent (lockstep)

    def __init__(self, ids: list[str], interest_radius_m: list[float], lockstep: bool, wait_s: float) -> None:
        self.ids = list(ids)
        self.index = {a: i for i, a in enumerate(self.ids)}
        self.radius_m = np.asarray(interest_radius_m, float)  # (n,) m
        self.lockstep, self.wait_s = lockstep, wait_s
        self.held = {a: _Held({}) for a in self.ids}
        self.live: set[str] = set()
        self.late: set[str] = set()  # the bundles went out without them; not waited for until heard
        self.skipped: set[str] = set()  # lockstep: the last bundles went out without their state of that tick
        self.again = False  # lockstep: the last bundles are due again (a skipped state came)
        self.next_k = 0  # lockstep: the tick whose bundles are due next
        self.first_s: float | None = None  # wall time [s] the first state the next bundles wait for arrived
        self.sent_k = -1  # the newest tick bundled

    def set_live(self, agent_id: str, alive: bool) -> None:
        if agent_id in self.index:
            (self.live.add if alive else self.live.discard)(agent_id)

    def add(self, agent_id: str, k: int, x_w: FloatArray, record: bytes, now_s: float) -> None:
        """A state of tick ``k`` of ``agent_id`` (body centre ``x_w`` [m, world]) arrived at
        wall time ``now_s`` [s]; stale ticks (already bundled in lockstep) are kept too:
        a late neighbour's state is better than none."""
        held = self.held[agent_id]
        self.late.discard(agent_id)
        held.by_k[k] = (x_w, record)
        if len(held.by_k) > self.HISTORY:
            del held.by_k[min(held.by_k)]
        if self.lockstep and k < self.next_k:
            if k == self.sent_k and agent_id in self.skipped:
                self.skipped.discard(agent_id)
                self.again = True
            return
        held.fresh = True
        if self.first_s is None:
            self.first_s = now_s

    def waiting_for(self) -> int:
        """How many live agents the next bundles still wait for."""
        return len(self._missing())

    def _missing(self) -> list[str]:
        """The live agents (not late) the next bundles wait for."""
        if self.lockstep:
            return [a for a in self.live - self.late if max(self.held[a].by_k, default=-1) < self.next_k]
        return [a for a in self.live - self.late if not self.held[a].fresh]

    def due(self, now_s: float) -> bool:
        """Are the next bundles due at wall time ``now_s`` [s]?"""
        if self.again:
            return True
        if self.first_s is None:
            return False
        return self.waiting_for() == 0 or now_s - self.first_s >= self.wait_s

    def deadline_s(self) -> float | None:
        """Wall time [s] by which the next bundles are due whatever else arrives."""
        return None if self.first_s is None else self.first_s + self.wait_s

    def take(self, now_s: float) -> tuple[int, list[tuple[str, list[bytes]]]]:
        """The tick of the due bundles and, per agent that has a state, the records of the
        others within its interest radius (in the order of ``ids``); marks them sent at
        wall time ``now_s`` [s]. Lockstep: the last tick's bundles again when a state they
        went without has come since (nothing else changes)."""
        if self.again:
            self.again = False
            return self.sent_k, self._bundles(self.sent_k)
        k = self.next_k if self.lockstep else max(max(h.by_k) for h in self.held.values() if h.fresh)
        missing = self._missing()  # (due at the deadline: these did not come)
        self.late.update(missing)
        self.skipped = set(missing) if self.lockstep else set()
        out = self._bundles(k)
        for h in self.held.values():
            h.fresh = False
        self.sent_k = max(self.sent_k, k)
        if self.lockstep:
            self.next_k = k + 1
            pending = [h for h in self.held.values() if max(h.by_k, default=-1) >= self.next_k]
            for h in pending:
                h.fresh = True
            self.first_s = now_s if pending else None  # (states of the next tick already here)
        else:
            self.first_s = None
        return k, out

    def _bundles(self, k: int) -> list[tuple[str, list[bytes]]]:
        """Per agent that has a state for tick ``k``, the records of the others within its
        interest radius (in the order of ``ids``)."""
        names, xs, records = [], [], []
        for a in self.ids:
            got = self._state(a, k)
            if got is not None:
                names.append(a)
                xs.append(got[0])
                records.append(got[1])
        out: list[tuple[str, list[bytes]]] = []
        if names:
            x = np.asarray(xs)  # (m, 3) m, world
            d2 = ((x[:, None, :] - x[None, :, :]) ** 2).sum(axis=2)  # (m, m) m^2
            r = self.radius_m[[self.index[a] for a in names]]
            near = d2 <= (r * r)[:, None]
            np.fill_diagonal(near, False)
            for i, a in enumerate(names):
                out.append((a, [records[j] for j in np.flatnonzero(near[i]).tolist()]))
        return out

    def _state(self, agent_id: str, k: int) -> tuple[FloatArray, bytes] | None:
        """``agent_id``'s state for the bundles of tick ``k``: lockstep, its newest of tick
        <= k; realtime, its newest."""
        by_k = self.held[agent_id].by_k
        ks = [kk for kk in by_k if kk <= k] if self.lockstep else list(by_k)
        return by_k[max(ks)] if ks else None


class Intake:
    """Which of the states the relay hears it takes, per sender (no I/O): each must be
    plausible (:class:`swarm.net.statewire.Plausible`), newer in sim time than the last one
    taken from its sender (one per tick: a repeat or an older one is dropped; one link per
    agent reaches the relay, in order), and no more
    than ``ahead_s`` [s] ahead of the run (the newest time the world has reported,
    :meth:`run_at`). That is the relay's rate limit per sender, in the run's own time: a
    flood of one tick's state keeps one; a limit in wall time would drop an honest agent's
    backlog after any stall, and lockstep runs faster than real time. Everything else is
    dropped and counted against its sender (:attr:`rejected`)."""

    def __init__(self, limits: Plausible | None, ahead_s: float) -> None:
        self.limits, self.ahead_s = limits, ahead_s
        self.last_t: dict[str, float] = {}  # sender -> sim time [s] of its newest state taken
        self.run_t = -math.inf  # the newest sim time [s] the world has reported
        self.rejected: dict[str, dict[str, int]] = {}  # sender -> reason -> states dropped

    def run_at(self, t_s: float) -> None:
        self.run_t = max(self.run_t, t_s)

    def early(self, sender: str, t_s: float) -> str | None:
        """The checks on the time alone (before a record is read whole): why a state of sim
        time ``t_s`` [s] from ``sender`` is not taken, or None."""
        last = self.last_t.get(sender, -math.inf)
        if t_s == last:
            return REPEATED
        if t_s < last:
            return OUT_OF_ORDER
        if math.isfinite(self.run_t) and t_s > self.run_t + self.ahead_s:
            return AHEAD
        return None

    def admit(self, sender: str, t_s: float, x_w: tuple[float, ...], v_w: tuple[float, ...], r_m: float) -> bool:
        """Take a well-formed state of ``sender`` (sim time ``t_s`` [s], body centre ``x_w``
        [m, world], velocity ``v_w`` [m/s], radius ``r_m`` [m]), or count why not."""
        why = self.early(sender, t_s) or (self.limits.reason(x_w, v_w, r_m) if self.limits else None)
        if why is not None:
            self.reject(sender, why)
            return False
        self.last_t[sender] = t_s
        return True

    def reject(self, sender: str, reason: str) -> None:
        per = self.rejected.setdefault(sender, {})
        per[reason] = per.get(reason, 0) + 1
