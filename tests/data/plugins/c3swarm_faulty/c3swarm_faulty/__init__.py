"""Safety filters that misbehave from ``after_s`` on: raise, return NaN, overrun their budget,
or ask for more thrust than the airframe has. Before then each passes the reference through.
Reference controllers: one that raises from ``after_s`` on, and a sound one that asks for a
gentler horizontal thrust than the path tracker's. Planners: a sound one that detours by a
waypoint ``side_m`` to the left of the first leg's middle, one that raises, one that ends short."""

from __future__ import annotations

import time

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from swarm.planner import PlannerInput, PlannerOutput, PlannerSpec
from swarm.reference import ControllerInput, ControllerOutput, ControllerSpec
from swarm.safety.external import FilterInput, FilterOutput, FilterSpec


class Options(BaseModel):
    model_config = ConfigDict(extra="forbid")

    after_s: float = Field(0.5, ge=0)  # s: sim time from which it misbehaves
    sleep_ms: float = Field(20.0, ge=0)  # ms: how long the slow one takes a call


class _Faulty:
    Options = Options

    def __init__(self, spec: FilterSpec) -> None:
        self.spec = spec
        self.opt = spec.options if isinstance(spec.options, Options) else Options()

    def filter(self, inp: FilterInput) -> FilterOutput:
        if inp.t_s < self.opt.after_s:
            return FilterOutput(inp.u_ref)
        return self.fault(inp)

    def fault(self, inp: FilterInput) -> FilterOutput:
        raise NotImplementedError


class Raises(_Faulty):
    def fault(self, inp: FilterInput) -> FilterOutput:
        raise RuntimeError("this filter raises on purpose")


class ReturnsNaN(_Faulty):
    def fault(self, inp: FilterInput) -> FilterOutput:
        return FilterOutput(np.full_like(inp.u_ref, np.nan))


class Slow(_Faulty):
    def fault(self, inp: FilterInput) -> FilterOutput:
        time.sleep(self.opt.sleep_ms * 1e-3)
        return FilterOutput(inp.u_ref)


class OutOfLimits(_Faulty):
    def fault(self, inp: FilterInput) -> FilterOutput:
        return FilterOutput(inp.u_ref * 100.0)


class RaisingController:
    Options = Options

    def __init__(self, spec: ControllerSpec) -> None:
        self.opt = spec.options if isinstance(spec.options, Options) else Options()

    def reference(self, inp: ControllerInput) -> ControllerOutput:
        if inp.t_s < self.opt.after_s:
            return ControllerOutput(inp.F_track_w)
        raise RuntimeError("this controller raises on purpose")


class GentleController:
    def __init__(self, spec: ControllerSpec) -> None:
        self.spec = spec

    def reference(self, inp: ControllerInput) -> ControllerOutput:
        F = np.array(inp.F_track_w)
        F[:2] *= 0.8  # N, world: four fifths of the tracker's horizontal thrust
        return ControllerOutput(F)


class DetourOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")

    side_m: float = Field(0.5, gt=0)  # m: how far left of the first leg's middle the detour goes


class Detour:
    Options = DetourOptions

    def __init__(self, spec: PlannerSpec) -> None:
        self.opt = spec.options if isinstance(spec.options, DetourOptions) else DetourOptions()

    def plan(self, inp: PlannerInput) -> PlannerOutput:
        a, b = inp.start_w, inp.targets_w[0]
        d = b - a
        left = np.array([-d[1], d[0], 0.0]) / max(float(np.hypot(d[0], d[1])), 1e-9)
        return PlannerOutput(np.vstack([(a + b) / 2 + self.opt.side_m * left, inp.targets_w]))


class RaisingPlanner:
    def __init__(self, spec: PlannerSpec) -> None:
        pass

    def plan(self, inp: PlannerInput) -> PlannerOutput:
        raise RuntimeError("this planner raises on purpose")


class LostPlanner:
    def __init__(self, spec: PlannerSpec) -> None:
        pass

    def plan(self, inp: PlannerInput) -> PlannerOutput:
        return PlannerOutput(inp.targets_w[:, :] * 0.5)  # short of the goal
