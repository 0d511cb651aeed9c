"""The plant: what a simulator adds to its rigid bodies each physics step.

:meth:`Plant.step` takes the drones' true states and the rotor thrusts their controllers
command, and returns the thrusts the rotors make (after the motors' lag and each drone's
thrust factor, and the battery's sag) and the extra force [N, world] and torque [N m, body]
of downwash, drag (in the wind: the rotors' and, if set, the body's) and ground effect.
State (rotor speeds, gust filters) is held in flat arrays, vectorised over drones.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from swarm.model import QuadParams, rotor_geometry
from swarm.realism.aero import AeroParams, downwash_force_w, drag_force_w, ground_effect
from swarm.realism.motors import MotorParams, Motors, battery_start_min, drone_factors, plant_airframe
from swarm.realism.rng import Stream
from swarm.realism.wind import Wind, WindParams, body_drag_force_w
from swarm.rotation import FloatArray


@dataclass(frozen=True)
class PlantParams:
    aero: AeroParams = AeroParams(downwash=False, drag=False, ground_effect=False)
    motors: MotorParams = MotorParams(time_constant_up_s=0.0, time_constant_down_s=0.0)
    wind: WindParams = WindParams()

    @property
    def ideal(self) -> bool:
        """Nothing acts: :meth:`Plant.step` returns the commanded thrusts and zeros."""
        m = self.motors
        return (
            not self.aero.any
            and not self.wind.any
            and not m.lag
            and not m.sag
            and self.wind.body_drag_area_m2 == 0.0
            and m.thrust_coefficient_offset_fraction == 0.0
            and m.thrust_coefficient_spread_fraction == 0.0
            and m.mass_offset_fraction == 0.0
            and m.mass_spread_fraction == 0.0
        )


class PlantStep(NamedTuple):
    """One step's result for n drones."""

    f_N: FloatArray  # (n, 4) N: the thrust each rotor makes
    force_w: FloatArray  # (n, 3) N, world, at the centre of mass: the sum of the three below
    torque_b: FloatArray  # (n, 3) N m, body
    downwash_w: FloatArray  # (n, 3) N, world
    drag_w: FloatArray  # (n, 3) N, world
    ground_w: FloatArray  # (n, 3) N, world
    wind_w: FloatArray  # (n, 3) m/s, world: the air's velocity at each drone


class Plant:
    """n drones as built (``nominal[i]`` is drone i's nominal airframe, the one its filter
    and controller keep), stepped every ``dt_s`` [s].

    :attr:`airframes` are the drones as built (mass and inertia times their mass factor):
    give them to the physics (PyBullet bodies, RK4) in place of the nominal ones.
    ``f0_N`` (n, 4) [N]: the rotors' thrust at the start (default: each nominal drone's
    hover thrust, as the simulators start their drones hovering)."""

    def __init__(
        self,
        p: PlantParams,
        nominal: Sequence[QuadParams],
        dt_s: float,
        seed: int,
        f0_N: FloatArray | None = None,
    ) -> None:
        n = len(nominal)
        self.p = p
        self.n = n
        self.dt_s = dt_s
        self.k = 0
        m = p.motors
        self.thrust_factor = drone_factors(
            seed, n, m.thrust_coefficient_offset_fraction, m.thrust_coefficient_spread_fraction, Stream.THRUST_FACTOR
        )
        self.mass_factor = drone_factors(seed, n, m.mass_offset_fraction, m.mass_spread_fraction, Stream.MASS_FACTOR)
        self.airframes = [
            a if f == 1.0 else plant_airframe(a, float(f)) for a, f in zip(nominal, self.mass_factor, strict=True)
        ]
        if f0_N is None:
            f0_N = np.array([[a.weight_N / 4.0] * 4 for a in nominal]).reshape(n, 4)
        self.battery_start_min = battery_start_min(seed, n, m.battery_start_spread_min) if m.sag else np.zeros(n)
        self.motors = Motors(
            m, dt_s, np.array([a.kf for a in nominal]), self.thrust_factor, f0_N, self.battery_start_min
        )
        self.wind = Wind(p.wind, n, dt_s, seed)
        self.rotor_xy_b = np.array([rotor_geometry(a)[0] for a in nominal]).reshape(n, 4, 2)
        self._zeros = np.zeros((n, 3))

    @property
    def t_s(self) -> float:
        """Time of the last step's end [s]."""
        return self.k * self.dt_s

    def step(self, x_w: FloatArray, v_w: FloatArray, R: FloatArray, f_cmd_N: FloatArray) -> PlantStep:
        """One physics step: the drones' true centres of mass ``x_w`` (n, 3) [m, world],
        velocities ``v_w`` (n, 3) [m/s, world], rotations ``R`` (n, 3, 3) body to world, and
        the commanded rotor thrusts ``f_cmd_N`` (n, 4) [N], held over the step.

        With :attr:`PlantParams.ideal` it returns ``f_cmd_N`` itself and zeros."""
        self.k += 1
        f = self.motors.step(f_cmd_N)
        wind_w = self.wind.step()
        a = self.p.aero
        dw = downwash_force_w(x_w, f.sum(axis=1), a) if a.downwash else self._zeros
        if a.drag:
            drag = drag_force_w(R, np.asarray(v_w, float) - wind_w, self.motors.omega_sum_rad_s, a)
        else:
            drag = self._zeros
        if self.p.wind.body_drag_area_m2 > 0.0:
            drag = drag + body_drag_force_w(np.asarray(v_w, float) - wind_w, self.p.wind.body_drag_area_m2)
        if a.ground_effect:
            ground, torque = ground_effect(x_w, R, f, self.rotor_xy_b, a)
        else:
            ground, torque = self._zeros, np.zeros((self.n, 3))
        return PlantStep(f, dw + drag + ground, torque, dw, drag, ground, wind_w)
