"""A script's orders (swarm.agents.orders, pure): which a run takes, the goal and cruise speed
a drone flies for each, and the config that enables them."""

import math

import numpy as np
import pytest

from swarm.agents.orders import Action, Order, check_point, cruise_speed, steerable, taken
from swarm.config import load
from swarm.errors import ConfigError, RefusedError
from tests.integration.conftest import CONFIGS


def _cfg(**script):
    return load(CONFIGS / "script_lab.yaml", {"script": {"enabled": True, **script}})


def test_a_script_steers_only_the_drones_the_config_names():
    cfg = _cfg(drones=["cf1"])
    assert cfg.steerable == ["cf1"] and cfg.topology == "router"
    steerable(cfg, "cf1")
    with pytest.raises(RefusedError, match="'cf2' is not one a script may steer"):
        steerable(cfg, "cf2")
    with pytest.raises(RefusedError, match="no drone 'cf9'"):
        steerable(cfg, "cf9")
    assert _cfg().steerable == ["cf1", "cf2", "cf3"]
    assert load(CONFIGS / "swap_2.yaml").steerable == []


def test_the_config_names_a_bad_script_field():
    with pytest.raises(ConfigError, match=r"script.drones.0: no agent 'cf9'"):
        _cfg(drones=["cf9"])
    with pytest.raises(ConfigError, match="bounds_m"):
        _cfg(bounds_m=[[0, 0, 0], [0, 1, 1]])
    with pytest.raises(ConfigError, match="script.enabled: a script joins through the run's Zenoh router"):
        load(CONFIGS / "script_lab.yaml", {"network": {"topology": "mesh"}})


@pytest.mark.parametrize(
    ("x", "why"),
    [
        ([math.nan, 0.0, 1.0], "not finite"),
        ([0.0, math.inf, 1.0], "not finite"),
        ([3.5, 0.0, 1.0], "outside script.bounds_m"),
        ([0.0, 0.0, 2.6], "outside script.bounds_m"),
        ([0.0, 0.0, 0.1], "below its floor"),
        ([0.0, 1.0], "not a position"),
    ],
)
def test_a_goal_not_finite_out_of_bounds_or_below_the_floor_is_refused(x, why):
    with pytest.raises(RefusedError, match=why):
        check_point(_cfg(), "cf1", x)


def test_a_duration_becomes_a_cruise_speed_within_the_drones_own():
    me = _cfg().agent("cf1")  # speed_mps 1.0
    assert cruise_speed(me, 1.0, 2.0, None, 0.05) == pytest.approx(0.5)
    assert cruise_speed(me, 4.0, 1.0, None, 0.05) == pytest.approx(1.0)  # capped at its own
    assert cruise_speed(me, 0.001, 10.0, None, 0.05) == pytest.approx(0.05)  # at least the minimum
    assert cruise_speed(me, 1.0, None, 0.3, 0.05) == pytest.approx(0.3)
    assert cruise_speed(me, 1.0, None, None, 0.05) == 0.0  # its own
    for bad in (0.0, -1.0, math.nan):
        with pytest.raises(RefusedError):
            cruise_speed(me, 1.0, bad, None, 0.05)
    with pytest.raises(RefusedError, match="not both"):
        cruise_speed(me, 1.0, 1.0, 1.0, 0.05)


def test_what_a_drone_flies_for_each_order():
    cfg = _cfg()
    here = np.array([-1.0, 0.0, 0.4])
    up = taken(cfg, "cf1", Order(1, Action.TAKEOFF, np.array([9.0, 9.0, 1.0]), 0.0, 0.5), here)
    np.testing.assert_allclose(up.goal_w, [-1.0, 0.0, 1.0])  # straight up: only the height is taken
    assert up.speed_mps == 0.5
    go = taken(cfg, "cf1", Order(2, Action.GOTO, np.array([0.5, 0.5, 1.0]), 0.0, 7.0), here)
    np.testing.assert_allclose(go.goal_w, [0.5, 0.5, 1.0])
    assert go.speed_mps == 1.0  # never faster than its own speed_mps
    down = taken(cfg, "cf1", Order(3, Action.LAND, np.zeros(3)), np.array([0.2, 0.3, 1.0]))
    np.testing.assert_allclose(down.goal_w, [0.2, 0.3, cfg.agent("cf1").filter.floor_z_m])
    hold = taken(cfg, "cf1", Order(4, Action.STOP, np.zeros(3)), here)
    np.testing.assert_allclose(hold.goal_w, here)
    with pytest.raises(RefusedError, match="outside"):
        taken(cfg, "cf1", Order(5, Action.GOTO, np.array([0.0, 0.0, 9.0])), here)
