"""The reference controller protocol a plugin implements, and its containment in the agent's
step (docs/plugins.md, "Your own reference controller"; docs/design.md, "Plugins").

A reference controller is a class registered under the entry-point group
``c3swarm.controllers`` (``swarm.plugins``). The agent builds it once from a
:class:`ControllerSpec` and calls :meth:`reference` every control tick with a
:class:`ControllerInput` (its own estimate, its planned path and goal, the obstacles' and
neighbours' rows, and the built-in path tracker's reference); it returns a
:class:`ControllerOutput`, the thrust vector the safety filter then filters (at the rotor level
the step turns it into rotor thrusts, as it does the built-in's). It shapes the mission's
reference only: where the route gives way or brakes, the safety monitor slows, holds or lands the
drone, or a real drone takes off or lands, the built-in reference flies.

:class:`ContainedController` calls it: a call that raises, returns a thrust vector that is not
three finite numbers or is outside the airframe's thrust-vector input set, or takes longer than
its budget is replaced by the built-in path tracker's reference and counted by reason
(``swarm.safety.external.Fallback``). It is trusted code in the agent's process, handed only what
the two dataclasses name.

The built-in path tracker is registered the same way (:class:`PathTracking`); its ``builtin``
attribute tells the step to compute its reference itself, which is every plugin's fallback.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import numpy as np
from pydantic import BaseModel

from swarm.model import LinearInputSet, QuadParams, QuadState, all_finite
from swarm.rotation import FloatArray
from swarm.safety.external import LIMIT_TOL, Containment, Fallback, Rows


@dataclass(frozen=True)
class ControllerSpec:
    """What a reference controller is built with, once per agent."""

    agent_id: str
    params: QuadParams  # the airframe: mass_kg, g_mps2, body_radius_m, f_max_N, max_tilt_rad ...
    limits: LinearInputSet  # the thrust vector's input set: lb <= F <= ub and C F <= d [N, world]
    speed_mps: float  # m/s: the agent's target speed along its path (speed_mps)
    control_period_s: float  # s: one control tick
    options: BaseModel | None  # the plugin's validated options (its ``Options`` model), or None


@dataclass(frozen=True)
class ControllerInput:
    """What a reference controller is given at one control tick."""

    t_s: float  # s: the tick's simulated time
    state: QuadState  # its own estimate (a copy): x_w [m], v_w [m/s], q (x, y, z, w), Omega_b [rad/s], world
    x_b_w: FloatArray  # (3,) m, world: its body centre
    v_b_w: FloatArray  # (3,) m/s, world: its velocity
    path_w: FloatArray  # (k, 3) m, world: its planned path (round the walls), the start first, the goal last
    goal_w: FloatArray  # (3,) m, world: its goal
    obstacles: Rows  # the scene's obstacles at the tick
    neighbours: Rows  # the other drones within the sensing radius, predicted to the tick
    F_track_w: FloatArray  # (3,) N, world: the built-in path tracker's reference (with the tie-break)


class ControllerOutput(NamedTuple):
    """What a reference controller returns: the reference thrust vector [N, world] (3,)."""

    F_w: FloatArray


class PathTracking:
    """The built-in reference: the path tracker with the right-hand tie-break
    (``swarm.control.reference_thrust``), ``controller.kind: path_tracker``. The step computes it
    itself (``builtin``); called as a plugin it returns the tracker's reference it is given."""

    builtin: ClassVar[bool] = True

    def __init__(self, spec: ControllerSpec) -> None:
        self.spec = spec

    def reference(self, inp: ControllerInput) -> ControllerOutput:
        return ControllerOutput(inp.F_track_w)


def is_builtin(cls: type) -> bool:
    """The class is the built-in path tracker (the step computes its reference itself)."""
    return getattr(cls, "builtin", False) is True


@dataclass
class ContainedController(Containment):
    """A reference controller plugin with its containment (see the module docstring)."""

    method: Any  # a class with reference(inp) -> ControllerOutput
    spec: ControllerSpec

    def run(self, inp: ControllerInput) -> FloatArray:
        """The plugin's reference thrust vector [N, world] for ``inp``, or on a fault the built-in's
        (``inp.F_track_w``)."""
        t0 = time.perf_counter()
        reason: Fallback | None = None
        F: FloatArray = inp.F_track_w
        out: Any = None
        try:
            out = self.method.reference(inp)
        except Exception as exc:  # a plugin's fault of any kind is contained, never the agent's
            reason, self.last_error = Fallback.RAISED, f"{type(exc).__name__}: {exc}"
        if reason is None:
            try:
                F = np.array(out.F_w if isinstance(out, ControllerOutput) else out, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                F = np.zeros(0)
            if F.shape != (3,) or not all_finite(F):
                reason = Fallback.NON_FINITE
        if reason is None:
            scale = max(1.0, float(np.max(np.abs(self.spec.limits.ub))))
            if self.spec.limits.violation(F) > LIMIT_TOL * scale:
                reason = Fallback.OUT_OF_LIMITS
        if reason is None and time.perf_counter() - t0 > self.budget_s:
            reason = Fallback.OVERRUN
        if reason is None:
            return F
        self._fell_back(reason)
        return inp.F_track_w
