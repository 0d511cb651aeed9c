"""tools.bench_imperfections' bad-day axes: each level a valid world.realism, the first level the
lab's motion capture alone (no failure), the one failure the only change up the axis, and one
short point (and ORCA's reference row) flown to a JSON line with the monitor's keys."""

import json

import pytest

from swarm.realism.settings import PRESETS, RealismSettings
from tools.bench_imperfections import (
    AXES,
    DELAY_AXES,
    DELAY_SCENES,
    FIXED,
    METHODS,
    ORCA,
    SCENES,
    Point,
    fly,
    lab_sensing,
    points,
    realism,
)

NEW = ("occlusion", "swap", "radio", "battery", "turbulence")
# what each axis raises, and what it keeps at every level (beside the lab's motion capture)
FAILURE = {
    "occlusion": ("sensing", "occlusion_rate_hz"),
    "swap": ("sensing", "swap_rate_hz"),
    "radio": ("comms", "shared_radio"),
    "battery": ("motors", "battery_sag_fraction_per_min"),
    "turbulence": ("wind", "relative_gust_std_mps"),
}


def _settings(axis: str, level: float) -> RealismSettings:
    return RealismSettings.model_validate(realism(axis, level))


@pytest.mark.parametrize("axis", NEW)
def test_every_level_is_a_valid_world(axis):
    for level in AXES[axis][1]:
        s = _settings(axis, level)
        assert s.sensing.enabled and s.sensing.estimator.gate_sigmas == 5.0
        assert s.sensing.rate_hz == 100.0 and s.sensing.position_noise_m == 0.001 and s.sensing.latency_s == 0.010


@pytest.mark.parametrize("axis", NEW)
def test_the_first_level_is_the_labs_motion_capture_alone(axis):
    first = _settings(axis, AXES[axis][1][0])
    ideal = RealismSettings()
    assert first.sensing == RealismSettings.model_validate({"sensing": lab_sensing()}).sensing
    lab = PRESETS["crazyflie_lab"]["sensing"]
    assert first.sensing.drop_fraction == lab["drop_fraction"]
    s = first.sensing
    assert s.occlusion_rate_hz == s.swap_rate_hz == s.outlier_fraction == s.centroid_offset_std_m == 0.0
    assert first.motors == ideal.motors and first.comms.shared_radio == ideal.comms.shared_radio
    assert first.wind.relative_gust_std_mps == 0.0 and first.wind.gust_std_mps == 0.0
    if axis != "turbulence":  # (its drag, through which the gusts act, is on at every level)
        assert first.wind == ideal.wind and first.aero == ideal.aero
    if axis != "radio":  # (the bad day's command link is on at every level)
        assert first.comms == ideal.comms


@pytest.mark.parametrize("axis", NEW)
def test_only_the_failure_changes_up_the_axis(axis):
    levels = AXES[axis][1]
    first = _settings(axis, levels[0]).model_dump()
    section, key = FAILURE[axis]
    for level in levels[1:]:
        got = _settings(axis, level).model_dump()
        changed = {k for k in got if got[k] != first[k]}
        assert changed == {section}, (axis, level, changed)
        assert got[section][key] != first[section][key]


def test_orca_flies_each_axis_first_level_only_but_every_level_of_the_delay_axes():
    orca = [p for p in points(list(AXES)) if p.method == ORCA]
    want = {(a, lv[0]) for a, (_, lv) in AXES.items()} | {(a, x) for a in DELAY_AXES for x in AXES[a][1]}
    assert {(p.axis, p.level) for p in orca} == want
    assert not any(p.method == ORCA for p in points(["radio"], orca=False))
    assert {p.scene for p in points(["latency"])} == set(DELAY_SCENES) and "circle_16" not in SCENES
    assert {p.method for p in points(["jitter"])} == {*METHODS, FIXED, ORCA}
    assert FIXED not in {p.method for p in points(["noise"])}


def test_orca_sees_and_flies_the_delay_axes_links_late():
    """ORCA on the latency axis: what it sees late by the state's and the bundle's links, its velocities by
    the command link; at 100 ms its closest pair comes nearer than in the ideal world."""
    ideal = fly(Point("latency", 0.0, ORCA, "circle_8p"))
    late = fly(Point("latency", 0.1, ORCA, "circle_8p"))
    assert ideal["ideal_world"] is True and late["ideal_world"] is False
    assert late["min_separation_m"] < ideal["min_separation_m"]


def test_a_short_point_and_orcas_row_fly():
    line = fly(Point("occlusion", 0.5, "c3bf", "circle_8", duration_s=0.5))
    json.dumps(line)
    assert line["unit"] == "s" and line["ideal_world"] is False and line["collisions"] == 0
    assert set(line["monitor_ticks"]) == {"slow", "hold", "land"}
    assert line["landed_by_monitor"] == 0 and line["unguarded_ticks"] >= 0
    assert line["estimate_error_max_m"] >= line["estimate_error_p95_m"] >= 0.0
    ref = fly(Point("radio", 1, ORCA, "circle_8", duration_s=0.5))
    assert ref["ideal_world"] is True and ref["monitor_ticks"] is None and ref["collisions"] == 0
    assert set(ref) == set(line)
