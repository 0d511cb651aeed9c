"""One C3BF-QP filter call: a Crazyflie at 1 m/s straight at a sphere 1.5 m ahead.

python examples/filter_call.py
"""

import numpy as np

from swarm.model import CommandLevel, QuadModel, QuadParams, QuadState
from swarm.safety.filter import FilterConfig, SafetyFilter
from swarm.safety.obstacles import ObstacleArrays


def main() -> None:
    model = QuadModel(QuadParams())  # Crazyflie 2.1
    filt = SafetyFilter(model, FilterConfig(level=CommandLevel.ATTITUDE))  # u = thrust vector [N, world]
    state = QuadState.hover([0.0, 0.0, 1.0])  # m, world
    state.v_w = np.array([1.0, 0.0, 0.0])  # m/s, world: towards the sphere
    sphere = ObstacleArrays.build([[1.5, 0.0, 1.0]], [0.2])  # centre [m, world], radius [m]
    u_ref = np.array([0.3, 0.0, model.params.weight_N])  # N, world: hover while pushing on towards it
    filt.filter(state, u_ref, sphere)  # the first call loads the compiled kernels (about a second)
    res = filt.filter(state, u_ref, sphere)
    print(
        f"status {res.status.value}, u = {np.round(res.u, 4).tolist()} N, h = {np.round(res.h, 4).tolist()}, "
        f"intervention {res.intervention:.4f} N, solved in {res.solve_time_s * 1e6:.0f} us"
    )


if __name__ == "__main__":
    main()
