"""The world pays for its compiled code before the realtime clock starts (swarm/world/main.py,
``World.warm_up``). With a cold kernel cache (the first run after an install or an edit)
the first tick used to compile the stacked onboard controller, the frame conversion of the
drone states and the closest-pair kernel: 1.5 to 2.5 s in which a real drone's
motion-capture frames, stamped on the wall clock, met simulated drones from the past
(``configs/mixed_sitl.yaml``: the real drones' rows went down to h = -0.09; -0.0006 once
warmed up). A kernel that the first tick calls with argument types ``warm_up`` did not use
gets a new compiled signature then: there must be none. Checked in a fresh interpreter, so
that no other test has loaded the kernels already."""

import json
import subprocess
import sys

PROBE = """
import json
import numpy as np
from swarm.config import load
from swarm.control import onboard_rotor_thrusts
from swarm.geometry import _min_pair_d2
from swarm.world.main import World
from swarm.sim.physics import _frames

kernels = (onboard_rotor_thrusts, _frames, _min_pair_d2)
world = World(load("configs/mixed_sitl.yaml"), "warm-up-test")  # real and simulated drones
world.warm_up()
before = {k.__name__: len(k.signatures) for k in kernels}
world.measure(0, 0.0)  # the first tick's measurement and metrics
thrusts = world.physics.rotor_thrusts(world.physics.read(world.flown), set(), True)  # its first substep
print(json.dumps(dict(
    before=before,
    after={k.__name__: len(k.signatures) for k in kernels},
    flown=len(world.flown),
    thrusts_ok=bool(thrusts.shape == (len(world.flown), 4) and np.isfinite(thrusts).all()),
)))
"""


def test_after_the_warm_up_the_first_tick_compiles_nothing():
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=300, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["flown"] == 2 and got["thrusts_ok"]
    assert all(n >= 1 for n in got["before"].values()), got  # each kernel loaded or compiled by the warm-up
    assert got["after"] == got["before"], got  # and the first tick needed no other signature
