"""Safety filter plugins (``swarm.plugins``, ``swarm.safety.external``): the registry, the checks
at load, and the containment of a plugin that raises, returns NaN, leaves the input set, says it
failed or overruns its budget. The installed example and the faulty plugins fly in
``tests/integration/test_plugins.py``."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from swarm.build import contained_plugin, step_of
from swarm.config import ConfigError, resolve
from swarm.model import CommandLevel, QuadModel, QuadParams, QuadState, rotor_input_set, thrust_vector_input_set
from swarm.planning import StaticObstacles
from swarm.plugins import CONTROLLERS, FILTERS, PLANNERS, filter_class, names, plugin_class, registered
from swarm.reference import ContainedController, ControllerInput, ControllerOutput, ControllerSpec, is_builtin
from swarm.safety.external import (
    C3BF,
    HOCBF,
    ContainedFilter,
    Fallback,
    FilterInput,
    FilterOutput,
    FilterSpec,
    Rows,
    barrier_of,
    into_limits,
)
from swarm.safety.filter import FilterConfig, FilterStatus, SafetyFilter
from swarm.safety.obstacles import NamedObstacles, ObstacleArrays


def _raw(**filt: object) -> dict:
    return {
        "version": 1,
        "name": "t",
        "duration_s": 1.0,
        "agents": [{"id": "a", "start": [0, 0, 1], "goal": [2, 0, 1], "filter": dict(filt)}],
    }


def test_the_built_in_barriers_are_registered_as_any_plugin():
    eps = registered(FILTERS)
    assert {"c3bf", "hocbf"} <= set(names())
    assert eps["c3bf"].group == FILTERS and filter_class("c3bf") is C3BF and filter_class("hocbf") is HOCBF
    assert barrier_of(C3BF).value == "c3bf" and barrier_of(HOCBF).value == "hocbf"


@pytest.mark.parametrize(
    ("filt", "field", "says"),
    [
        ({"kind": "mypkg.nope"}, "agents.0.filter.kind", "unknown filter 'mypkg.nope'"),
        ({"kind": "none"}, "agents.0.filter.kind", "filter.enabled: false"),
        ({"kind": "c3bf", "options": {"x": 1}}, "agents.0.filter.options", "takes no options"),
        ({"kind": "c3bf", "budget_ms": 0}, "agents.0.filter.budget_ms", "greater than 0"),
    ],
)
def test_a_bad_filter_is_refused_at_load_naming_the_field(filt, field, says):
    with pytest.raises(ConfigError) as e:
        resolve(_raw(**filt), "t.yaml")
    assert f"t.yaml: {field}: " in str(e.value) and says in str(e.value), str(e.value)


def test_a_built_in_barrier_runs_in_the_step_s_own_qp():
    cfg = resolve(_raw(kind="hocbf"))
    a = cfg.agents[0]
    assert (
        a.filter.barrier.value == "hocbf" and contained_plugin(a, a.filter.filter_config(a.command_level), 120) is None
    )


# -- containment, with in-code methods (the protocol, without an entry point) --

PARAMS = QuadParams()
LIMITS = thrust_vector_input_set(PARAMS)
AGREED = thrust_vector_input_set(PARAMS, accel_limit_mps2=3.0)  # a swarm's agreed acceleration (delay contract)
SPEC = FilterSpec("a", PARAMS, CommandLevel.ATTITUDE, LIMITS, 0.02, 3.0, 1 / 120, None)
HOVER = np.array([0.0, 0.0, PARAMS.weight_N])


class _Returns:
    def __init__(self, u: object, status: FilterStatus = FilterStatus.OK) -> None:
        self.u, self.status = u, status

    def filter(self, inp: FilterInput) -> FilterOutput:
        return FilterOutput(self.u, self.status)  # type: ignore[arg-type]


class _Raises:
    def filter(self, inp: FilterInput) -> FilterOutput:
        raise ZeroDivisionError("boom")


def _input(state: QuadState, u_ref: np.ndarray, sphere: ObstacleArrays) -> FilterInput:
    named = NamedObstacles(sphere, ["ball"])
    none = NamedObstacles.none()
    return FilterInput(
        0.0, state, state.x_w, state.v_w, 0.0, u_ref, Rows.of(sphere, named), Rows.of(none.arrays, none), state.x_w
    )


def _scene() -> tuple[QuadState, np.ndarray, ObstacleArrays, SafetyFilter]:
    state = QuadState.hover([0.0, 0.0, 1.0])
    state.v_w = np.array([1.0, 0.0, 0.0])  # m/s, straight at the sphere
    sphere = ObstacleArrays.build([[1.0, 0.0, 1.0]], [0.2])
    u_ref = HOVER + np.array([0.2, 0.0, 0.0])  # N, world: pushing on towards it
    return state, u_ref, sphere, SafetyFilter(QuadModel(PARAMS), FilterConfig(level=CommandLevel.ATTITUDE))


@pytest.mark.parametrize(
    ("method", "budget_s", "reason"),
    [
        (_Raises(), 1.0, Fallback.RAISED),
        (_Returns(np.array([np.nan, 0.0, 0.3])), 1.0, Fallback.NON_FINITE),
        (_Returns(np.array([0.0, 0.3])), 1.0, Fallback.NON_FINITE),  # not the level's shape
        (_Returns("not a command"), 1.0, Fallback.NON_FINITE),
        (_Returns(HOVER * 10.0), 1.0, Fallback.OUT_OF_LIMITS),
        (_Returns(HOVER, FilterStatus.FAILED), 1.0, Fallback.FAILED),
        (_Returns(HOVER), 0.0, Fallback.OVERRUN),  # any call takes longer than no time at all
    ],
)
def test_a_faulty_plugin_s_command_is_replaced_by_the_c3bf_qp_s_and_counted(method, budget_s, reason):
    state, u_ref, sphere, qp = _scene()
    box = ContainedFilter(method, SPEC, budget_s=budget_s)
    res = box.run(_input(state, u_ref, sphere), lambda: qp.filter(state, u_ref, sphere), lambda: HOVER)
    want = qp.filter(state, u_ref, sphere)
    assert np.array_equal(res.u, want.u) and res.status is want.status and len(res.row_index) == 1
    assert box.last == reason.value and box.counts[reason.value] == 1 and box.fallbacks == 1
    box.reset()
    assert box.fallbacks == 0 and box.last == ""


def test_a_sound_plugin_s_command_is_flown_as_it_is():
    state, u_ref, sphere, qp = _scene()
    u = HOVER + np.array([-0.1, 0.0, 0.0])
    box = ContainedFilter(_Returns(u, FilterStatus.INFEASIBLE), SPEC, budget_s=1.0)
    res = box.run(_input(state, u_ref, sphere), lambda: qp.filter(state, u_ref, sphere), lambda: HOVER)
    assert np.array_equal(res.u, u) and res.status is FilterStatus.INFEASIBLE and box.fallbacks == 0
    assert math.isclose(res.intervention, 0.3) and len(res.row_index) == 0


def test_when_the_fallback_cannot_run_either_the_drone_brakes():
    state, u_ref, sphere, _ = _scene()
    box = ContainedFilter(_Raises(), SPEC, budget_s=1.0)

    def broken() -> None:
        raise ValueError("state not finite")

    res = box.run(_input(state, u_ref, sphere), broken, lambda: HOVER)  # type: ignore[arg-type,return-value]
    assert np.array_equal(res.u, HOVER) and res.status is FilterStatus.FAILED and box.counts["raised"] == 1


def test_the_step_flies_the_fallback_and_reports_it():
    state, _, sphere, _ = _scene()
    agent = resolve(_raw(kind="c3bf")).agents[0]
    step = step_of(agent, StaticObstacles.of([]), 0.1)
    ref = step_of(agent, StaticObstacles.of([]), 0.1)
    step.plugin = ContainedFilter(_Raises(), replace(SPEC, control_period_s=1 / 100), budget_s=1.0)
    named, none = NamedObstacles(sphere, ["ball"]), NamedObstacles.none()
    for k in range(3):
        got, want = step(0.01 * k, state, named, none), ref(0.01 * k, state, named, none)
        assert np.array_equal(got.command, want.command)  # the C3BF-QP's command, tick for tick
        assert (got.fallback, got.fallbacks, want.fallbacks) == ("raised", k + 1, 0)
    step.reset_tallies()
    assert step.plugin.fallbacks == 0


def test_into_limits_puts_any_command_inside_the_input_set():
    rotors = rotor_input_set(PARAMS)
    rng = np.random.default_rng(0)
    for _ in range(500):
        F = rng.normal(0.0, 2.0, 3) * rng.choice([0.01, 1.0, 100.0])
        assert LIMITS.violation(into_limits(F, LIMITS)) <= 1e-12
        assert AGREED.violation(into_limits(F, AGREED)) <= 1e-12
        f = rng.normal(0.0, 1.0, 4)
        assert rotors.violation(into_limits(f, rotors)) == 0.0
    inside = HOVER + np.array([0.01, -0.02, 0.0])
    assert np.allclose(into_limits(inside, LIMITS), inside)  # a command inside stays (to 1e-9)


# -- reference controllers --


class _Reference:
    def __init__(self, F: object) -> None:
        self.F = F

    def reference(self, inp: ControllerInput) -> ControllerOutput:
        if isinstance(self.F, Exception):
            raise self.F
        return ControllerOutput(self.F)  # type: ignore[arg-type]


def _ctrl_input(F_track: np.ndarray) -> ControllerInput:
    state = QuadState.hover([0.0, 0.0, 1.0])
    none = NamedObstacles.none()
    rows = Rows.of(none.arrays, none)
    return ControllerInput(0.0, state, state.x_w, state.v_w, np.zeros((2, 3)), state.x_w, rows, rows, F_track)


CTRL_SPEC = ControllerSpec("a", PARAMS, LIMITS, 1.0, 1 / 120, None)


@pytest.mark.parametrize(
    ("F", "budget_s", "reason"),
    [
        (RuntimeError("boom"), 1.0, Fallback.RAISED),
        (np.array([np.inf, 0.0, 0.3]), 1.0, Fallback.NON_FINITE),
        (np.zeros(4), 1.0, Fallback.NON_FINITE),
        (HOVER * 10.0, 1.0, Fallback.OUT_OF_LIMITS),
        (HOVER, 0.0, Fallback.OVERRUN),
    ],
)
def test_a_faulty_controller_s_reference_is_replaced_by_the_tracker_s_and_counted(F, budget_s, reason):
    track = HOVER + np.array([0.1, 0.0, 0.0])
    box = ContainedController(_Reference(F), CTRL_SPEC, budget_s=budget_s)
    assert np.array_equal(box.run(_ctrl_input(track)), track)
    assert box.last == reason.value and box.fallbacks == 1


def test_a_sound_controller_s_reference_is_flown_and_the_built_in_is_registered():
    mine = HOVER + np.array([0.0, 0.05, 0.0])
    box = ContainedController(_Reference(mine), CTRL_SPEC, budget_s=1.0)
    assert np.array_equal(box.run(_ctrl_input(HOVER)), mine) and box.fallbacks == 0
    assert is_builtin(plugin_class(CONTROLLERS, "path_tracker")) and "path_tracker" in names(CONTROLLERS)
    with pytest.raises(ConfigError, match=r"t.yaml: defaults.controller.kind: unknown controller 'mypkg.mpc'"):
        resolve({**_raw(), "defaults": {"controller": {"kind": "mypkg.mpc"}}}, "t.yaml")
    with pytest.raises(ConfigError, match=r"defaults.controller.options: PathTracking takes no options"):
        resolve({**_raw(), "defaults": {"controller": {"options": {"k": 1}}}}, "t.yaml")


def test_the_built_in_planners_are_registered_and_an_unknown_one_is_refused():
    assert {"grid", "none"} <= set(names(PLANNERS))
    assert is_builtin(plugin_class(PLANNERS, "grid")) and is_builtin(plugin_class(PLANNERS, "none"))
    with pytest.raises(ConfigError, match=r"t.yaml: defaults.planner.kind: unknown planner 'mypkg.rrt'"):
        resolve({**_raw(), "defaults": {"planner": {"kind": "mypkg.rrt"}}}, "t.yaml")
    assert resolve({**_raw(), "defaults": {"planner": {"kind": "none"}}}).agents[0].planner.kind == "none"
