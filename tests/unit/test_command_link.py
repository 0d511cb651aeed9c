"""The world's command link (``swarm.sim.stepper.Stepper.send``/``deliver``), with
``world.realism.comms.command``'s seeded delays: commands reach their drone in the order they
were sent, as over the Crazyradio (cflib sends one packet at a time and resends it until it is
acknowledged; the firmware's commander flies the setpoint that arrived last). A command whose
own delay would have it overtake an older one still on its way waits for it; on the tick both
are in, the newer is held."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.config import resolve
from swarm.realism.comms import LOST, MessageKind
from swarm.sim.stepper import Stepper

pytestmark = pytest.mark.unit


def _stepper(jitter_s: float) -> Stepper:
    raw = {
        "version": 1,
        "name": "link",
        "duration_s": 2.0,
        "time": {"mode": "lockstep", "control_hz": 100, "physics_hz": 300},
        "world": {"realism": {"comms": {"command": {"delay_s": 0.01, "jitter_s": jitter_s}}}},
        "agents": [{"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [1.0, 0.0, 1.0]}],
    }
    return Stepper(resolve(raw))


def test_a_late_command_holds_back_the_newer_one_and_the_newer_is_flown_once_both_are_in():
    stepper = _stepper(jitter_s=0.08)
    assert stepper.comms is not None
    fates = [stepper.comms.fate("cf1", "world", MessageKind.COMMAND, k) for k in range(200)]
    k = next(
        k for k in range(199) if LOST not in fates[k : k + 2] and fates[k] > fates[k + 1] + 1
    )  # sent at k and k+1, the second's own delay would bring it first
    old, new = np.array([0.0, 0.0, 0.0, 0.1]), np.array([0.0, 0.0, 0.0, 0.2])  # two setpoints, told apart by thrust
    stepper.send("cf1", old, k * 0.01, k)
    stepper.send("cf1", new, (k + 1) * 0.01, k + 1)
    drone = stepper.drones["cf1"]
    for tick in range(k, k + fates[k]):
        stepper.deliver(tick)
        assert drone.command is None, tick  # neither is in: the newer waits behind the older
    stepper.deliver(k + fates[k])
    assert drone.command is new and drone.command_t_s == pytest.approx((k + 1) * 0.01)
    stepper.close()
