"""The safety-filter protocol a plugin implements, and its containment in the agent's step
(docs/plugins.md; docs/design.md, "Plugins").

A safety filter is a class registered under the entry-point group ``c3swarm.filters``
(``swarm.plugins``). The agent builds it once from a :class:`FilterSpec` (its airframe, command
level, input limits, margins and validated options) and calls :meth:`SafetyMethod.filter` once per
control tick with a :class:`FilterInput` (its own estimate, the reference command, the obstacles'
and neighbours' rows with their ages and uncertainty); it returns a :class:`FilterOutput` (the
command and a :class:`~swarm.safety.filter.FilterStatus`).

:class:`ContainedFilter` calls it: a call that raises, returns a command that is not finite, not
of the level's shape or outside the level's input set, says ``FAILED``, or takes longer than its
budget, is replaced by the built-in safe command (the C3BF-QP on the same rows, else brake and
hold) and counted by reason (:class:`Fallback`). The plugin runs in the agent's process and is
trusted code; it is handed only what :class:`FilterSpec` and :class:`FilterInput` name (no Zenoh
session, no keys, no credentials).

The built-in barriers are registered the same way (:class:`C3BF`, :class:`HOCBF`): their
``barrier`` attribute tells the agent's step to run that barrier in its own QP workspace, which
is also every plugin's fallback.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, ClassVar, NamedTuple, Protocol, runtime_checkable

import numpy as np
from pydantic import BaseModel

from swarm.model import CommandLevel, LinearInputSet, QuadModel, QuadParams, QuadState, all_finite
from swarm.rotation import FloatArray
from swarm.safety.barriers import BarrierKind
from swarm.safety.filter import FilterConfig, FilterResult, FilterStatus, SafetyFilter
from swarm.safety.obstacles import NamedObstacles, ObstacleArrays

LIMIT_TOL = 1e-6
"""The largest violation of the input set [input units: N] a plugin's command may have (a QP
solver's tolerance); more is a fallback (``out_of_limits``)."""


class Fallback(StrEnum):
    """Why a plugin's command was replaced by the built-in safe command at a tick."""

    RAISED = "raised"  # the call raised an exception
    NON_FINITE = "non_finite"  # the command has a NaN or an infinity, or is not of the level's shape
    OUT_OF_LIMITS = "out_of_limits"  # the command is outside the level's input set (by more than LIMIT_TOL)
    OVERRUN = "overrun"  # the call took longer than its budget (wall time)
    FAILED = "failed"  # the plugin said it has no usable command (FilterStatus.FAILED)


FALLBACK_NAMES: tuple[str, ...] = tuple(f.value for f in Fallback)


@dataclass(frozen=True)
class FilterSpec:
    """What a safety filter is built with, once per agent."""

    agent_id: str
    params: QuadParams  # the airframe: mass_kg, g_mps2, body_radius_m, f_max_N, max_tilt_rad, keep_out_*_m ...
    level: CommandLevel  # the command it filters: "attitude" F (3,) [N, world]; "rotors" f (4,) [N]
    # the level's input set: lb <= u <= ub and C u <= d [N]; at the attitude level with the swarm's agreed
    # acceleration where its delay contract binds (FilterConfig.accel_limit_mps2), as the C3BF-QP keeps it
    limits: LinearInputSet
    margin_m: float  # m: extra radius every row keeps (filter.margin_m)
    sensing_radius_m: float  # m: neighbours farther away are not given (filter.sensing_radius_m)
    control_period_s: float  # s: one control tick
    options: BaseModel | None  # the plugin's validated options (its ``Options`` model), or None


class Rows(NamedTuple):
    """The rows of one kind (obstacles, or neighbours) at the tick, in a frozen copy.

    Every radius is the row's own; the filter keeps ``radius_m + spec.params.body_radius_m +
    spec.margin_m`` (a neighbour is another drone: ``radius_m`` is its bounding radius)."""

    ids: tuple[str, ...]  # (n,) the obstacle's or the neighbour agent's name
    c_w: FloatArray  # (n, 3) m, world: centre (a point on the axis of a cylinder; a drone's body centre)
    v_w: FloatArray  # (n, 3) m/s, world: its velocity
    a_w: FloatArray  # (n, 3) m/s^2, world: its acceleration (0 for a drone)
    radius_m: FloatArray  # (n,) m: its radius, widened by the live noise margin where the agent keeps one
    axis_w: FloatArray  # (n, 3) unit axis of a cylinder, zeros for a sphere or a drone
    age_s: FloatArray  # (n,) s: age of the state the row is predicted from (0: measured or fixed)
    sd_m: FloatArray  # (n,) m: the position deviation that state carries (its uncertainty; 0: exact)

    @staticmethod
    def of(arrays: ObstacleArrays, named: NamedObstacles) -> Rows:
        """A frozen copy of ``arrays`` (the rows as the filter uses them) named by ``named``."""
        n = len(arrays)

        def col(a: FloatArray | None) -> FloatArray:
            out = np.zeros(n) if a is None or len(a) != n else np.array(a, dtype=float)
            out.flags.writeable = False
            return out

        def frozen(a: FloatArray) -> FloatArray:
            out = np.array(a, dtype=float)
            out.flags.writeable = False
            return out

        return Rows(
            tuple(named.ids),
            frozen(arrays.c_w),
            frozen(arrays.c_dot_w),
            frozen(arrays.c_ddot_w),
            frozen(arrays.radius_m),
            frozen(arrays.axis_w),
            col(named.age_s),
            col(named.sd_m),
        )


@dataclass(frozen=True)
class FilterInput:
    """What a safety filter is given at one control tick."""

    t_s: float  # s: the tick's simulated time
    state: QuadState  # its own estimate (a copy): x_w [m], v_w [m/s], q (x, y, z, w), Omega_b [rad/s], world
    x_b_w: FloatArray  # (3,) m, world: its body centre (the point the rows are kept from)
    v_b_w: FloatArray  # (3,) m/s, world: its velocity
    sd_m: float  # m: the position deviation of its own estimate (0: exact)
    u_ref: FloatArray  # (m,) the reference command of the level (spec.level) to filter
    obstacles: Rows  # the scene's obstacles at the tick (walls, spheres, moving obstacles)
    neighbours: Rows  # the other drones within the sensing radius, predicted to the tick
    goal_w: FloatArray  # (3,) m, world: its goal


class FilterOutput(NamedTuple):
    """What a safety filter returns: the command to fly and its status."""

    u: FloatArray  # (m,) the command of the level: F (3,) [N, world] or f (4,) [N]
    status: FilterStatus = FilterStatus.OK  # OK; INFEASIBLE (flown, counted); FAILED (not flown: the fallback is)


@runtime_checkable
class SafetyMethod(Protocol):
    """A safety filter plugin: built from a :class:`FilterSpec`, called every tick.

    Class attributes it may set: ``Options`` (a pydantic model of its ``filter.options``; none:
    it takes no options) and ``levels`` (the command levels it filters; default attitude only)."""

    def __init__(self, spec: FilterSpec) -> None: ...

    def filter(self, inp: FilterInput) -> FilterOutput: ...


def levels_of(cls: type) -> tuple[CommandLevel, ...]:
    """The command levels a filter class says it filters (``levels``; default the attitude level)."""
    raw = getattr(cls, "levels", (CommandLevel.ATTITUDE,))
    return tuple(CommandLevel(v) for v in raw)


def options_of(cls: type) -> type[BaseModel] | None:
    """A plugin class's options model (``Options``), or None."""
    opt = getattr(cls, "Options", None)
    return opt if isinstance(opt, type) and issubclass(opt, BaseModel) else None


class _Barrier:
    """A built-in barrier as a plugin: the C3BF-QP (``swarm.safety.filter``) with the given
    barrier. Its settings are the ``filter:`` section's own fields, so it takes no options."""

    barrier: ClassVar[BarrierKind]
    levels: ClassVar[tuple[CommandLevel, ...]] = (CommandLevel.ATTITUDE, CommandLevel.ROTORS)

    def __init__(self, spec: FilterSpec, config: FilterConfig | None = None) -> None:
        cfg = config or FilterConfig(
            level=spec.level, kind=self.barrier, margin_m=spec.margin_m, sensing_radius_m=spec.sensing_radius_m
        )
        self._filter = SafetyFilter(QuadModel(spec.params), cfg)

    def filter(self, inp: FilterInput) -> FilterOutput:
        rows = [inp.obstacles, inp.neighbours]
        arrays = ObstacleArrays.concat(
            [
                ObstacleArrays(r.c_w, r.v_w, r.a_w, r.radius_m, r.axis_w, np.full(len(r.ids), i == 1))
                for i, r in enumerate(rows)
            ]
        )
        res = self._filter.filter(inp.state, inp.u_ref, arrays)
        return FilterOutput(res.u, res.status)


class C3BF(_Barrier):
    """The collision-cone CBF-QP (the paper's, with the live rows): ``filter.kind: c3bf``."""

    barrier = BarrierKind.C3BF


class HOCBF(_Barrier):
    """The distance-based higher-order CBF-QP: ``filter.kind: hocbf``."""

    barrier = BarrierKind.HOCBF


def barrier_of(cls: type) -> BarrierKind | None:
    """The built-in barrier a filter class is (its ``barrier``), or None for any other method."""
    b = getattr(cls, "barrier", None)
    return b if isinstance(b, BarrierKind) else None


_EMPTY_I = np.zeros(0, dtype=np.intp)
_EMPTY_F = np.zeros(0)
_EMPTY_B = np.zeros(0, dtype=bool)


@dataclass(kw_only=True)
class Containment:
    """A plugin's tally of fallbacks (a filter's or a reference controller's): each tick a
    fault ruled its output out, counted by reason."""

    budget_s: float  # s of wall time a call may take
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(FALLBACK_NAMES, 0))
    last: str = ""  # the reason of the newest tick's fallback ("" none)
    last_error: str = ""  # the newest exception's type and message (for the agent's log)

    @property
    def fallbacks(self) -> int:
        """Ticks so far whose output was the fallback's."""
        return sum(self.counts.values())

    def reset(self) -> None:
        self.counts = dict.fromkeys(FALLBACK_NAMES, 0)
        self.last = self.last_error = ""

    def _fell_back(self, reason: Fallback) -> None:
        self.counts[reason.value] += 1
        self.last = reason.value


@dataclass
class ContainedFilter(Containment):
    """A plugin filter with its containment (see the module docstring). :meth:`run` is the
    agent step's filter call: the plugin's command, or the fallback's, as a
    :class:`FilterResult` (a plugin's has no rows: ``row_index`` empty)."""

    method: Any  # a SafetyMethod
    spec: FilterSpec

    def run(
        self,
        inp: FilterInput,
        fallback: Callable[[], FilterResult],
        brake: Callable[[], FloatArray],
    ) -> FilterResult:
        """The plugin's filtered command for ``inp``, or, on a fault, ``fallback()`` (the
        built-in C3BF-QP on the same rows), or, if that raises, ``brake()`` (a command that
        brakes to a hover where the drone is, status FAILED)."""
        t0 = time.perf_counter()
        reason: Fallback | None = None
        out: Any = None
        try:
            out = self.method.filter(inp)
        except Exception as exc:  # a plugin's fault of any kind is contained, never the agent's
            reason = Fallback.RAISED
            self.last_error = f"{type(exc).__name__}: {exc}"
        dt = time.perf_counter() - t0
        u = _EMPTY_F
        status = FilterStatus.OK
        if reason is None:
            u, status, reason = self._check(out)
        if reason is None and dt > self.budget_s:
            reason = Fallback.OVERRUN
        if reason is None:
            ins = self.spec.limits
            return FilterResult(
                u, inp.u_ref, status, _EMPTY_I, _EMPTY_F, _EMPTY_F, _EMPTY_B, _EMPTY_B, _EMPTY_F, dt,
                ins.violation(u), _EMPTY_F, False,
            )  # fmt: skip
        self._fell_back(reason)
        try:
            return fallback()
        except Exception as exc:  # the fallback's own input check: brake and hold
            self.last_error = f"fallback {type(exc).__name__}: {exc}"
            b = brake()
            return FilterResult(
                b, inp.u_ref, FilterStatus.FAILED, _EMPTY_I, _EMPTY_F, _EMPTY_F, _EMPTY_B, _EMPTY_B, _EMPTY_F,
                time.perf_counter() - t0, self.spec.limits.violation(b), _EMPTY_F, False,
            )  # fmt: skip

    def _check(self, out: Any) -> tuple[FloatArray, FilterStatus, Fallback | None]:
        """The command and status of a plugin's output, or the fault that rules it out."""
        m = self.spec.limits.lb.shape[0]
        try:
            u_raw, status = (out.u, out.status) if isinstance(out, FilterOutput) else (out, FilterStatus.OK)
            status = FilterStatus(status)
            u = np.array(u_raw, dtype=float).reshape(-1)
        except (TypeError, ValueError, AttributeError):
            return _EMPTY_F, FilterStatus.FAILED, Fallback.NON_FINITE
        if u.shape != (m,) or not all_finite(u):
            return _EMPTY_F, FilterStatus.FAILED, Fallback.NON_FINITE
        if status is FilterStatus.FAILED:
            return _EMPTY_F, status, Fallback.FAILED
        scale = max(1.0, float(np.max(np.abs(self.spec.limits.ub))))
        if self.spec.limits.violation(u) > LIMIT_TOL * scale:
            return _EMPTY_F, status, Fallback.OUT_OF_LIMITS
        return u, status, None


def into_limits(u: FloatArray, limits: LinearInputSet) -> FloatArray:
    """``u`` moved into the input set ``limits`` (a plugin's helper): at the rotor level each
    thrust clipped to its bounds; at the attitude level (``F`` (3,) [N, world], ``C F <= d`` the
    tilt rows) its vertical part clipped to its bounds, then its horizontal part shrunk, its
    direction kept, until the tilt rows and the bounds hold."""
    u = np.asarray(u, dtype=float)
    if u.shape != (3,) or limits.C.shape[1] != 3:
        return np.clip(u, limits.lb, limits.ub)
    out = u.copy()
    out[2] = min(max(out[2], limits.lb[2]), limits.ub[2])
    scale = 1.0
    for ci, di in zip(limits.C, limits.d, strict=True):
        lhs = ci[0] * out[0] + ci[1] * out[1]
        room = di - ci[2] * out[2]
        if lhs > room:
            scale = min(scale, max(room, 0.0) / lhs)
    for j in (0, 1):
        if abs(out[j]) * scale > limits.ub[j]:
            scale = min(scale, limits.ub[j] / abs(out[j]))
    out[:2] *= scale * (1.0 - 1e-9)
    return out


def budget_s(budget_ms: float | None, control_period_s: float, wall_clock: bool) -> float:
    """A plugin call's budget [s]: ``budget_ms`` if given; else one control period where the run
    is on the wall clock, and none (inf) where it is not (lockstep, offline): there the world waits
    for every agent, so a slow call costs time, not safety, and a budget of wall time would make a
    lockstep run's figures depend on the machine's load."""
    if budget_ms is not None:
        return budget_ms * 1e-3
    return control_period_s if wall_clock else math.inf
