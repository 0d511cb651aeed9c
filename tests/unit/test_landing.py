"""Landing on request (swarm.landing): who is down, and what each stop signal does."""

from __future__ import annotations

import numpy as np

from swarm.config import AgentConfig
from swarm.landing import DOWN_ABOVE_M, Stop, down, landing_height_m, stop_for


def test_the_first_signal_lands_a_flying_swarm_and_the_second_stops_it_now():
    assert stop_for(0, flying=True) is Stop.FLY
    assert stop_for(1, flying=True) is Stop.LAND
    assert stop_for(2, flying=True) is Stop.NOW
    assert stop_for(1, flying=False) is Stop.NOW  # nothing flies yet: nothing to land


def test_down_means_low_and_slow_for_every_drone():
    land_z = np.array([0.25, 0.05])
    x = np.array([[0.0, 0.0, 0.25 + DOWN_ABOVE_M - 1e-3], [1.0, 0.0, 0.05]])
    assert down(x, np.zeros((2, 3)), land_z)
    assert not down(x + [0.0, 0.0, 0.01], np.zeros((2, 3)), land_z)  # one too high
    assert not down(x, np.array([[0.0, 0.0, -0.3], [0.0, 0.0, 0.0]]), land_z)  # one still descending
    assert down(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))  # no simulated drone


def test_a_simulated_drone_lands_to_its_filters_floor():
    me = AgentConfig(id="cf1", start=[0, 0, 1], goal=[1, 0, 1])
    assert landing_height_m(me) == me.filter.floor_z_m
    off = me.model_copy(update={"filter": me.filter.model_copy(update={"floor_z_m": None})})
    assert landing_height_m(off) == 0.05
