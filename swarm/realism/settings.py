"""The ``world.realism`` section of a scenario: which imperfections the simulated world has.

A named ``preset`` fills every field; any field given beside it overrides the preset's
value (``world: {realism: {preset: crazyflie_lab, sensing: {position_noise_m: 0.002}}}``;
``world: {realism: crazyflie_lab}`` is the preset alone). A bad value is refused with its
field named (``world.realism.sensing.position_noise_m: ...``).

* ``ideal``: today's perfect world: every effect off, agents act on ground truth, every
  message arrives at once. The default.
* ``crazyflie_lab``: a Crazyflie 2.1 lab, every value with its source in
  :data:`PRESETS`. Where Crazyswarm2 warns about a quantity (motion-capture rate, link
  latency, lost packets), the preset sits at the limit it accepts without a warning.
* ``crazyflie_lab_bad_day``: the lab on a bad day: ``crazyflie_lab`` with bodies lost to the
  motion capture in bursts, two like bodies' identities swapped, jumps, the markers off each
  drone's centre of mass, a sagging battery, eight drones on one radio with bursts of lost
  commands, and drafts that differ between drones (each value's source or assumption in
  :data:`PRESETS`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import Field, model_validator

from swarm.strict import Strict, merge

if TYPE_CHECKING:  # (imported where used: a config is read, and refused, without numba or scipy)
    from swarm.model import QuadParams
    from swarm.realism.aero import AeroParams
    from swarm.realism.comms import CommsModel, CommsParams, LinkParams, RadioParams
    from swarm.realism.motors import MotorParams
    from swarm.realism.plant import Plant, PlantParams
    from swarm.realism.sensing import Estimator, EstimatorParams, MocapParams, MocapSensor
    from swarm.realism.wind import WindParams
    from swarm.rotation import FloatArray

_F = Annotated[float, Field(strict=True, allow_inf_nan=False)]

PRESETS: dict[str, dict[str, Any]] = {
    "ideal": {},
    "crazyflie_lab": {
        # gym-pybullet-drones' measured Crazyflie models of drag and ground effect (swarm.realism.aero,
        # the coefficients' defaults); the downwash fitted to Neural-Swarm's Crazyflie flight logs
        # (downwash_model: measured; docs/design.md, "The model of the world")
        "aero": {"downwash": True, "drag": True, "ground_effect": True, "downwash_model": "measured"},
        "motors": {
            # CrazySim's Crazyflie model (model.sdf.jinja: timeConstantUp / timeConstantDown)
            "time_constant_up_s": 0.0125,
            "time_constant_down_s": 0.025,
            # assumed, no published spread: Bitcraze's PWM-to-thrust measurements show the thrust
            # at one command falling with the battery's voltage (4.0 V to 3.65 V over their table);
            # 5 % per drone stands for battery state and propeller wear between drones of a lab
            "thrust_coefficient_spread_fraction": 0.05,
            # assumed: the Crazyflie 2.1 takes off at 27 g (datasheet) and a lab's carry decks and
            # markers (Crazyswarm2's simulator uses 34 g); a lab that weighs its drones is off
            # by its batteries and markers, 3 % (about 1 g)
            "mass_spread_fraction": 0.03,
        },
        # indoor air: ASHRAE 55 counts air speeds above 0.2 m/s in an occupied zone as
        # "elevated"; a lab's drafts as Dryden gusts with 0.2 m/s at 2 sigma, no steady wind
        "wind": {"gust_std_mps": 0.1},
        "sensing": {
            "enabled": True,
            # Crazyswarm2 warns when motion capture runs outside 80-120 Hz (server.yaml,
            # warnings.motion_capture.warning_if_rate_outside): its middle
            "rate_hz": 100.0,
            # Merriaux et al., "A Study of Vicon System Positioning Performance", Sensors 2017:
            # errors below 2 mm in motion (2 sigma)
            "position_noise_m": 0.001,
            # the Crazyflie firmware's trust in an external attitude (crtp_localization_service.c:
            # extQuatStdDev = 4.5e-3)
            "attitude_noise_rad": 0.0045,
            # Crazyswarm2's warning limit for a link's latency (warnings.communication.max_unicast_latency: 10 ms)
            "latency_s": 0.010,
            # Crazyswarm2's warning limit for broadcasts received (min_broadcast_receive_rate: 0.9)
            "drop_fraction": 0.1,
            "estimator": {
                # at the start, the thrust-to-mass departure of a drone of this preset: g x the
                # motors' spreads combined, sqrt(0.05^2 + 0.03^2) = 5.8 % of g (at hover, 1 sigma)
                "initial_disturbance_std_mps2": 0.57,
                # a time constant of about 1 s (a step found 63 % in 1.04 s, 90 % in 2.19 s, with
                # 0.009 m/s^2 of noise from these frames): it follows what holds for seconds (thrust
                # and mass, a steady wind), not a neighbour's downwash passing over (docs/design.md:
                # 0.2, a 0.5 s time constant, flew one contact in the lab's liveness benchmark)
                "disturbance_walk_mps2": 0.1,
            },
        },
        "comms": {
            # Zenoh over a switched LAN (TCP: nothing lost), well under a tick: used the next tick,
            # as agents that compute concurrently see each other's states in realtime runs
            "state": {"delay_s": 0.001},
            "bundle": {"delay_s": 0.001},
            # the radio to the drone at Crazyswarm2's warning limits: 10 ms latency, 90 % acknowledged
            "command": {"delay_s": 0.010, "loss_fraction": 0.1},
        },
    },
}


PRESETS["crazyflie_lab_bad_day"] = merge(
    PRESETS["crazyflie_lab"],
    {
        "sensing": {
            # assumed (no published rate): a body lost once in 10 s of flight, for 0.3 s on average
            # (a hand or a neighbour between it and the cameras, a marker in a reflection);
            # MotionBuilder's and Vicon's documentation describe occlusion as bursts, not single frames
            "occlusion_rate_hz": 0.1,
            "occlusion_mean_s": 0.3,
            # assumed: two like marker sets swapped once in 20 s of a run, for half a second
            # (Preiss et al., ICRA 2017: why Crazyswarm tracks identities from the drones' motion)
            "swap_rate_hz": 0.05,
            "swap_duration_s": 0.5,
            # assumed: one frame in 500 jumps 5 cm (a ghost marker joins the set)
            "outlier_fraction": 0.002,
            "outlier_m": 0.05,
            # assumed: the markers' centroid 2 mm (1 sigma per axis) off each drone's centre of mass
            "centroid_offset_std_m": 0.002,
            # the agents' estimators refuse implausible frames (swarm.realism.sensing, the gate)
            "estimator": {"gate_sigmas": 5.0},
        },
        "motors": {
            # Bitcraze's PWM-to-thrust table (crazyflie-firmware src/drivers/src/motors.c) without
            # the firmware's battery compensation: 1.8 % of thrust a minute over a 7-minute flight;
            # batteries already flown up to 3 minutes at take-off
            "battery_sag_fraction_per_min": 0.018,
            "battery_start_spread_min": 3.0,
        },
        # assumed: drafts that differ between drones 0.3 m apart (a fan, a door, the neighbours'
        # wakes), and the body's drag (a drag coefficient of 1 on half its 92 x 29 mm side)
        "wind": {"relative_gust_std_mps": 0.2, "body_drag_area_m2": 1.3e-3},
        "comms": {
            # eight drones on one Crazyradio with Crazyswarm2's C++ link (its paper draft: 27 ms
            # median for 8), 10 % of commands lost and in bursts (a Gilbert-Elliott chain: a burst
            # of about 5 ticks begins on 2 % of ticks and loses half of its commands)
            "shared_radio": {"drones_per_radio": 8, "backend": "cpp"},
            "command": {"burst_enter_probability": 0.02, "burst_exit_probability": 0.2, "burst_loss_fraction": 0.5},
        },
    },
)


class AeroSettings(Strict):
    """Downwash, rotor drag and ground effect (:mod:`swarm.realism.aero`; defaults:
    gym-pybullet-drones' cf2x.urdf)."""

    downwash: bool = False
    drag: bool = False
    ground_effect: bool = False
    prop_radius_m: float = Field(2.31348e-2, gt=0, allow_inf_nan=False)
    downwash_peak_N: float = Field(2267.18, ge=0, allow_inf_nan=False)
    downwash_width_slope: float = Field(0.16, allow_inf_nan=False)
    downwash_width_offset_m: float = Field(-0.11, allow_inf_nan=False)
    # the downwash on a drone is at most this fraction of the collective thrust above (momentum theory)
    downwash_cap_thrust_fraction: float = Field(1.0, ge=0, allow_inf_nan=False)
    downwash_range_xy_m: float = Field(10.0, gt=0, allow_inf_nan=False)
    # the wake's radius at the rotors (cf2x.urdf: arm + prop radius) and its spreading rate (a turbulent round jet)
    downwash_wake_radius_m: float = Field(0.0628, gt=0, le=1, allow_inf_nan=False)
    downwash_wake_spread: float = Field(0.094, ge=0, le=1, allow_inf_nan=False)
    # gym_pybullet: upstream's fit above; measured: a widening wake fitted to Neural-Swarm's Crazyflie
    # flights (swarm.realism.aero.downwash_force_w, the data and the fit's range in its docstring)
    downwash_model: Literal["gym_pybullet", "measured"] = "gym_pybullet"
    downwash_measured_area_m2: float = Field(4.19e-3, ge=0, le=1, allow_inf_nan=False)
    downwash_measured_width0_m: float = Field(0.0352, gt=0, le=1, allow_inf_nan=False)
    downwash_measured_spread_m_per_m: float = Field(0.0439, ge=0, le=1, allow_inf_nan=False)
    downwash_measured_min_depth_m: float = Field(0.27, ge=0, le=10, allow_inf_nan=False)
    drag_xy_kg_per_rad: float = Field(9.1785e-7, ge=0, allow_inf_nan=False)
    drag_z_kg_per_rad: float = Field(10.311e-7, ge=0, allow_inf_nan=False)
    ground_effect_coeff: float = Field(11.36859, ge=0, allow_inf_nan=False)
    ground_z_m: float = Field(0.0, allow_inf_nan=False)  # m, world: the floor

    def params(self) -> AeroParams:
        from swarm.realism.aero import AeroParams

        return AeroParams(**self.model_dump())


class MotorSettings(Strict):
    """Rotor-speed lag and the drones' departures from their nominal model
    (:mod:`swarm.realism.motors`)."""

    time_constant_up_s: float = Field(0.0, ge=0, le=1, allow_inf_nan=False)
    time_constant_down_s: float = Field(0.0, ge=0, le=1, allow_inf_nan=False)
    # every drone's thrust coefficient (mass) is off by the offset, and each by a further seeded
    # normal fraction of standard deviation spread (clipped at 3 sigma)
    thrust_coefficient_offset_fraction: float = Field(0.0, gt=-0.5, le=1, allow_inf_nan=False)
    thrust_coefficient_spread_fraction: float = Field(0.0, ge=0, le=0.15, allow_inf_nan=False)
    mass_offset_fraction: float = Field(0.0, gt=-0.5, le=0.5, allow_inf_nan=False)
    mass_spread_fraction: float = Field(0.0, ge=0, le=0.15, allow_inf_nan=False)
    # battery sag: the thrust at one command falls by this fraction per minute of flight (uncompensated
    # Crazyflie: about 0.018, swarm.realism.motors); each drone's battery had flown a seeded uniform
    # [0, spread) minutes at takeoff
    battery_sag_fraction_per_min: float = Field(0.0, ge=0, le=0.1, allow_inf_nan=False)
    battery_start_spread_min: float = Field(0.0, ge=0, le=10, allow_inf_nan=False)

    def params(self) -> MotorParams:
        from swarm.realism.motors import MotorParams

        return MotorParams(**self.model_dump())


class WindSettings(Strict):
    """A steady wind and Dryden gusts (:mod:`swarm.realism.wind`)."""

    steady_mps: Annotated[list[_F], Field(min_length=3, max_length=3)] = [0.0, 0.0, 0.0]  # m/s, world
    gust_std_mps: float = Field(0.0, ge=0, le=20, allow_inf_nan=False)  # sigma_u = sigma_v
    gust_vertical_std_mps: float | None = Field(None, ge=0, le=20, allow_inf_nan=False)  # None: MIL-F-8785C ratio
    gust_length_m: float | None = Field(None, gt=0, le=1e4, allow_inf_nan=False)  # L_u = L_v; None: MIL-F-8785C
    gust_vertical_length_m: float | None = Field(None, gt=0, le=1e4, allow_inf_nan=False)  # L_w; None: MIL-F-8785C
    height_m: float = Field(1.0, gt=0, allow_inf_nan=False)  # where the MIL-F-8785C scales are taken
    airspeed_mps: float = Field(1.0, gt=0, allow_inf_nan=False)  # V: lengths L become times L / V
    gust_field: Literal["shared", "per_drone"] = "shared"  # one gust field for all drones, or one each
    # each drone's own gust on top of the field (isotropic, correlation length L_r; swarm.realism.wind)
    relative_gust_std_mps: float = Field(0.0, ge=0, le=20, allow_inf_nan=False)
    relative_gust_length_m: float = Field(0.3, gt=0, le=1e4, allow_inf_nan=False)
    # the body's C_d A [m^2] (quadratic drag; a Crazyflie: about 1.3e-3, assumed, swarm.realism.wind)
    body_drag_area_m2: float = Field(0.0, ge=0, le=1, allow_inf_nan=False)

    def params(self) -> WindParams:
        from swarm.realism.wind import WindParams

        s = self.steady_mps
        return WindParams(
            steady_w_mps=(s[0], s[1], s[2]),
            shared=self.gust_field == "shared",
            **self.model_dump(exclude={"steady_mps", "gust_field"}),
        )


class EstimatorSettings(Strict):
    """The agent's estimator (:class:`swarm.realism.sensing.Estimator`)."""

    latency_s: float | None = Field(None, ge=0, le=1, allow_inf_nan=False)  # what the agent assumes; None: exact
    position_noise_m: float | None = Field(None, gt=0, le=1, allow_inf_nan=False)  # None: the sensing's
    # the Crazyflie EKF's process noise (kalman_core_params_defaults.h: procNoiseAcc_xy, procNoiseAcc_z)
    process_accel_xy_mps2: float = Field(0.5, gt=0, le=100, allow_inf_nan=False)
    process_accel_z_mps2: float = Field(1.0, gt=0, le=100, allow_inf_nan=False)
    rate_filter_s: float = Field(0.02, ge=0, le=1, allow_inf_nan=False)  # low-pass of body rates from frames
    # the disturbance the agent estimates and takes off its command (swarm.realism.sensing): how fast
    # it may change (its random walk's std over 1 s) and how large it may be at the start; 0, 0: none
    disturbance_walk_mps2: float = Field(0.0, ge=0, le=100, allow_inf_nan=False)
    initial_disturbance_std_mps2: float = Field(0.0, ge=0, le=10, allow_inf_nan=False)
    # the innovation gate (swarm.realism.sensing.Estimator.frame): 0 sigmas, off (every frame fused);
    # its floor and the push it allows an unseen drone (assumed, EstimatorParams' docstrings)
    gate_sigmas: float = Field(0.0, ge=0, le=100, allow_inf_nan=False)
    gate_floor_m: float = Field(0.03, ge=0, le=10, allow_inf_nan=False)
    gate_accel_mps2: float = Field(1.0, ge=0, le=100, allow_inf_nan=False)
    gate_reset_s: float = Field(1.0, gt=0, le=60, allow_inf_nan=False)  # refusing every frame this long: restart


class SensingSettings(Strict):
    """Motion capture of the simulated drones and the agents' estimator
    (:mod:`swarm.realism.sensing`). ``enabled: false``: agents get ground truth."""

    enabled: bool = False
    rate_hz: float = Field(100.0, gt=0, le=10_000, allow_inf_nan=False)
    position_noise_m: float = Field(0.0, ge=0, le=1, allow_inf_nan=False)  # std of each coordinate
    attitude_noise_rad: float = Field(0.0, ge=0, le=0.5, allow_inf_nan=False)  # std of each rotation-vector component
    latency_s: float = Field(0.0, ge=0, le=1, allow_inf_nan=False)
    drop_fraction: float = Field(0.0, ge=0, lt=1, allow_inf_nan=False)
    # motion capture's failures (swarm.realism.sensing.MocapParams has each one's source or assumption);
    # all off by default. Bursts of occlusion: how often a drone is lost per second seen, their mean length
    occlusion_rate_hz: float = Field(0.0, ge=0, le=100, allow_inf_nan=False)
    occlusion_mean_s: float = Field(0.2, gt=0, le=60, allow_inf_nan=False)
    # the two closest drones swap identities: swaps per second of the run, how long each lasts
    swap_rate_hz: float = Field(0.0, ge=0, le=100, allow_inf_nan=False)
    swap_duration_s: float = Field(0.5, gt=0, le=60, allow_inf_nan=False)
    # a frame jumps by outlier_m in a random direction
    outlier_fraction: float = Field(0.0, ge=0, lt=1, allow_inf_nan=False)
    outlier_m: float = Field(0.1, ge=0, le=10, allow_inf_nan=False)
    # std of each coordinate of a drone's constant offset of its markers' centroid from its centre of mass
    centroid_offset_std_m: float = Field(0.0, ge=0, le=0.1, allow_inf_nan=False)
    estimator: EstimatorSettings = EstimatorSettings()

    def mocap_params(self) -> MocapParams:
        from swarm.realism.sensing import MocapParams

        return MocapParams(
            self.rate_hz,
            self.position_noise_m,
            self.attitude_noise_rad,
            self.latency_s,
            self.drop_fraction,
            occlusion_rate_hz=self.occlusion_rate_hz,
            occlusion_mean_s=self.occlusion_mean_s,
            swap_rate_hz=self.swap_rate_hz,
            swap_duration_s=self.swap_duration_s,
            outlier_fraction=self.outlier_fraction,
            outlier_m=self.outlier_m,
            centroid_offset_std_m=self.centroid_offset_std_m,
        )

    def estimator_params(self) -> EstimatorParams:
        from swarm.realism.sensing import EstimatorParams

        e = self.estimator
        return EstimatorParams(
            position_noise_m=e.position_noise_m if e.position_noise_m is not None else self.position_noise_m,
            latency_s=e.latency_s if e.latency_s is not None else self.latency_s,
            process_accel_xy_mps2=e.process_accel_xy_mps2,
            process_accel_z_mps2=e.process_accel_z_mps2,
            rate_filter_s=e.rate_filter_s,
            disturbance_walk_mps2=e.disturbance_walk_mps2,
            initial_disturbance_std_mps2=e.initial_disturbance_std_mps2,
            gate_sigmas=e.gate_sigmas,
            gate_floor_m=e.gate_floor_m,
            gate_accel_mps2=e.gate_accel_mps2,
            gate_reset_s=e.gate_reset_s,
        )


class LinkSettings(Strict):
    """One kind of message's delay and loss (:mod:`swarm.realism.comms`)."""

    delay_s: float = Field(0.0, ge=0, le=10, allow_inf_nan=False)
    jitter_s: float = Field(0.0, ge=0, le=10, allow_inf_nan=False)  # plus up to this, uniformly
    loss_fraction: float = Field(0.0, ge=0, lt=1, allow_inf_nan=False)  # in the good state, if bursts
    # loss in bursts (a Gilbert-Elliott chain, one step per message; swarm.realism.comms): the chance
    # per message of entering the bad state (0: no bursts), of leaving it, and the loss in it
    burst_enter_probability: float = Field(0.0, ge=0, le=1, allow_inf_nan=False)
    burst_exit_probability: float = Field(0.2, gt=0, le=1, allow_inf_nan=False)
    burst_loss_fraction: float = Field(0.0, ge=0, le=1, allow_inf_nan=False)

    def params(self) -> LinkParams:
        from swarm.realism.comms import LinkParams

        return LinkParams(**self.model_dump())


class RadioSettings(Strict):
    """Drones that share one Crazyradio: the command link's latency and loss grow with their
    number and command rate (:class:`swarm.realism.comms.RadioParams`). 1: the link as set."""

    drones_per_radio: int = Field(1, ge=1, le=64)
    backend: Literal["cpp", "cflib"] = "cpp"  # Crazyswarm2's C++ backend (broadcasts) or cflib (unicasts)
    command_rate_hz: float | None = Field(None, gt=0, le=10_000, allow_inf_nan=False)  # None: the control rate
    # assumed, uncalibrated: the loss each further drone adds at 100 Hz (Crazyswarm2 publishes no loss curve)
    loss_per_extra_drone: float = Field(0.0, ge=0, le=0.5, allow_inf_nan=False)

    def params(self) -> RadioParams:
        from swarm.realism.comms import RadioParams

        return RadioParams(**self.model_dump())


class CommsSettings(Strict):
    state: LinkSettings = LinkSettings()  # an agent's state to another agent
    bundle: LinkSettings = LinkSettings()  # the relay's bundle to an agent
    command: LinkSettings = LinkSettings()  # an agent's command to its drone
    shared_radio: RadioSettings = RadioSettings()  # the command link's Crazyradio, shared by drones_per_radio drones

    def params(self) -> CommsParams:
        from swarm.realism.comms import CommsParams

        return CommsParams(self.state.params(), self.bundle.params(), self.command.params(), self.shared_radio.params())


class RealismSettings(Strict):
    """``world.realism``: see the module docstring and docs/design.md, "The model of the world"."""

    preset: Literal["ideal", "crazyflie_lab", "crazyflie_lab_bad_day"] = "ideal"
    aero: AeroSettings = AeroSettings()
    motors: MotorSettings = MotorSettings()
    wind: WindSettings = WindSettings()
    sensing: SensingSettings = SensingSettings()
    comms: CommsSettings = CommsSettings()

    @model_validator(mode="before")
    @classmethod
    def _preset(cls, data: Any) -> Any:
        """The preset's values under the ones given (a bare name: the preset alone)."""
        if isinstance(data, str):
            data = {"preset": data}
        if isinstance(data, dict):
            name = data.get("preset", "ideal")
            if isinstance(name, str) and name in PRESETS:
                return merge(PRESETS[name], data)
        return data

    def plant_params(self) -> PlantParams:
        from swarm.realism.plant import PlantParams

        return PlantParams(self.aero.params(), self.motors.params(), self.wind.params())

    @property
    def ideal(self) -> bool:
        """Nothing is imperfect: the simulators may skip the plant, the sensing and the comms."""
        return self.plant_params().ideal and not self.sensing.enabled and self.comms.params().perfect

    def plant(self, nominal: Sequence[QuadParams], dt_s: float, seed: int) -> Plant:
        """The plant of the drones whose nominal airframes are ``nominal``, stepped every ``dt_s`` [s]."""
        from swarm.realism.plant import Plant

        return Plant(self.plant_params(), nominal, dt_s, seed)

    def mocap(self, n: int, seed: int) -> MocapSensor:
        from swarm.realism.sensing import MocapSensor

        return MocapSensor(self.sensing.mocap_params(), n, seed)

    def estimator(
        self, x0_w: FloatArray, q0: FloatArray, t0_s: float = 0.0, v0_w: FloatArray | None = None
    ) -> Estimator:
        """A drone's estimator, starting at ``x0_w`` (3,) [m, world] with attitude ``q0`` at
        ``t0_s`` [s], moving at ``v0_w`` (3,) [m/s, world] (None: at rest)."""
        from swarm.realism.sensing import Estimator

        return Estimator(self.sensing.estimator_params(), x0_w, q0, t0_s, v0_w)

    def comms_model(self, seed: int, tick_s: float) -> CommsModel:
        from swarm.realism.comms import CommsModel

        return CommsModel(self.comms.params(), seed, tick_s)
