"""The safety monitor every agent runs: each control tick it checks what the filter's margins
assume, and on a breach it acts in grades the config sets (docs/design.md, "The safety monitor").

The filter keeps a drone safe under assumptions that no barrier can check by itself: its own
estimate and its neighbours' are within the deviation the radii keep (``swarm.tuning``), their
states are young, the QP is feasible, the disturbance the estimator takes off the command is
inside its clip, and the world and the agent keep pace. :class:`SafetyMonitor` reads those
quantities (:class:`Readings`) each tick and returns a :class:`Verdict`: which checks breached
and the strongest action their grades ask for, held for a settling time once the breach is
gone so the drone does not chatter between grades. ``LAND`` is latched: a drone that lands
does not take off again. This is what the Crazyflie firmware's supervisor
(``crazyflie-firmware/src/modules/src/supervisor.c``: a lock after a tumble or a lost link)
and Crazyswarm2's warnings (``crazyflie/config/server.yaml``, ``warnings``) do for their part
of the loop.

Actions, weakest first (:class:`Action`): ``WARN`` only counts and reports, ``SLOW`` flies the
reference at a fraction of its speed, ``HOLD`` holds the drone where it is (a velocity of zero
under the filter), ``LAND`` lands it where it is. Every action still passes the safety filter.
No I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from typing import NamedTuple


class Action(IntEnum):
    """What the monitor asks of the step, weakest first."""

    NONE = 0
    WARN = 1
    SLOW = 2
    HOLD = 3
    LAND = 4


class Breach(IntFlag):
    """The checks, one bit each (the command message's ``breaches``)."""

    NONE = 0
    ESTIMATE_STD = 1  # own estimate's position deviation beyond the margin's envelope
    ESTIMATE_AGE = 2  # own estimate coasting without motion capture beyond the bound
    ESTIMATE_LOST = 4  # own estimate coasting past the longest gap it may fly through
    NEIGHBOUR_STD = 8  # a neighbour's deviation beyond the envelope
    NEIGHBOUR_AGE = 16  # a neighbour's state older than the bound
    INFEASIBLE = 32  # the filter has not had a clean solve for a while
    DISTURBANCE = 64  # the disturbance estimate at its clip for a while (thrust lost, a sagging battery)
    WORLD_LATE = 128  # the world's clock behind the wall clock (realtime)
    TICK_OVERRUN = 256  # the agent's own tick took longer than a tick


BREACH_NAMES: dict[Breach, str] = {
    Breach.ESTIMATE_STD: "estimate_std",
    Breach.ESTIMATE_AGE: "estimate_age",
    Breach.ESTIMATE_LOST: "estimate_lost",
    Breach.NEIGHBOUR_STD: "neighbour_std",
    Breach.NEIGHBOUR_AGE: "neighbour_age",
    Breach.INFEASIBLE: "infeasible",
    Breach.DISTURBANCE: "disturbance",
    Breach.WORLD_LATE: "world_late",
    Breach.TICK_OVERRUN: "tick_overrun",
}
"""Each check's name in configs, ``metrics.json`` and the status channel."""


@dataclass(frozen=True)
class MonitorParams:
    """The monitor's bounds and grades (``monitor:`` in a scenario, ``swarm.config``)."""

    enabled: bool = True
    std_envelope_m: float = math.inf
    """Position deviation [m] (the largest axis's standard deviation) an estimate may have: the
    deviation the filter's design margin was derived for (``swarm.tuning.design_std_m``); inf:
    no estimate to check."""
    neighbour_std_envelope_m: float | None = None
    """The position deviation [m] a neighbour's state may carry; None: ``std_envelope_m`` (a
    neighbour that publishes its state predicted for when its command acts carries the deviation
    of that prediction, ``swarm.tuning.monitor_params``)."""
    estimate_age_s: float = 0.15
    """Own estimate: seconds without a fused motion-capture frame before ``ESTIMATE_AGE``."""
    estimate_lost_s: float = 1.0
    """Own estimate: seconds without a fused frame before ``ESTIMATE_LOST`` (past the
    estimator's gate's ``gate_reset_s``, after which it takes any frame)."""
    neighbour_age_s: float = 0.1
    """A neighbour's state older than this [s] (``failure.neighbour_timeout_s``) breaches."""
    infeasible_s: float = 0.25
    """The filter without a clean solve for this long [s] breaches."""
    disturbance_s: float = 0.5
    """The disturbance estimate at its clip for this long [s] breaches."""
    world_late_s: float = 0.1
    """Realtime: the world's clock this far [s] behind the wall clock breaches."""
    slow_fraction: float = 0.5
    """``SLOW`` flies the reference at this fraction of its speed."""
    land_speed_mps: float = 0.3
    """``LAND``: the descent speed [m/s]."""
    settle_s: float = 0.5
    """An action holds this long [s] after its breach is gone."""
    grades: tuple[tuple[Breach, Action], ...] = (
        (Breach.ESTIMATE_STD, Action.SLOW),
        (Breach.ESTIMATE_AGE, Action.HOLD),
        (Breach.ESTIMATE_LOST, Action.LAND),
        (Breach.NEIGHBOUR_STD, Action.SLOW),
        (Breach.NEIGHBOUR_AGE, Action.SLOW),
        (Breach.INFEASIBLE, Action.WARN),
        (Breach.DISTURBANCE, Action.LAND),
        (Breach.WORLD_LATE, Action.HOLD),
        (Breach.TICK_OVERRUN, Action.WARN),
    )
    """The action of each check."""

    def grade(self, breach: Breach) -> Action:
        for b, a in self.grades:
            if b == breach:
                return a
        return Action.WARN


class Readings(NamedTuple):
    """What the monitor checks at one tick (0 or inf where the agent has no such reading)."""

    t_s: float  # s: the tick's sim time
    own_std_m: float = 0.0  # m: the own estimate's largest axis position standard deviation
    own_age_s: float = 0.0  # s: since the capture of the last frame the own estimate fused
    neighbour_std_m: float = 0.0  # m: the largest position deviation a neighbour in range carries
    neighbour_age_s: float = 0.0  # s: the oldest state of a neighbour in range
    clean_solve: bool = True  # the filter's last call was a clean solve
    disturbance_clipped: bool = False  # the disturbance taken off the command is at its clip
    world_late_s: float = 0.0  # s: how far the world's clock is behind the wall clock
    tick_overrun: bool = False  # the agent's previous tick took longer than a tick


class Verdict(NamedTuple):
    """The monitor's decision at one tick."""

    breaches: Breach  # the checks that breached at this tick
    action: Action  # what the step does now (held over ``settle_s``; LAND latched)

    @property
    def acting(self) -> bool:
        """The flight is changed (SLOW or stronger)."""
        return self.action >= Action.SLOW


CLEAR = Verdict(Breach.NONE, Action.NONE)


class SafetyMonitor:
    """One agent's monitor: :meth:`check` once per control tick. Keeps the running tallies the
    agent reports (ticks per breach, ticks per action)."""

    def __init__(self, p: MonitorParams) -> None:
        self.p = p
        self._since: dict[Breach, float] = {}  # a sustained condition: since when [s]
        self._until: dict[Action, float] = {}  # each action asked: held until [s, sim time]
        self.breach_ticks: dict[str, int] = {}  # per check's name: ticks it breached
        self.action_ticks: dict[str, int] = {}  # per action's name (slow, hold, land, warn): ticks it acted
        self.first_action_s: float | None = None  # sim time of the first SLOW or stronger

    def _sustained(self, breach: Breach, now: bool, t_s: float, hold_s: float) -> bool:
        if not now:
            self._since.pop(breach, None)
            return False
        since = self._since.setdefault(breach, t_s)
        return t_s - since >= hold_s - 1e-9

    def check(self, r: Readings) -> Verdict:
        """The verdict at ``r.t_s``: the breaches of this tick, and the action to take."""
        p = self.p
        if not p.enabled:
            return CLEAR
        b = Breach.NONE
        if r.own_std_m > p.std_envelope_m:
            b |= Breach.ESTIMATE_STD
        if r.own_age_s > p.estimate_lost_s:
            b |= Breach.ESTIMATE_LOST
        elif r.own_age_s > p.estimate_age_s:
            b |= Breach.ESTIMATE_AGE
        if r.neighbour_std_m > (p.std_envelope_m if p.neighbour_std_envelope_m is None else p.neighbour_std_envelope_m):
            b |= Breach.NEIGHBOUR_STD
        if r.neighbour_age_s > p.neighbour_age_s:
            b |= Breach.NEIGHBOUR_AGE
        if self._sustained(Breach.INFEASIBLE, not r.clean_solve, r.t_s, p.infeasible_s):
            b |= Breach.INFEASIBLE
        if self._sustained(Breach.DISTURBANCE, r.disturbance_clipped, r.t_s, p.disturbance_s):
            b |= Breach.DISTURBANCE
        if r.world_late_s > p.world_late_s:
            b |= Breach.WORLD_LATE
        if r.tick_overrun:
            b |= Breach.TICK_OVERRUN
        if not b and not self._until:  # (the common tick: nothing to count, nothing held)
            return CLEAR
        asked = Action.NONE
        for one in Breach:
            if one and one in b:
                name = BREACH_NAMES[one]
                self.breach_ticks[name] = self.breach_ticks.get(name, 0) + 1
                asked = max(asked, p.grade(one))
        if asked > Action.NONE:
            self._until[asked] = r.t_s + p.settle_s
        for a in [a for a, until in self._until.items() if until <= r.t_s and a is not asked]:
            del self._until[a]  # (expired)
        action = max(self._until, default=Action.NONE)
        if action is Action.LAND:
            self._until[Action.LAND] = math.inf  # latched
        if action > Action.NONE:
            name = action.name.lower()
            self.action_ticks[name] = self.action_ticks.get(name, 0) + 1
            if action >= Action.SLOW and self.first_action_s is None:
                self.first_action_s = r.t_s
        return Verdict(b, action)
