"""Motors: a first-order lag of each rotor's speed, faster up than down, and drones whose
thrust coefficient and mass are off from the nominal model by a seeded per-drone factor.

The lag is Gazebo's ``MulticopterMotorModel`` (gz-sim ``src/systems/multicopter_motor_model``,
after RotorS' ``gazebo_motor_model``): the commanded rotor speed goes through a
``FirstOrderFilter`` with ``timeConstantUp`` while it rises and ``timeConstantDown`` while
it falls, discretised exactly for a command held over the step
(``w' = a w + (1 - a) w_cmd``, ``a = exp(-dt / tau)``). CrazySim's Crazyflie model keeps
12.5 ms up and 25 ms down (llanesc/crazyflie-simulation, branch ``sitl-release``,
``simulator_files/gazebo/models/crazyflie/model.sdf.jinja`` lines 229-230, at 61dd124):
the plugin's defaults (1/80 s, 1/40 s), not a Crazyflie measurement. Thrust is
``kf w^2`` (``swarm.model.QuadParams.kf`` [N/rpm^2]), so the speed lag is not a thrust lag:
a step from rest reaches 63 % of its speed at the time constant, 40 % of its thrust.

The filter keeps its nominal model: the plant's drone ``i`` makes ``thrust_factor[i]``
times the thrust its nominal model predicts for a rotor speed, and weighs
``mass_factor[i]`` times its nominal mass (inertia scaled alike, rotor limits kept).

Battery sag (off by default): the thrust at one command falls linearly with flight time,
drone i's factor ``max(0, 1 - r (a_i + t / 60 s))`` times ``thrust_factor[i]``, ``r``
(``battery_sag_fraction_per_min``) the fractional fall of the thrust coefficient per minute and
``a_i`` the minutes drone i's battery had already flown at takeoff (seeded, uniform in
``[0, battery_start_spread_min)``: batteries not all full). Source: Bitcraze's PWM-to-thrust
table (crazyflie-firmware ``src/drivers/src/motors.c``, above ``motorsCompensateBatteryVoltage``)
gives the voltage a motor needs for a thrust, ``v = -0.0006239 T^2 + 0.088 T`` [V, g], nearly
linear near a Crazyflie's hover (7-9 g a motor): at one PWM the thrust goes with the battery's
voltage to the power 1.06, so a LiPo's fall from 4.2 V to 3.7 V over a 7-minute flight (the
firmware's own comment: 4.2 V charged, 3.7 V mid-charge, 3 V empty) is about 12.5 % of the
thrust, 1.8 % per minute, without compensation. The firmware compensates when built with
``CONFIG_ENABLE_THRUST_BAT_COMPENSATED`` (``motorsCompensateBatteryVoltage`` scales the PWM by
the needed motor voltage over the measured battery voltage; ``powerDistributionCap`` in
``src/modules/src/power_distribution_quadrotor.c`` then caps the compensated value at full
PWM), on by default for the Crazyflie 2.x (Bitcraze's "Battery Compensation" page): there
``r`` stands for what the compensation misses (its fit, the filtered voltage's lag, the
voltage's dip under load), a fraction of the 1.8 %/min. Fitted range: 0 to about 2 %/min over
one battery (about 7 min); linear, so it leaves out the LiPo curve's knees (the fast fall at
the start and near empty) and the cap at full PWM.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from swarm.model import QuadParams
from swarm.realism.rng import Stream, normals, uniform, word
from swarm.rotation import FloatArray

RPM_TO_RAD_S = 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class MotorParams:
    time_constant_up_s: float = 0.0125
    time_constant_down_s: float = 0.025
    thrust_coefficient_offset_fraction: float = 0.0
    """Every drone's thrust coefficient is off by this fraction (a sweep's knob)."""
    thrust_coefficient_spread_fraction: float = 0.0
    """Standard deviation of a drone's own further fraction (seeded, clipped at 3 sigma)."""
    mass_offset_fraction: float = 0.0
    mass_spread_fraction: float = 0.0
    battery_sag_fraction_per_min: float = 0.0
    """The fall of the thrust at one command per minute of flight, a fraction of it at full charge."""
    battery_start_spread_min: float = 0.0
    """Drone i's battery had flown a seeded uniform ``[0, this)`` minutes at takeoff."""

    @property
    def lag(self) -> bool:
        return self.time_constant_up_s > 0.0 or self.time_constant_down_s > 0.0

    @property
    def sag(self) -> bool:
        return self.battery_sag_fraction_per_min > 0.0


def drone_factors(seed: int, n: int, offset: float, spread: float, stream: Stream) -> FloatArray:
    """(n,) factors ``1 + offset + spread z_i``, ``z_i`` a standard normal of (seed,
    stream, drone i) clipped to [-3, 3]: drone i's factor does not depend on n."""
    if spread == 0.0:
        return np.full(n, 1.0 + offset)
    z = np.clip(normals(seed, stream, np.arange(n), 0, 1)[:, 0], -3.0, 3.0)
    return 1.0 + offset + spread * z


def battery_start_min(seed: int, n: int, spread_min: float) -> FloatArray:
    """(n,) the minutes each drone's battery had flown at takeoff: ``spread_min`` times a
    uniform of (seed, :attr:`Stream.BATTERY_START`, drone i), in ``[0, spread_min)``; drone
    i's does not depend on n."""
    if spread_min == 0.0:
        return np.zeros(n)
    s, st = word(seed), np.uint64(int(Stream.BATTERY_START))
    u = np.array([uniform(s, st, np.uint64(i), np.uint64(0), np.uint64(0)) for i in range(n)])
    return spread_min * (1.0 - u)  # uniform is in (0, 1]


def plant_airframe(nominal: QuadParams, mass_factor: float) -> QuadParams:
    """The drone as built: mass and inertia times ``mass_factor``, the rotors' thrust
    limit ``f_max_N`` unchanged (a heavier drone does not get stronger motors). Raises
    :class:`swarm.errors.InputError` if it can no longer hover."""
    return replace(
        nominal,
        mass_kg=nominal.mass_kg * mass_factor,
        Ixx_kgm2=nominal.Ixx_kgm2 * mass_factor,
        Iyy_kgm2=nominal.Iyy_kgm2 * mass_factor,
        Izz_kgm2=nominal.Izz_kgm2 * mass_factor,
        thrust_to_weight=nominal.thrust_to_weight / mass_factor,
    )


class Motors:
    """The rotor speeds of n drones (state, (n, 4) rad/s) and their thrust.

    ``kf_N_per_rpm2`` (n,) is each drone's nominal thrust coefficient; the commanded
    thrust ``f_cmd`` [N] is the speed ``sqrt(f_cmd / kf)`` the nominal model asks for."""

    def __init__(
        self,
        p: MotorParams,
        dt_s: float,
        kf_N_per_rpm2: FloatArray,
        thrust_factor: FloatArray,
        f0_N: FloatArray,
        battery_start_min: FloatArray | None = None,
    ) -> None:
        self.p = p
        self.dt_s = dt_s
        self.k = 0
        self.kf_rad = np.asarray(kf_N_per_rpm2, float)[:, None] / RPM_TO_RAD_S**2  # N / (rad/s)^2
        self.thrust_factor = np.asarray(thrust_factor, float)
        n = len(self.thrust_factor)
        self.battery_start_min = np.zeros(n) if battery_start_min is None else np.asarray(battery_start_min, float)
        self._scale = self.thrust_factor[:, None]
        self._identity = not p.lag and not p.sag and bool(np.all(self.thrust_factor == 1.0))
        self.a_up = math.exp(-dt_s / p.time_constant_up_s) if p.time_constant_up_s > 0 else 0.0
        self.a_down = math.exp(-dt_s / p.time_constant_down_s) if p.time_constant_down_s > 0 else 0.0
        self.omega_rad_s = np.zeros((len(self.thrust_factor), 4))
        self.reset(f0_N)

    def reset(self, f_N: FloatArray) -> None:
        """Set every rotor to the speed that makes ``f_N`` (n, 4) [N] of nominal thrust."""
        self.omega_rad_s[:] = np.sqrt(np.maximum(np.asarray(f_N, float), 0.0) / self.kf_rad)

    def step(self, f_cmd_N: FloatArray) -> FloatArray:
        """Advance one step with ``f_cmd_N`` (n, 4) [N] held; the thrusts (n, 4) [N] the
        rotors make at its end. Without lag and with factors of exactly 1 it returns
        ``f_cmd_N`` itself (the ideal world, bit for bit)."""
        self.k += 1
        if self.p.sag:
            self._scale = (self.thrust_factor * self.battery_factor(self.k * self.dt_s))[:, None]
        if self._identity:
            self.omega_rad_s[:] = np.sqrt(np.maximum(f_cmd_N, 0.0) / self.kf_rad)
            return f_cmd_N
        w_cmd = np.sqrt(np.maximum(f_cmd_N, 0.0) / self.kf_rad)
        if self.p.lag:
            a = np.where(w_cmd > self.omega_rad_s, self.a_up, self.a_down)
            self.omega_rad_s = a * self.omega_rad_s + (1.0 - a) * w_cmd
            return self._scale * self.kf_rad * self.omega_rad_s**2
        self.omega_rad_s = w_cmd
        return self._scale * np.maximum(f_cmd_N, 0.0)

    def battery_factor(self, t_s: float) -> FloatArray:
        """(n,) the thrust at one command after ``t_s`` [s] of flight over the thrust at full
        charge: ``max(0, 1 - r (a_i + t / 60))`` (1 without sag)."""
        if not self.p.sag:
            return np.ones(len(self.thrust_factor))
        used_min = self.battery_start_min + t_s / 60.0
        return np.maximum(1.0 - self.p.battery_sag_fraction_per_min * used_min, 0.0)

    @property
    def omega_sum_rad_s(self) -> FloatArray:
        """(n,) the four rotor speeds summed [rad/s] (what rotor drag scales with)."""
        return self.omega_rad_s.sum(axis=1)
