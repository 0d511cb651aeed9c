"""Where an agent hears the other agents (docs/design.md, "Neighbours"): one class per
source, picked once when the agent starts (:func:`pick`), behind one small protocol
(:class:`NeighbourSource`). Each gives the agent's neighbour rows for a tick, with their
names, and in lockstep says how many messages that tick still waits for.

* :class:`RosterSource` (``neighbours.source: world``): the world's roster of measured body
  centres in every clock, as motion capture broadcasts all bodies (same-tick states).
* :class:`StateSource` (``interest: all``): every other agent's state on its own key.
* :class:`BundleSource` (``interest: bundle``): the relay's one bundle per tick of the states
  near the agent.
* :class:`CellSource` (``interest: cells``): the states published in the cells near it.

The last three hold a :class:`swarm.net.neighbours.NeighbourTable` and, in lockstep, use
exactly the states of tick k-1 (bundles and cells: of the neighbours the world names near
the agent with tick k). Taking states and building rows is pure (``fly_scenario`` feeds a
:class:`BundleSource` directly); :meth:`hear` decodes what the transport brings.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from swarm.errors import DecodeError
from swarm.net import statewire
from swarm.net import transport as tp
from swarm.net.cells import Interest, cell_of
from swarm.net.messages import Message
from swarm.net.neighbours import (
    HELD_TICKS,
    HeardNeighbours,
    HeldRecord,
    NearNeighbours,
    NeighbourTable,
    known_records,
    roster_arrays,
)
from swarm.realism.comms import CommsModel, MessageKind
from swarm.rotation import FloatArray
from swarm.safety.obstacles import NamedObstacles, ObstacleArrays

if TYPE_CHECKING:
    from swarm.config import ScenarioConfig


def _keep_newest(by_tick: dict, n: int) -> None:
    """Drop the oldest entries of a dict keyed by tick until ``n`` remain (they arrive in
    tick order over one link, so the first inserted is the oldest)."""
    while len(by_tick) > n:
        del by_tick[next(iter(by_tick))]


class NeighbourSource(Protocol):
    """What an agent process asks of its neighbour source."""

    publishes_state: bool
    """The agent publishes its own state for the others (every source but the roster)."""
    missed: int
    """Near neighbours whose state was not there when used (lockstep: at the deadline)."""

    @property
    def cells_declared(self) -> int:
        """Cell subscriptions declared so far (cells only)."""
        ...

    def subscriptions(self) -> list[str]:
        """The keys of the neighbours' traffic (added to the agent's inbox)."""
        ...

    def state_key(self, x_b_w: FloatArray) -> str | None:
        """The key the agent publishes its state on with its body centre at ``x_b_w`` [m, world]
        (None: it publishes none)."""
        ...

    def follow(self, subs: tp.Channels, x_b_w: FloatArray) -> None:
        """The agent's body centre is at ``x_b_w`` [m, world] (at its start, then each tick): the
        channels of neighbours' traffic that depend on where it is, in ``subs`` (cells only)."""
        ...

    def hear(self, key: str, sample: Any) -> bool:
        """Take a sample of the neighbours' traffic on ``key`` (dropped and counted when bad);
        False when ``key`` is not this source's."""
        ...

    def on_clock(self, m: Message) -> None:
        """The world's clock of tick ``m.k`` (live agents, the roster)."""
        ...

    def on_near(self, k: int, names: list[str]) -> None:
        """The live agents the world names near this agent with its tick ``k``."""
        ...

    def lost(self, name: str) -> None:
        """``name``'s liveliness is gone, or the world has seen it go."""
        ...

    def missing(self, k: int) -> int:
        """Lockstep: how many messages tick k still waits for (its clock or tick, then each
        neighbour's state of tick k-1)."""
        ...

    def rows(self, t_s: float, k: int, x_b_w: FloatArray, lockstep: bool) -> NamedObstacles:
        """The neighbour rows at sim time ``t_s`` [s] of tick ``k`` for the agent at ``x_b_w``
        [m, world] (lockstep: from exactly the states that tick uses)."""
        ...

    def wake(self, lockstep: bool, pending_k: int | None, acted_k: int) -> tuple[int, float | None]:
        """How many messages to wait for before waking (one wake for all that the oldest
        pending tick ``pending_k`` still needs, not one per message), and at most how long
        [s] (None: the caller's wake period)."""
        ...

    def late(self, k: int) -> None:
        """Lockstep: tick k is acted on at the deadline, incomplete (the neighbours it still
        waited for are not waited for again until they are heard)."""
        ...

    def at(self, t_s: float) -> None:
        """This agent has heard of sim time ``t_s`` [s] (a measurement): no neighbour's state
        may be much newer (``swarm.net.statewire.Plausible.ahead_s``)."""
        ...

    def warm_up(self) -> None:
        """Load the compiled code hearing neighbours calls, before the first tick (a throwaway
        table: nothing heard here stays)."""
        ...

    @property
    def rejected(self) -> dict[str, dict[str, int]]:
        """The neighbours' states dropped as implausible, repeated, out of order or ahead of
        the run, per sender and reason."""
        ...


class RosterSource:
    """``neighbours.source: world``: every other drone's body centre, velocity and radius as the
    world measured them at tick k, from the clock's roster (same-tick states, no acceleration).
    A drone the world lists as ``solo`` (not doing its share) is an obstacle row."""

    publishes_state = False
    missed = 0
    cells_declared = 0

    def __init__(self, others: set[str]) -> None:
        self.others = others
        self.live: dict[int, list[str]] = {}  # tick -> agents the world expects answers from
        self.roster: dict[int, tuple[float, ObstacleArrays]] = {}  # tick -> (t [s], rows)
        self.ids: list[str] = []  # the roster rows' names (the other drones, in the clock's order)
        self._key: tuple[str, ...] = ()  # the clock's ids the rows were indexed for
        self._rows = np.zeros(0, dtype=np.intp)  # indices of the other drones in the clock's ids
        self._shares = np.zeros(0, dtype=bool)  # each roster drone does its share (a neighbour row)

    def state_key(self, x_b_w: FloatArray) -> str | None:
        return None  # (the world measures every drone)

    def follow(self, subs: tp.Channels, x_b_w: FloatArray) -> None:
        pass

    def subscriptions(self) -> list[str]:
        return []

    def hear(self, key: str, sample: Any) -> bool:
        return False

    def on_clock(self, m: Message) -> None:
        self.live[m.k] = m["live"]
        ids = tuple(m["ids"])
        if ids != self._key:  # the roster's drones changed (rarely): index them again
            self._key = ids
            self._rows = np.array([i for i, name in enumerate(ids) if name in self.others], dtype=np.intp)
            self.ids = [ids[i] for i in self._rows.tolist()]
            self._shares = np.ones(len(self._rows), dtype=bool)
        shares = self._shares
        if m["solo"]:  # drones not doing their share: this agent takes all of each of those pairs
            shares = np.array([name not in m["solo"] for name in self.ids], dtype=bool)
        self.roster[m.k] = (m.t, roster_arrays(m["xvr"], self._rows, shares))
        _keep_newest(self.roster, HELD_TICKS)
        _keep_newest(self.live, HELD_TICKS)

    def on_near(self, k: int, names: list[str]) -> None:
        pass

    def lost(self, name: str) -> None:
        pass  # the world keeps measuring a dead agent's body

    def missing(self, k: int) -> int:
        return 1 if k not in self.live else 0  # the clock of tick k carries every neighbour's state

    def wake(self, lockstep: bool, pending_k: int | None, acted_k: int) -> tuple[int, float | None]:
        return 1, None

    def late(self, k: int) -> None:
        pass

    def at(self, t_s: float) -> None:
        pass

    def warm_up(self) -> None:
        pass  # (the roster's kernel: the agent's warm-up calls roster_arrays)

    @property
    def rejected(self) -> dict[str, dict[str, int]]:
        return {}  # (the world measured every row)

    def rows(self, t_s: float, k: int, x_b_w: FloatArray, lockstep: bool) -> NamedObstacles:
        """From the newest roster of tick <= k (lockstep) or the newest of all, extrapolated
        to ``t_s`` at constant velocity."""
        if not self.roster:
            return NamedObstacles.none()
        if lockstep:
            ks = [kk for kk in self.roster if kk <= k]
            if not ks:
                return NamedObstacles.none()
            t_r, arr = self.roster[max(ks)]
        else:
            t_r, arr = self.roster[next(reversed(self.roster))]  # the newest (inserted last)
        return NamedObstacles(arr.at(t_s - t_r), self.ids[: len(arr)])


class StateSource(HeardNeighbours):
    """``interest: all``: every other agent's state on its own key; in lockstep the states of
    tick k-1 of every agent the clock lists live."""

    publishes_state = True
    cells_declared = 0

    def __init__(self, agent_id: str, others: set[str], table: NeighbourTable, run: str, counter: tp.Counter,
                 keys: tp.Keys, comms: CommsModel | None = None) -> None:  # fmt: skip
        super().__init__(others, table, agent_id, comms)
        self.run, self.counter = run, counter
        self._keys = {keys.state(n): n for n in sorted(others)}
        self._own = keys.state(agent_id)

    def subscriptions(self) -> list[str]:
        return list(self._keys)

    def state_key(self, x_b_w: FloatArray) -> str | None:
        return self._own

    def follow(self, subs: tp.Channels, x_b_w: FloatArray) -> None:
        pass

    def hear(self, key: str, sample: Any) -> bool:
        name = self._keys.get(key)
        if name is None:
            return False
        m = tp.decode_sample(sample, self.run, self.counter)
        if m is None:
            return True
        if m.kind == "state" and m.src == name:
            self.take(m.src, m.t, m.k, m["x"], m["v"], m["r"], m["solo"], sd=m["sd"])
        else:
            self.counter.drop(f"unexpected {m.kind} on {key}")
        return True

    def on_clock(self, m: Message) -> None:
        self.on_list(m.k, m["live"])

    def on_near(self, k: int, names: list[str]) -> None:
        pass

    def wake(self, lockstep: bool, pending_k: int | None, acted_k: int) -> tuple[int, float | None]:
        return (max(1, self.missing(pending_k)) if lockstep and pending_k is not None else 1), None


class _NearSource(NearNeighbours):
    """Bundles and cells: the world names the live agents near this one with its own tick."""

    publishes_state = True
    cells_declared = 0

    def __init__(self, agent_id: str, others: set[str], table: NeighbourTable, run: str, counter: tp.Counter,
                 interest: Interest, comms: CommsModel | None = None) -> None:  # fmt: skip
        super().__init__(others, table, interest.radius_m + interest.hysteresis_m, agent_id, comms)
        self.run, self.counter, self.interest = run, counter, interest

    def on_clock(self, m: Message) -> None:
        pass  # (a real drone's clock: realtime, where the near lists are not waited on)

    def on_near(self, k: int, names: list[str]) -> None:
        self.on_list(k, names)


class BundleSource(_NearSource):
    """``interest: bundle``: one message per tick from the run's bundle relay with the states
    of the agents within this agent's interest radius, checked as one array
    (``swarm.net.statewire.check_states``), each bad record dropped and counted."""

    def __init__(self, agent_id: str, others: set[str], table: NeighbourTable, run: str, counter: tp.Counter,
                 interest: Interest, keys: tp.Keys, comms: CommsModel | None = None) -> None:  # fmt: skip
        super().__init__(agent_id, others, table, run, counter, interest, comms)
        self.key = keys.bundle(agent_id)
        self._own = keys.state(agent_id)  # (the relay bundles it for the others)
        self.bundle_k = -1  # the newest tick whose bundle arrived

    def subscriptions(self) -> list[str]:
        return [self.key]

    def state_key(self, x_b_w: FloatArray) -> str | None:
        return self._own

    def follow(self, subs: tp.Channels, x_b_w: FloatArray) -> None:
        pass

    def wake(self, lockstep: bool, pending_k: int | None, acted_k: int) -> tuple[int, float | None]:
        """One bundle brings every neighbour's state: in lockstep, wait for the next tick and
        the bundle of the tick before (the relay sends each agent one bundle per tick, so the
        two wake it once); in realtime, for whichever comes (it acts on the newest)."""
        if not lockstep or pending_k is not None:
            return 1, None
        k_next = acted_k + 1
        return (1 if k_next == 0 or self.bundle_k >= k_next - 1 else 2), None

    def warm_up(self) -> None:
        """As every source (:meth:`swarm.net.neighbours.HeardNeighbours.warm_up`), and read a
        bundle of two states into a throwaway table: its compiled checks load now. (Two: the
        fields of one record are contiguous arrays, a type of their own to numba.) The same
        bundle twice: the second is all copies, which the table's limits drop, and what is left
        of a bundle then is a copy of its records (writable, another type to numba). With a comms
        model, the same for the records it delivers a tick or more later, in runs of two and of
        one (:meth:`swarm.net.neighbours.HeardNeighbours.take_records`)."""
        super().warm_up()
        z, names = np.zeros(3), ["warm-up-1", "warm-up-2"]
        records = [statewire.encode_state("", n, 0, 0.0, 0, z, z, 0.0) for n in names]
        b = statewire.read_bundle(statewire.encode_bundle("", self.id, 0, 0.0, 0, records), "")
        table = self.table.blank()
        for _ in range(2):
            table.update_records(b.states.records, set(names), tp.Counter())
        if self.comms is not None:  # the fates of a bundle's states, and their records delivered later
            self.comms.fates(names, self.id, MessageKind.STATE, b.states.records["k"])
            heard = HeardNeighbours(set(names), self.table.blank(), self.id, self.comms)
            held = [HeldRecord(n, r) for n, r in zip(names, records, strict=True)]
            later = HeldRecord(names[0], statewire.encode_state("", names[0], 1, 0.01, 1, z, z, 0.0))
            for run in (held, [later], held):  # two, one, and two copies the limits drop
                heard.deliver(run)

    def hear(self, key: str, sample: Any) -> bool:
        if key != self.key:
            return False
        self.take_bundle(tp.payload(sample))
        return True

    def take_bundle(self, data: bytes) -> None:
        """A bundle's bytes: checked, each bad record (or one from an agent it does not know, or
        from itself) dropped and counted."""
        counter = self.counter
        counter.rx_bytes += len(data)
        counter.rx_messages += 1
        try:
            b = statewire.read_bundle(data, self.run)
        except DecodeError as exc:
            counter.drop(str(exc))
            return
        if b.dst != self.id:
            counter.drop("bundle: for another agent")
            return
        self.bundle_k = max(self.bundle_k, b.k)
        for reason, n in b.states.dropped.items():
            counter.dropped += n
            counter.reasons[reason] = counter.reasons.get(reason, 0) + n
        if self.comms is None:
            self.table.update_records(b.states.records, self.others, counter)
            return
        # (world.realism.comms: each state on its own way, through the relay)
        rec, names = known_records(b.states.records, self.others, counter)
        keep = [n for n, name in enumerate(names) if name not in self.table.gone]
        if keep:
            rec, names = (rec, names) if len(keep) == len(names) else (rec[keep], [names[n] for n in keep])
            self.take_records(rec, names, bundled=True)


class CellSource(_NearSource):
    """``interest: cells``: the agent publishes its state under the cell of its body centre and
    subscribes to the cells that meet its interest ball (``swarm.net.cells.Interest``), as
    Zenoh FIFO channels drained when its tick wakes it."""

    def __init__(self, agent_id: str, others: set[str], table: NeighbourTable, run: str, counter: tp.Counter,
                 interest: Interest, keys: tp.Keys, comms: CommsModel | None = None) -> None:  # fmt: skip
        super().__init__(agent_id, others, table, run, counter, interest, comms)
        self.keys = keys

    def subscriptions(self) -> list[str]:
        return []  # (the cells are channels of their own, followed as the agent moves)

    @property
    def cells_declared(self) -> int:  # type: ignore[override]
        return self.interest.declared

    def wake(self, lockstep: bool, pending_k: int | None, acted_k: int) -> tuple[int, float | None]:
        """The tick is here and states are still coming: look again in 1 ms."""
        return 1, (0.001 if pending_k is not None else None)

    def hear(self, key: str, sample: Any) -> bool:
        if not key.startswith(self.keys.cell_prefix):
            return False
        m = tp.decode_sample(sample, self.run, self.counter)
        if m is None:
            return True
        if m.kind == "state" and m.src == self.id:
            return True  # its own state, heard in its own cell
        if (
            m.kind == "state"
            and m.src in self.others
            and key == self.keys.cell_state(cell_of(m["x"], self.interest.cell_m), m.src)
        ):
            self.take(m.src, m.t, m.k, m["x"], m["v"], m["r"], m["solo"], sd=m["sd"])
        else:
            self.counter.drop(f"unexpected {m.kind} on {key}")
        return True

    def cell_of(self, x_b_w: FloatArray) -> tuple[int, int, int]:
        """The cell this agent publishes its state in, at body centre ``x_b_w`` [m, world]."""
        return cell_of(x_b_w.tolist(), self.interest.cell_m)

    def state_key(self, x_b_w: FloatArray) -> str | None:
        """The key of this agent's state in the cell of its body centre ``x_b_w`` [m, world]."""
        return self.keys.cell_state(self.cell_of(x_b_w), self.id)

    def follow(self, subs: tp.Channels, x_b_w: FloatArray) -> None:
        """Subscribe to the cells near the body centre ``x_b_w`` [m, world] and drop the ones
        left behind (nothing while within the hysteresis)."""
        add, drop = self.interest.update(x_b_w.tolist())
        for c in sorted(add):
            subs.add(self.keys.cell(c))
        for c in drop:
            subs.remove(self.keys.cell(c))


def pick(cfg: ScenarioConfig, agent_id: str, run: str, counter: tp.Counter, table: NeighbourTable) -> NeighbourSource:
    """The source ``agent_id`` of the scenario ``cfg`` (:class:`swarm.config.ScenarioConfig`)
    hears its neighbours from, chosen once by its ``neighbours`` settings, keeping them in
    ``table`` (``swarm.build.agent_neighbour_table``)."""
    others = {a.id for a in cfg.agents} - {agent_id}
    if cfg.neighbours.source == "world":
        return RosterSource(others)
    realism = cfg.world.realism
    keys = tp.Keys(run)
    interest = Interest(cfg.interest_radius_m(agent_id), cfg.cell_m, cfg.neighbours.hysteresis_m)
    comms = None if realism.comms.params().perfect else realism.comms_model(cfg.seed, 1.0 / cfg.time.control_hz)
    if cfg.uses_bundles:
        return BundleSource(agent_id, others, table, run, counter, interest, keys, comms)
    if cfg.uses_cells:
        return CellSource(agent_id, others, table, run, counter, interest, keys, comms)
    return StateSource(agent_id, others, table, run, counter, keys, comms)
