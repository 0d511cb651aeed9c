"""The safety monitor (``swarm.safety.monitor``) by its definition, its settings
(``swarm.config.MonitorSettings`` through ``swarm.tuning.monitor_params``), the live noise
margins every row grows by (``swarm.tuning.live_margin_m``, ``swarm.step``), the deviation a
neighbour's state carries into its row (``swarm.net.neighbours``), the ideal world unchanged bit
for bit, and the monitor at work offline in the lab's bad day."""

from __future__ import annotations

import copy
import math
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.build import neighbour_table
from swarm.config import ConfigError, FailureSettings, MonitorSettings, WorldSettings, resolve
from swarm.control import PathTracker
from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.net.neighbours import NeighbourTable
from swarm.offline.closed_loop import fly_scenario, outcome
from swarm.offline.scenario import circle_swap
from swarm.realism.sensing import MocapFrame
from swarm.realism.settings import RealismSettings
from swarm.safety.filter import FilterConfig
from swarm.safety.monitor import (
    BREACH_NAMES,
    CLEAR,
    Action,
    Breach,
    MonitorParams,
    Readings,
    SafetyMonitor,
)
from swarm.safety.obstacles import NamedObstacles, ObstacleArrays
from swarm.step import AgentStep, Sensing
from swarm.tuning import (
    NOISE_SIGMAS,
    command_lead_s,
    design_std,
    expected_ages,
    live_margin_m,
    monitor_params,
)

pytestmark = pytest.mark.unit

MODEL = QuadModel()
LAB = RealismSettings.model_validate("crazyflie_lab")
LEVEL_Q = np.array([0.0, 0.0, 0.0, 1.0])
BREACHES = [b for b in Breach if b]  # the single checks
DT = 1.0 / 64.0  # s: a tick exact in binary, so that sums of ticks and settling times are exact


# --- 1. the monitor by its definition -------------------------------------------------------------------------


def _expected_breaches(p: MonitorParams, r: Readings) -> Breach:
    """Each check's bound, read off the docs of MonitorParams and Readings (the sustained ones with
    a duration of 0: at once)."""
    b = Breach.NONE
    if r.own_std_m > p.std_envelope_m:
        b |= Breach.ESTIMATE_STD
    if r.own_age_s > p.estimate_lost_s:
        b |= Breach.ESTIMATE_LOST
    elif r.own_age_s > p.estimate_age_s:
        b |= Breach.ESTIMATE_AGE
    if r.neighbour_std_m > p.std_envelope_m:
        b |= Breach.NEIGHBOUR_STD
    if r.neighbour_age_s > p.neighbour_age_s:
        b |= Breach.NEIGHBOUR_AGE
    if not r.clean_solve:
        b |= Breach.INFEASIBLE
    if r.disturbance_clipped:
        b |= Breach.DISTURBANCE
    if r.world_late_s > p.world_late_s:
        b |= Breach.WORLD_LATE
    if r.tick_overrun:
        b |= Breach.TICK_OVERRUN
    return b


_ACTIONS = st.sampled_from([Action.WARN, Action.SLOW, Action.HOLD, Action.LAND])
_GRADES = st.fixed_dictionaries({b: _ACTIONS for b in BREACHES}).map(lambda d: tuple(d.items()))


def _around(bound: float) -> st.SearchStrategy[float]:
    """A reading below, at, just above or well past ``bound``."""
    at = [0.0, bound, math.nextafter(bound, math.inf)] if math.isfinite(bound) else [0.0, 1e9]
    return st.one_of(st.sampled_from(at), st.floats(0.0, 3.0 * bound if math.isfinite(bound) else 1e3))


@st.composite
def _params_and_readings(draw):
    p = MonitorParams(
        std_envelope_m=draw(st.sampled_from([math.inf, 0.002, 0.01])),
        estimate_age_s=draw(st.sampled_from([0.05, 0.15])),
        estimate_lost_s=draw(st.sampled_from([0.5, 1.0])),
        neighbour_age_s=draw(st.sampled_from([0.1, 0.3])),
        infeasible_s=0.0,
        disturbance_s=0.0,
        world_late_s=draw(st.sampled_from([0.05, 0.1])),
        grades=draw(_GRADES),
    )
    r = Readings(
        t_s=draw(st.floats(0.0, 100.0)),
        own_std_m=draw(_around(p.std_envelope_m)),
        own_age_s=draw(st.one_of(_around(p.estimate_age_s), _around(p.estimate_lost_s))),
        neighbour_std_m=draw(_around(p.std_envelope_m)),
        neighbour_age_s=draw(_around(p.neighbour_age_s)),
        clean_solve=draw(st.booleans()),
        disturbance_clipped=draw(st.booleans()),
        world_late_s=draw(_around(p.world_late_s)),
        tick_overrun=draw(st.booleans()),
    )
    return p, r


@settings(max_examples=300, deadline=None)
@given(_params_and_readings())
def test_each_breach_arises_exactly_when_its_reading_crosses_its_bound_and_the_action_is_the_strongest_grade(pr):
    p, r = pr
    mon = SafetyMonitor(p)
    v = mon.check(r)
    want = _expected_breaches(p, r)
    assert v.breaches == want
    assert v.action == max((p.grade(b) for b in BREACHES if b in want), default=Action.NONE)
    assert v.acting == (v.action >= Action.SLOW)
    # the tallies of one tick: one per breach, one for the action
    assert mon.breach_ticks == {BREACH_NAMES[b]: 1 for b in BREACHES if b in want}
    assert mon.action_ticks == ({} if v.action is Action.NONE else {v.action.name.lower(): 1})
    assert mon.first_action_s == (r.t_s if v.action >= Action.SLOW else None)


def _readings_for(t_s: float, breaches: Breach, p: MonitorParams) -> Readings:
    """Readings at ``t_s`` that breach exactly ``breaches`` of ``p`` (sustained ones of duration 0)."""
    past = 1.0 + 1e-6
    own_age = 0.0
    if Breach.ESTIMATE_LOST in breaches:
        own_age = p.estimate_lost_s * past
    elif Breach.ESTIMATE_AGE in breaches:
        own_age = p.estimate_age_s * past
    return Readings(
        t_s=t_s,
        own_std_m=p.std_envelope_m * past if Breach.ESTIMATE_STD in breaches else 0.0,
        own_age_s=own_age,
        neighbour_std_m=p.std_envelope_m * past if Breach.NEIGHBOUR_STD in breaches else 0.0,
        neighbour_age_s=p.neighbour_age_s * past if Breach.NEIGHBOUR_AGE in breaches else 0.0,
        clean_solve=Breach.INFEASIBLE not in breaches,
        disturbance_clipped=Breach.DISTURBANCE in breaches,
        world_late_s=p.world_late_s * past if Breach.WORLD_LATE in breaches else 0.0,
        tick_overrun=Breach.TICK_OVERRUN in breaches,
    )


_SEQUENCES = st.lists(
    st.lists(st.sampled_from([b for b in BREACHES if b is not Breach.ESTIMATE_LOST]), max_size=3).map(
        lambda bs: Breach(sum(set(bs)))
    ),
    min_size=1,
    max_size=120,
)


@settings(max_examples=150, deadline=None)
@given(_SEQUENCES, _GRADES, st.sampled_from([0, 1, 8, 32]))
def test_an_action_is_held_settle_s_after_its_breach_clears_the_strongest_wins_and_land_is_latched(
    sequence, grades, settle_ticks
):
    """The reference: at tick i the action is the strongest grade of every breach at a tick j <= i
    with ``t_j + settle_s > t_i`` (its own tick's breaches always), LAND forever once taken; the
    tallies count the verdicts' breaches and actions, the first action the first SLOW or stronger."""
    p = MonitorParams(std_envelope_m=0.01, infeasible_s=0.0, disturbance_s=0.0, settle_s=settle_ticks * DT,
                      grades=grades)  # fmt: skip
    mon = SafetyMonitor(p)
    verdicts, landed = [], False
    for i, breaches in enumerate(sequence):
        t = i * DT
        v = mon.check(_readings_for(t, breaches, p))
        assert v.breaches == breaches, i
        asked = [
            p.grade(b)
            for j, bj in enumerate(sequence[: i + 1])
            for b in BREACHES
            if b in bj and (j == i or j * DT + p.settle_s > t)
        ]
        want = max(asked, default=Action.NONE)
        if landed:
            want = Action.LAND
        landed = landed or want is Action.LAND
        assert v.action == want, (i, sequence[: i + 1])
        verdicts.append(v)
    for b in BREACHES:
        assert mon.breach_ticks.get(BREACH_NAMES[b], 0) == sum(b in v.breaches for v in verdicts)
    for a in Action:
        if a is not Action.NONE:
            assert mon.action_ticks.get(a.name.lower(), 0) == sum(v.action is a for v in verdicts)
    first = next((i * DT for i, v in enumerate(verdicts) if v.action >= Action.SLOW), None)
    assert mon.first_action_s == first


def test_a_held_action_drops_exactly_settle_s_after_its_breach_and_a_stronger_one_overrides_it():
    p = MonitorParams(std_envelope_m=0.01, settle_s=32 * DT)  # ESTIMATE_STD: slow, ESTIMATE_AGE: hold
    mon = SafetyMonitor(p)
    script = {k: Breach.ESTIMATE_STD for k in range(0, 10)}  # slow over ticks 0-9
    script.update({k: Breach.ESTIMATE_AGE for k in range(20, 24)})  # hold over 20-23, inside slow's settling
    actions = [mon.check(_readings_for(k * DT, script.get(k, Breach.NONE), p)).action for k in range(100)]
    assert actions[:20] == [Action.SLOW] * 20  # slow, then held (9 + 32 = 41 > 19)
    assert actions[20:55] == [Action.HOLD] * 35  # the stronger at once, held while t < (23 + 32) ticks
    assert actions[55:] == [Action.NONE] * 45  # slow's hold ended at 41 under it: nothing is left
    assert mon.first_action_s == 0.0
    assert mon.action_ticks == {"slow": 20, "hold": 35}
    assert mon.breach_ticks == {"estimate_std": 10, "estimate_age": 4}


def test_land_is_latched_forever_and_a_disabled_monitor_is_clear():
    p = MonitorParams(std_envelope_m=0.01)
    mon = SafetyMonitor(p)
    assert mon.check(_readings_for(0.0, Breach.ESTIMATE_STD, p)).action is Action.SLOW
    lost = mon.check(Readings(t_s=0.1, own_age_s=p.estimate_lost_s + 0.01))
    assert lost.breaches == Breach.ESTIMATE_LOST and lost.action is Action.LAND
    for k in range(1, 2000):  # clear readings for 200 s, and a weaker breach among them
        v = mon.check(_readings_for(0.1 + 0.1 * k, Breach.ESTIMATE_AGE if k == 500 else Breach.NONE, p))
        assert v.action is Action.LAND, k
    off = SafetyMonitor(MonitorParams(enabled=False, std_envelope_m=0.0))
    for k in range(50):
        r = Readings(t_s=k * 0.01, own_std_m=1.0, own_age_s=5.0, neighbour_std_m=1.0, neighbour_age_s=5.0,
                     clean_solve=False, disturbance_clipped=True, world_late_s=5.0, tick_overrun=True)  # fmt: skip
        assert off.check(r) == CLEAR
    assert off.breach_ticks == off.action_ticks == {} and off.first_action_s is None


@pytest.mark.parametrize(
    ("breach", "field", "duration"),
    [(Breach.INFEASIBLE, "clean_solve", 0.25), (Breach.DISTURBANCE, "disturbance_clipped", 0.5)],
)
def test_infeasible_and_disturbance_breach_only_once_sustained_for_their_durations(breach, field, duration):
    p = MonitorParams(infeasible_s=0.25, disturbance_s=0.5, settle_s=0.0,
                      grades=((Breach.INFEASIBLE, Action.SLOW), (Breach.DISTURBANCE, Action.HOLD)))  # fmt: skip
    bad = {field: field != "clean_solve"}  # not a clean solve / clipped

    def run(mon: SafetyMonitor, k0: int, ticks: int) -> list[bool]:
        return [breach in mon.check(Readings(t_s=(k0 + k) * DT, **bad)).breaches for k in range(ticks)]

    n = round(duration / DT)  # 16 and 32 ticks
    mon = SafetyMonitor(p)
    assert run(mon, 0, n + 5) == [False] * n + [True] * 5  # from the tick the condition is `duration` old
    assert mon.check(Readings(t_s=(n + 5) * DT)).breaches == Breach.NONE  # one good tick: the count starts again
    assert run(mon, n + 6, n + 2) == [False] * n + [True] * 2
    assert mon.breach_ticks == {BREACH_NAMES[breach]: 7}
    assert mon.action_ticks == {p.grade(breach).name.lower(): 7}
    assert mon.first_action_s == n * DT == duration  # the first tick it breached, `duration` after it began


# --- 2. config -> params ----------------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(
    st.fixed_dictionaries({name: st.sampled_from(["warn", "slow", "hold", "land"]) for name in BREACH_NAMES.values()})
)
def test_the_configs_grades_are_the_monitors(grades):
    p = monitor_params(MonitorSettings(grades=grades), None, FailureSettings())
    by_name = {name: b for b, name in BREACH_NAMES.items()}
    assert {by_name[name]: Action[a.upper()] for name, a in grades.items()} == dict(p.grades)
    for name, a in grades.items():
        assert p.grade(by_name[name]) is Action[a.upper()]


def test_the_std_envelope_is_the_design_deviation_times_its_factor_with_sensing_and_none_without():
    failure = FailureSettings(neighbour_timeout_s=0.2)
    sd = design_std(LAB)[0]
    assert sd > 0.0
    assert monitor_params(MonitorSettings(), LAB, failure).std_envelope_m == pytest.approx(1.5 * sd)
    assert monitor_params(MonitorSettings(std_envelope_factor=4.0), LAB, failure).std_envelope_m == pytest.approx(
        4 * sd
    )
    assert monitor_params(MonitorSettings(std_envelope_m=0.02), LAB, failure).std_envelope_m == 0.02
    for without in (
        None,
        RealismSettings(),
        RealismSettings.model_validate({"preset": "crazyflie_lab", "sensing": {"enabled": False}}),
    ):
        assert monitor_params(MonitorSettings(), without, failure).std_envelope_m == math.inf
    p = monitor_params(MonitorSettings(), LAB, failure)
    ages = expected_ages(LAB, None)  # (no rate: no lead)
    assert p.neighbour_age_s == pytest.approx(0.2 + ages.neighbour_s)  # failure.neighbour_timeout_s unless set
    assert monitor_params(MonitorSettings(neighbour_age_s=0.3), LAB, failure).neighbour_age_s == pytest.approx(
        0.3 + ages.neighbour_s
    )
    s = MonitorSettings(estimate_age_s=0.2, estimate_lost_s=0.9, settle_s=0.25, slow_fraction=0.4, enabled=False)
    q = monitor_params(s, LAB, failure)
    assert (q.estimate_age_s, q.estimate_lost_s) == pytest.approx((0.2 + ages.own_s, 0.9 + ages.own_s))
    assert (q.settle_s, q.slow_fraction, q.enabled) == (0.25, 0.4, False)


def test_the_age_bounds_are_counted_beyond_the_ages_the_configured_delays_give():
    """A known delay is predicted through, not a breach: at 150 ms on the motion capture and on every
    link, the own estimate is read 300 ms after its frame's capture (the latency and the command's lead)
    and a neighbour's row is a tick, two links and the lead old; the bounds sit that far beyond the
    settings, and nothing is added in the ideal world."""
    link = {"delay_s": 0.15}
    late = RealismSettings.model_validate(
        {"sensing": {"enabled": True, "latency_s": 0.15}, "comms": {"state": link, "bundle": link, "command": link}}
    )
    hz = 100.0
    lead = command_lead_s(late, hz)
    assert lead == pytest.approx(0.15)
    ages = expected_ages(late, hz)
    assert ages.own_s == pytest.approx(0.15 + lead)
    assert ages.neighbour_s == pytest.approx(0.01 + 0.3 + lead)
    p = monitor_params(MonitorSettings(), late, FailureSettings(), hz)
    assert p.estimate_age_s == pytest.approx(0.15 + 0.3)
    assert p.neighbour_age_s == pytest.approx(0.1 + 0.46)
    assert expected_ages(None, hz) == (0.0, 0.0) == expected_ages(RealismSettings(), hz)
    assert monitor_params(MonitorSettings(), None, FailureSettings(), hz).estimate_age_s == 0.15


_BAD_MONITORS = {
    "lost_before_age": ({"estimate_age_s": 0.5, "estimate_lost_s": 0.5}, ["monitor", "estimate_lost_s"]),
    "lost_below_age": ({"estimate_age_s": 0.5, "estimate_lost_s": 0.2}, ["monitor", "estimate_lost_s"]),
    "unknown_grade": ({"grades": {"estimate_stale": "hold"}}, ["monitor.grades.estimate_stale"]),
    "unknown_action": ({"grades": {"estimate_age": "panic"}}, ["monitor.grades.estimate_age"]),
    "negative_settle": ({"settle_s": -1.0}, ["monitor.settle_s"]),
}


@pytest.mark.parametrize("case", sorted(_BAD_MONITORS))
def test_a_bad_monitor_config_is_refused_naming_the_field(case):
    change, fields = _BAD_MONITORS[case]
    raw = copy.deepcopy(circle_swap(2))
    raw["monitor"] = change
    with pytest.raises(ConfigError) as err:
        resolve(raw, "bad.yaml")
    msg = str(err.value)
    assert msg.startswith("bad.yaml: monitor"), msg
    for f in fields:
        assert f in msg, msg


# --- 3. live margins --------------------------------------------------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(st.floats(0.0, 1.0), st.lists(st.floats(0.0, 1.0), max_size=8))
def test_the_live_margin_is_three_sigma_of_own_and_rows_deviations_in_quadrature(own, rows):
    got = live_margin_m(own, np.array(rows))
    want = [3.0 * math.sqrt(own * own + r * r) for r in rows]
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0.0)
    assert NOISE_SIGMAS == 3.0


def _hover_step(monitor: MonitorParams, start: np.ndarray, floor_z_m: float | None = None) -> AgentStep:
    """A step holding ``start`` with the lab's estimator (its own frames from :func:`_frame`)."""
    return AgentStep(MODEL, FilterConfig(level=CommandLevel.ATTITUDE, floor_z_m=floor_z_m), PathTracker([start], 0.5),
                     sensing=Sensing(LAB.estimator(start, LEVEL_Q)), monitor=monitor)  # fmt: skip


def _frame(k: int, t: float, at: np.ndarray, rng: np.random.Generator) -> MocapFrame:
    """Frame k of a drone at rest at ``at``: captured 10 ms (the lab's latency) before it arrives at ``t``."""
    return MocapFrame(0, k, t - 0.01, t, at + 1e-3 * rng.standard_normal(3), LEVEL_Q)


PILLAR = NamedObstacles(ObstacleArrays.build([[1.0, 0.0, 1.0]], [0.2]), ["pillar"])


def test_a_motion_capture_gap_grows_the_live_margin_holds_the_drone_and_frames_shrink_it_back():
    """Frames every 10 ms, none for 0.2 s from 0.5 s, then frames again: the published deviation
    and the live margin (3 x it, against a fixed obstacle) grow every tick of the gap; past the
    estimate's 0.15 s age the verdict is HOLD and the velocity held zero; with frames back the
    margin returns to its size before the gap and, ``settle_s`` after the last breach, the
    action clears."""
    start = np.array([0.0, 0.0, 1.0])
    p = monitor_params(MonitorSettings(), LAB, FailureSettings())
    step = _hover_step(p, start)
    rng = np.random.default_rng(0)
    none = NamedObstacles.none()
    res = []
    for k in range(150):
        t = k * 0.01
        frames = [] if k == 0 or 50 <= k < 70 else [_frame(k, t, start, rng)]
        res.append(step(t, QuadState.hover(start), PILLAR, none, frames=frames))
    before = res[49]
    assert before.verdict == CLEAR and 0.0 < before.live_margin_m < 0.005  # about 3 x 0.8 mm
    assert before.live_margin_m == pytest.approx(3.0 * before.sd[0], rel=1e-12)  # a fixed row carries none
    assert before.est[6] == before.sd[0] and before.est[8] == pytest.approx(0.01)
    gap = res[49:70]
    live = [r.live_margin_m for r in gap]
    sd = [r.sd[0] for r in gap]
    assert all(b > a for a, b in zip(live, live[1:], strict=False)), live  # the gap grows the radius, every tick
    assert all(b > a for a, b in zip(sd, sd[1:], strict=False)), sd
    assert live[-1] > 5.0 * live[0]
    ages = [float(r.est[8]) for r in gap]
    for r, age in zip(gap, ages, strict=True):
        if age > p.estimate_age_s + 1e-9:
            assert r.verdict.action is Action.HOLD and Breach.ESTIMATE_AGE in r.verdict.breaches, age
            np.testing.assert_array_equal(r.held_w, np.zeros(3))
        elif age < p.estimate_age_s - 1e-9:
            assert r.verdict.action < Action.HOLD and Breach.ESTIMATE_AGE not in r.verdict.breaches, age
    assert max(ages) > p.estimate_age_s + 0.03  # the gap did pass the bound
    after = res[-1]
    assert after.live_margin_m == pytest.approx(before.live_margin_m, rel=0.1)  # frames shrink it back
    assert res[71].live_margin_m < 0.2 * live[-1]
    last_breach = max(k for k, r in enumerate(res) if r.verdict.breaches)
    assert 69 <= last_breach <= 71
    settled = last_breach + round(p.settle_s / 0.01)
    assert all(r.verdict.action is Action.HOLD for r in res[last_breach:settled])  # held through its settling
    assert all(r.verdict == CLEAR and r.held_w is None for r in res[settled + 1 :])  # then clear
    assert step.monitor is not None and step.monitor.breach_ticks["estimate_age"] > 0


def _same_rows(a: ObstacleArrays, b: ObstacleArrays) -> bool:
    """Every field of every row the same, bit for bit (the record's padding aside)."""
    names = a.rec.dtype.names or ()
    return len(a) == len(b) and all(a.rec[f].tobytes() == b.rec[f].tobytes() for f in names)


def _spy(step: AgentStep) -> list[ObstacleArrays]:
    """The rows each filter call of ``step`` gets."""
    seen: list[ObstacleArrays] = []
    real = step.filt.filter

    def spied(state, u_ref, rows, *a, **kw):
        seen.append(rows)
        return real(state, u_ref, rows, *a, **kw)

    step.filt.filter = spied  # type: ignore[method-assign]
    return seen


def test_a_neighbours_carried_deviation_widens_its_row_by_the_live_margin():
    """A neighbour whose state carries 1 cm of deviation: its row reaches the filter wider by
    ``live_margin_m(own, 0.01)``, a fixed obstacle's by ``live_margin_m(own, 0)``; the step reports
    the larger, and the filter's answer is the one it gives the rows widened by hand."""
    start = np.array([0.0, 0.0, 1.0])
    own = (0.002, 0.01)
    nb = ObstacleArrays.build([[0.6, 0.05, 1.0]], [0.1], c_dot_w=[[-0.3, 0.0, 0.0]], is_neighbour=[True])
    carried = NamedObstacles(nb, ["b"], sd_m=np.array([0.01]), age_s=np.array([0.02]))
    exact = NamedObstacles(nb, ["b"])
    results, rows = [], []
    for neighbours in (carried, exact):
        step = AgentStep(MODEL, FilterConfig(level=CommandLevel.ATTITUDE), PathTracker([start, [2.0, 0.0, 1.0]], 0.8),
                         sensing=Sensing(fixed_sd=own))  # fmt: skip
        seen = _spy(step)
        results.append(step(0.0, QuadState.hover(start), PILLAR, neighbours))
        rows.append(seen[-1])
    wide = float(live_margin_m(own[0], np.array([0.01]))[0])
    fixed = float(live_margin_m(own[0], np.zeros(1))[0])
    assert wide == pytest.approx(3.0 * math.hypot(0.002, 0.01))
    r_carried, r_exact = rows
    # the rows: the pillar then the neighbour, each the caller's radius plus its margin
    np.testing.assert_allclose(r_carried.radius_m, [0.2 + fixed, 0.1 + wide], rtol=0, atol=1e-15)
    np.testing.assert_allclose(r_exact.radius_m, [0.2 + fixed, 0.1 + fixed], rtol=0, atol=1e-15)
    np.testing.assert_allclose(r_carried.grow_m, [fixed, wide], rtol=0, atol=1e-15)
    widened = ObstacleArrays.concat([PILLAR.arrays, nb]).widened(np.array([fixed, wide]))
    assert _same_rows(widened, r_carried)
    assert results[0].live_margin_m == pytest.approx(wide) and results[1].live_margin_m == pytest.approx(fixed)
    assert results[0].filter is not None and results[1].filter is not None
    h_carried = dict(zip(results[0].row_ids, results[0].filter.h.tolist(), strict=True))
    h_exact = dict(zip(results[1].row_ids, results[1].filter.h.tolist(), strict=True))
    assert h_carried["b"] < h_exact["b"]  # the wider row is nearer its boundary
    assert h_carried["pillar"] == h_exact["pillar"]


# --- 4. the ideal world -----------------------------------------------------------------------------------------


def test_in_the_ideal_world_the_filter_gets_the_callers_rows_and_the_monitor_is_clear():
    start = np.array([0.0, 0.0, 1.0])
    step = AgentStep(MODEL, FilterConfig(level=CommandLevel.ATTITUDE), PathTracker([start, [2.0, 0.0, 1.0]], 0.8),
                     monitor=MonitorParams())  # fmt: skip
    assert not step.live and step.monitor is not None
    seen = _spy(step)
    none = NamedObstacles.none()
    state = QuadState.hover(start)
    for k in range(30):
        nb = ObstacleArrays.build([[1.0 - 0.02 * k, 0.05, 1.0]], [0.1], c_dot_w=[[-1.0, 0.0, 0.0]], is_neighbour=[True])
        neighbours = NamedObstacles(nb, ["b"])
        r = step(k * 0.01, state, none, neighbours)
        assert seen[-1] is nb  # the caller's rows themselves
        assert r.live_margin_m == 0.0 and r.verdict == CLEAR and r.sd == (0.0, 0.0) and len(r.est) == 0
        with_obstacle = step(k * 0.01, state, PILLAR, neighbours)
        assert _same_rows(seen[-1], ObstacleArrays.concat([PILLAR.arrays, nb]))
        assert with_obstacle.live_margin_m == 0.0 and with_obstacle.verdict.action is Action.NONE


def test_in_the_ideal_world_a_swap_flies_bit_for_bit_the_same_with_the_monitor_off_or_on():
    raw = circle_swap(2, 1.0)
    raw["duration_s"] = 4.0
    cfg = resolve(raw)
    cfg = cfg.model_copy(update={"world": WorldSettings()})
    off = fly_scenario(cfg.model_copy(update={"monitor": MonitorSettings(enabled=False)}))
    on = fly_scenario(cfg)
    assert on.x_b_w.tobytes() == off.x_b_w.tobytes()
    for log in (on, off):
        assert log.live_margin_m is not None and not log.live_margin_m.any()
        assert log.monitor is not None and not log.monitor.any()
        assert not any(log.breach_ticks.values()) and log.own_sd_m is None and log.unguarded_ticks == 0
    assert outcome(cfg, on).reached == 2


# --- 5. the neighbour table -------------------------------------------------------------------------------------


def test_a_states_carried_deviation_reaches_its_row_and_its_velocity_error_grows_the_radius():
    timeout, growth, accel, vel_err, sigmas = 0.05, 0.5, 4.0, 0.02, 3.0
    table = NeighbourTable(timeout, growth, 1.0, "keep_stopped", accel, vel_err, sigmas)
    table.update("b", 0.0, 0, np.array([1.0, 0.0, 1.0]), np.array([0.5, 0.0, 0.0]), 0.07, sd=(0.01, 0.05))
    table.update("c", 0.0, 0, np.array([-1.0, 0.0, 1.0]), np.zeros(3), 0.07)  # exact: the fixed velocity error
    for age in (0.0, 0.03, 0.08):
        rows = table.arrays(age)
        assert table.row_names == ["b", "c"]
        np.testing.assert_array_equal(table.row_sd_m, [0.01, 0.0])
        np.testing.assert_allclose(table.row_age_s, [age, age], rtol=0, atol=1e-15)
        for err, i in ((sigmas * 0.05, 0), (vel_err, 1)):  # 3 x 0.05 m/s over the table's 0.02 m/s; 0.02 m/s
            grow = growth * max(0.0, age - timeout) + (0.5 * accel * age + err) * age
            assert rows.grow_m[i] == pytest.approx(grow, rel=1e-12, abs=1e-15)
            assert rows.radius_m[i] == pytest.approx(0.07 + grow, rel=1e-12)
        assert age == 0.0 or rows.radius_m[0] > rows.radius_m[1]
        np.testing.assert_allclose(rows.c_w[0], [1.0 + 0.5 * age, 0.0, 1.0])


def test_the_tables_sigmas_are_three_with_sensing_and_none_without():
    f = FailureSettings()
    assert neighbour_table(f, MODEL.params, LAB).sigmas == NOISE_SIGMAS
    assert neighbour_table(f, MODEL.params, None).sigmas == 0.0
    lab = neighbour_table(f, MODEL.params, LAB)
    assert 0.0 < lab.velocity_error_mps < NOISE_SIGMAS * 0.05  # a state's 0.05 m/s deviation is the larger


# --- 6. offline: the lab's bad day ------------------------------------------------------------------------------


def test_a_circle_in_the_bad_day_breaches_slows_and_holds_and_collides_with_nothing():
    bad = RealismSettings.model_validate("crazyflie_lab_bad_day")
    raw = circle_swap(4, 1.5)
    raw["duration_s"] = 8.0
    cfg = resolve(raw)
    # (seed 4: a day whose occlusions outlast the estimate's age bound beyond the known latency and lead)
    cfg = cfg.model_copy(update={"world": WorldSettings(realism=bad), "seed": 4})
    fly_scenario(cfg.model_copy(update={"duration_s": 0.05}))  # (the compiled kernels loaded: not timed)
    t0 = time.perf_counter()
    log = fly_scenario(cfg)
    took = time.perf_counter() - t0
    assert took < 10.0, took  # about 2 s on an idle machine
    assert sum(log.breach_ticks.values()) > 0
    assert log.breach_ticks["estimate_std"] > 0 and log.breach_ticks["neighbour_std"] > 0
    assert log.breach_ticks["estimate_age"] > 0
    assert log.action_ticks(Action.SLOW) > 0 and log.action_ticks(Action.HOLD) > 0
    assert log.monitor is not None and log.monitor.shape == log.x_b_w.shape[:2]
    assert log.own_sd_m is not None and log.own_sd_m.max() > design_std(bad)[0]
    assert log.live_margin_m is not None and log.live_margin_m.max() > 0.0
    assert log.landed_by_monitor == [False] * 4
    o = outcome(cfg, log)
    assert o.collisions == 0 and o.reached == 4, o


# --- 7. LAND ----------------------------------------------------------------------------------------------------


def test_a_land_verdict_descends_while_above_the_floor_and_stays_landing():
    p = monitor_params(MonitorSettings(grades={"estimate_age": "land"}), LAB, FailureSettings())
    assert p.grade(Breach.ESTIMATE_AGE) is Action.LAND
    none = NamedObstacles.none()
    for z, descends in ((1.0, True), (0.12, False)):  # the floor 0.1 m: within 5 cm of it the drone is down
        start = np.array([0.0, 0.0, z])
        step = _hover_step(p, start, floor_z_m=0.1)
        rng = np.random.default_rng(1)
        res = []
        for k in range(80):  # frames to 0.3 s, none to 0.6 s, frames again
            t = k * 0.01
            frames = [] if k == 0 or 30 <= k < 60 else [_frame(k, t, start, rng)]
            res.append(step(t, QuadState.hover(start), none, none, frames=frames))
        assert all(r.verdict.action < Action.LAND for r in res[:40])
        landing = [r for r in res if r.verdict.action is Action.LAND]
        assert landing and landing[0].est[8] > p.estimate_age_s  # from the tick the age passed its bound
        first = next(k for k, r in enumerate(res) if r.verdict.action is Action.LAND)
        assert all(r.verdict.action is Action.LAND for r in res[first:])  # latched, frames back or not
        for r in res[first:]:
            assert r.held_w is not None
            if descends:
                np.testing.assert_allclose(r.held_w, [0.0, 0.0, -p.land_speed_mps])
            else:
                np.testing.assert_array_equal(r.held_w, np.zeros(3))
        if descends:  # the filter lets it descend: the thrust under the weight
            assert landing[0].u[2] < MODEL.params.weight_N
