"""Scenario files: a versioned YAML in the spirit of Crazyswarm2's ``crazyflies.yaml``.

Layers: ``defaults`` <- ``agent_types[type]`` <- the agent's own keys (later wins, dicts
merge key by key). Everything is validated before any process starts; an error names
the file, the field path and the reason (:class:`ConfigError`). Validation uses pydantic.
"""

from __future__ import annotations

import math
import os
from dataclasses import replace
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, NamedTuple

import numpy as np
import yaml
from pydantic import Field, PrivateAttr, ValidationError, field_validator, model_validator

from swarm.config_where import Loc, explain, key_lines
from swarm.crazyflie_fw import CMD_FULL, ThrustMap, pwm_per_newton, thrust_map
from swarm.errors import ConfigError
from swarm.model import CommandLevel, Layout, QuadParams
from swarm.planning import PlannerSettings
from swarm.realism.settings import RealismSettings
from swarm.safety.barriers import BarrierKind
from swarm.safety.filter import FilterConfig
from swarm.strict import Strict as _Strict
from swarm.strict import merge as _merge

if TYPE_CHECKING:
    from swarm.planner import PlanRequest

SCHEMA_VERSION = 1

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class TimeMode(StrEnum):
    LOCKSTEP = "lockstep"
    """The world steps only when every live agent has answered tick k (deterministic)."""
    REALTIME = "realtime"
    """The world runs on the wall clock; agents run on each new measurement."""


def _finite(v: Any) -> Any:
    vals = v if isinstance(v, list) else [v]
    for x in vals:
        if isinstance(x, float) and not math.isfinite(x):
            raise ValueError("must be finite")
    return v


class FilterSettings(_Strict):
    # the safety filter: a name registered in the entry-point group c3swarm.filters (swarm.plugins):
    # the built-in c3bf and hocbf, or an installed plugin's (docs/plugins.md)
    kind: str = BarrierKind.C3BF.value
    # a plugin's own options, validated by its Options model (the built-ins' settings are the fields below)
    options: dict[str, Any] = {}
    # ms of wall time a plugin's call may take before its command is replaced by the built-in C3BF's
    # (swarm.safety.external); null: one control period in a realtime run or on a real drone, none in lockstep
    budget_ms: float | None = Field(None, gt=0, allow_inf_nan=False)
    gamma: float = Field(1.0, gt=0)  # 1/s, class-K gain
    gamma_ho: float = Field(1.0, gt=0)  # m/s, HO-CBF gain
    rho: float = Field(1.0, gt=0, le=1)  # responsibility share of neighbour rows
    sensing_radius_m: float = Field(3.0, gt=0)
    margin_m: float = Field(0.02, ge=0)
    backend: Literal["daqp", "osqp"] = "daqp"
    enabled: bool = True  # false: fly the reference controller unfiltered (baseline)
    floor_z_m: float | None = Field(
        0.25, allow_inf_nan=False
    )  # m, world: the centre of mass stays above (HO-CBF row); null: no floor
    # C3BF: live rows at low relative speed (swarm.safety.barriers); false: the paper's rows, which freeze at rest
    live: bool = True
    # s: live rows' horizon allowance (docs/design.md, "The barrier math"); null: the cone alone
    horizon_s: float | None = Field(None, gt=0, allow_inf_nan=False)
    # s: the obstacle rows' own horizon allowance (not other agents'); null: the planner's
    # planner.obstacle_horizon_s on a path planned round walls, else horizon_s
    obstacle_horizon_s: float | None = Field(None, gt=0, allow_inf_nan=False)
    # m/s: live rows' velocity buffer (docs/design.md, "The barrier math"); 0: the rows alone
    buffer_mps: float = Field(0.1, ge=0, allow_inf_nan=False)
    # s: live neighbour rows' contact horizon (docs/design.md, "The barrier math"); 0: the cone alone
    contact_s: float = Field(0.0, ge=0, allow_inf_nan=False)
    # live rows leave the braking of a relative velocity free (swarm.safety.barriers, "Free braking")
    free_braking: bool = True
    # rows of other drones keep the airframes' keep-out ellipsoid (downwash: airframe.keep_out_*_m, plus
    # margin_m; swarm.safety.barriers, "Keep-out ellipsoid"); false: the sphere of the bodies' radii
    ellipsoid: bool = True
    # m: delay-aware rows (docs/design.md, "Delay"): a neighbour's row grows by at most this much over the
    # loop's expected delay, for which every agent of the swarm keeps its acceleration within the agreed bound
    # that gives it (swarm.tuning.agreed_accel_mps2); null: the airframe's whole acceleration (the row grows by it)
    delay_growth_m: float | None = Field(0.15, gt=0, le=10, allow_inf_nan=False)

    @field_validator("kind")
    @classmethod
    def _registered(cls, v: str) -> str:
        from swarm.plugins import PluginError, filter_class

        try:
            filter_class(v)
        except PluginError as exc:
            raise ValueError(str(exc)) from None
        return v

    @model_validator(mode="after")
    def _options(self) -> FilterSettings:
        from swarm.plugins import PluginError, filter_class, filter_options

        try:
            filter_options(filter_class(self.kind), self.options)
        except PluginError as exc:
            raise ValueError(str(exc)) from None
        return self

    @property
    def barrier(self) -> BarrierKind:
        """The built-in barrier the agent's own QP runs: the filter's, or for a plugin C3BF (its fallback)."""
        from swarm.plugins import filter_class
        from swarm.safety.external import barrier_of

        return barrier_of(filter_class(self.kind)) or BarrierKind.C3BF

    def filter_config(self, level: CommandLevel) -> FilterConfig:
        return FilterConfig(
            level=level,
            kind=self.barrier,
            gamma=self.gamma,
            gamma_ho=self.gamma_ho,
            rho=self.rho,
            sensing_radius_m=self.sensing_radius_m,
            margin_m=self.margin_m,
            backend=self.backend,
            floor_z_m=self.floor_z_m,
            live=self.live,
            horizon_s=self.horizon_s,
            obstacle_horizon_s=self.obstacle_horizon_s,
            buffer_mps=self.buffer_mps,
            contact_s=self.contact_s,
            free_braking=self.free_braking,
            ellipsoid=self.ellipsoid,
        )


class ControllerSettings(_Strict):
    """The reference controller: a name registered in the entry-point group c3swarm.controllers
    (``swarm.plugins``): the built-in path_tracker or an installed plugin's (docs/plugins.md)."""

    kind: str = "path_tracker"
    options: dict[str, Any] = {}  # a plugin's own options, validated by its Options model
    # ms of wall time a plugin's call may take before the built-in's reference replaces it
    # (swarm.reference); null: one control period in a realtime run or on a real drone, none in lockstep
    budget_ms: float | None = Field(None, gt=0, allow_inf_nan=False)

    @field_validator("kind")
    @classmethod
    def _registered(cls, v: str) -> str:
        from swarm.plugins import CONTROLLERS, PluginError, plugin_class

        try:
            plugin_class(CONTROLLERS, v)
        except PluginError as exc:
            raise ValueError(str(exc)) from None
        return v

    @model_validator(mode="after")
    def _options(self) -> ControllerSettings:
        from swarm.plugins import CONTROLLERS, PluginError, plugin_class, plugin_options

        try:
            plugin_options(plugin_class(CONTROLLERS, self.kind), self.options)
        except PluginError as exc:
            raise ValueError(str(exc)) from None
        return self


class AirframeSettings(_Strict):
    """Overrides of :class:`swarm.model.QuadParams` (Crazyflie 2.1 defaults)."""

    mass_kg: float | None = Field(None, gt=0)
    Ixx_kgm2: float | None = Field(None, gt=0)
    Iyy_kgm2: float | None = Field(None, gt=0)
    Izz_kgm2: float | None = Field(None, gt=0)
    l_m: float | None = Field(None, ge=0)
    rotor_to_rotor_m: float | None = Field(None, gt=0)
    thrust_to_weight: float | None = Field(None, gt=1)
    layout: Layout | None = None
    body_radius_m: float | None = Field(None, gt=0)
    # m: the keep-out ellipsoid between this drone's centre and another's, across and up and down
    # (downwash; default Crazyswarm's 0.12 and 0.30 between Crazyflies: swarm.model.QuadParams)
    keep_out_xy_m: float | None = Field(None, ge=0, allow_inf_nan=False)
    keep_out_z_m: float | None = Field(None, ge=0, allow_inf_nan=False)

    def params(self) -> QuadParams:
        return QuadParams(**{k: v for k, v in self.model_dump().items() if v is not None})


class TiebreakSettings(_Strict):
    """A deadlock answer that changes the reference, never the filter
    (``swarm.control.right_hand_bias``). On by default: a crowd at rest in exact symmetry
    (a circle swap) has every pair's relative reference on its cone's axis, and the
    filter's least change of a radial reference is then no motion; the right-hand bias
    gives every agent the same turning sense, a roundabout the live rows admit."""

    kind: Literal["none", "right_hand"] = "right_hand"
    trigger_m: float = Field(1.2, gt=0)  # m: other agents closer than this, and in front, count
    speed_mps: float = Field(0.5, gt=0)  # m/s: largest sideways bias; it turns the reference, never speeds it up

    @property
    def pair(self) -> tuple[float, float] | None:
        """(trigger [m], speed [m/s]) for ``swarm.control.reference_thrust``, or None."""
        return (self.trigger_m, self.speed_mps) if self.kind == "right_hand" else None


class ThrustCalibration(_Strict):
    """Collective thrust [N] to the Crazyflie's 16-bit thrust command, clipped to
    ``[0, max_pwm]``: the inverse of a :class:`swarm.crazyflie_fw.ThrustMap`. By default
    the firmware's own map for ``firmware`` (linear ``65535 / (4 THRUST_MAX)`` per newton
    for the battery-compensated releases, THRUST_MAX by release and propellers; quadratic
    for ``crazysim``, the software-in-the-loop build's simulated motors). To trim for your
    drones fit, by a hover test, either ``pwm_per_newton`` (and ``pwm_offset``): linear,
    ``pwm = offset + per_newton * F``; or ``pwm_to_thrust_a`` and ``_b``: quadratic, each
    motor ``a u^2 + b u`` [N] at ``u = (pwm - offset) / 65535`` (the firmware's
    ``quadSysId`` parameters)."""

    firmware: str = "2026.04"  # the firmware on the drones: 2025.09, 2025.12, 2026.04, 2026.08, crazysim
    propellers: Literal["standard", "thrust_upgrade"] = "standard"
    pwm_offset: float = 0.0
    pwm_per_newton: float | None = Field(None, gt=0)  # None: the firmware's thrust map
    pwm_to_thrust_a: float | None = Field(None, ge=0)  # N per motor at u^2, with pwm_to_thrust_b
    pwm_to_thrust_b: float | None = Field(None, gt=0)  # N per motor at u
    max_pwm: int = Field(60_000, gt=0, le=60_000)  # the RPYT commander caps at 60000 (crtp_commander_rpyt.c)

    @model_validator(mode="after")
    def _known(self) -> ThrustCalibration:
        if (self.pwm_to_thrust_a is None) != (self.pwm_to_thrust_b is None):
            raise ValueError("give pwm_to_thrust_a and pwm_to_thrust_b together")
        if self.pwm_per_newton is not None and self.pwm_to_thrust_b is not None:
            raise ValueError("give either pwm_per_newton or pwm_to_thrust_a and _b, not both")
        if self.pwm_per_newton is None and self.pwm_to_thrust_b is None:
            try:
                thrust_map(self.firmware, self.propellers)
            except ValueError as exc:
                raise ValueError(str(exc)) from None
        return self

    @property
    def map(self) -> ThrustMap:
        """The thrust map this calibration inverts."""
        if self.pwm_per_newton is not None:
            return ThrustMap(0.0, CMD_FULL / (4.0 * self.pwm_per_newton), self.pwm_offset)
        if self.pwm_to_thrust_a is not None and self.pwm_to_thrust_b is not None:
            return ThrustMap(self.pwm_to_thrust_a, self.pwm_to_thrust_b, self.pwm_offset)
        m = thrust_map(self.firmware, self.propellers)
        return ThrustMap(m.a_N, m.b_N, self.pwm_offset)

    @property
    def per_newton(self) -> float:
        """Thrust command per newton of collective thrust (a linear map's slope)."""
        if self.map.a_N != 0.0:
            raise ValueError("a quadratic thrust map has no single pwm_per_newton")
        return self.pwm_per_newton or pwm_per_newton(self.firmware, self.propellers)

    @property
    def max_thrust_N(self) -> float:
        """The largest collective thrust [N] a setpoint can ask of the drone."""
        return max(0.0, self.map.collective_N(self.max_pwm))


class CrazyflieSettings(_Strict):
    """A real Crazyflie 2.1 flown through cflib (``backend: crazyflie``)."""

    uri: str = Field(pattern=r"^(radio|usb|udp|tcp)://.+")  # e.g. radio://0/80/2M/E7E7E7E701
    mocap_body: str | None = None  # rigid-body name in the motion-capture system (default: the agent id)
    send_external_pose: bool = True  # relay the motion-capture pose to the drone's estimator
    thrust: ThrustCalibration = ThrustCalibration()
    takeoff_speed_mps: float = Field(0.3, gt=0)  # climbs at this speed from below start z
    land_speed_mps: float = Field(0.3, gt=0)
    landed_height_m: float = Field(0.08, gt=0)  # below this the motors are stopped when landing
    geofence_min_m: Vec3 = [-3.0, -3.0, -0.1]  # m, world: leaving this box is an emergency stop
    geofence_max_m: Vec3 = [3.0, 3.0, 2.5]
    link_timeout_s: float = Field(0.5, gt=0)  # no packet back from the drone for this long: link lost
    mocap_timeout_s: float = Field(0.2, gt=0)  # no measurement for this long: body lost
    expect_replies: bool = True  # the radio (and the test stand-in) answer every packet
    # when the agent dies (its connection to the link guard closes without a clean end):
    # estop: the guard sends the emergency stop (motors off now, locked until a reboot);
    # watchdog: the guard goes silent and the firmware's watchdog levels the drone out with
    # its last thrust after 500 ms and stops and locks it after 2 s (supervisor.c)
    on_agent_loss: Literal["estop", "watchdog"] = "estop"
    # from the end of the take-off on, the agent estimates the acceleration its drone has beyond its
    # commands (a thrust map off the motors, a sagging battery, a mass off the model) from the
    # motion capture and takes it off its thrust (swarm.build.real_drone_estimator); false: it does not
    disturbance_estimate: bool = True

    _fin = field_validator("geofence_min_m", "geofence_max_m")(_finite)


class PlannerConfig(_Strict):
    """The agent's reference path around the static obstacles (``swarm.planning``;
    docs/design.md, "Reference paths"). It shapes the reference only: the filter keeps
    the agent safe whatever the path."""

    # a name registered in the entry-point group c3swarm.planners (swarm.plugins): the built-in grid (planned
    # where the straight path is blocked) or none (straight), or an installed plugin's (swarm.planner)
    kind: str = "grid"
    options: dict[str, Any] = {}  # a plugin's own options, validated by its Options model
    resolution_m: float = Field(0.1, gt=0, le=1)  # m: the grid's cell
    clearance_m: float = Field(0.1, ge=0, le=2)  # m: kept from obstacles beyond the safety radius
    stall_s: float = Field(4.0, gt=0)  # s: replan from where the agent is after this long without progress
    # a long narrow passage wide enough for two is flown in its right-hand lane (opposite flows pass);
    # false: every narrow passage is taken in turn
    lanes: bool = True
    # s: on a path planned round walls, the filter's obstacle rows relax the cones of obstacles more
    # than about this far in time with the horizon allowance (filter.obstacle_horizon_s), stretched by
    # speed_mps / (0.4 m x filter.gamma) where that exceeds 1 (swarm.tuning.obstacle_horizon_s); None: never
    obstacle_horizon_s: float | None = Field(3.0, gt=0, allow_inf_nan=False)

    @field_validator("kind")
    @classmethod
    def _registered(cls, v: str) -> str:
        from swarm.plugins import PLANNERS, PluginError, plugin_class

        try:
            plugin_class(PLANNERS, v)
        except PluginError as exc:
            raise ValueError(str(exc)) from None
        return v

    @model_validator(mode="after")
    def _options(self) -> PlannerConfig:
        from swarm.plugins import PLANNERS, PluginError, plugin_class, plugin_options

        try:
            plugin_options(plugin_class(PLANNERS, self.kind), self.options)
        except PluginError as exc:
            raise ValueError(str(exc)) from None
        return self

    def settings(self) -> PlannerSettings:
        return PlannerSettings(resolution_m=self.resolution_m, clearance_m=self.clearance_m, lanes=self.lanes)


class AgentConfig(_Strict):
    """One quadrotor after layering."""

    id: str = Field(pattern=r"^[A-Za-z0-9_-]{1,32}$")
    start: Vec3  # m, world: initial position
    start_velocity: Vec3 = [0.0, 0.0, 0.0]  # m/s, world: initial velocity (level attitude)
    goal: Vec3 | None = None  # m, world
    waypoints: list[Vec3] | None = None  # m, world; the path flown after the start
    speed_mps: float = Field(1.0, gt=0)  # target speed along the path
    yaw_rad: float = 0.0
    command_level: CommandLevel = CommandLevel.ATTITUDE
    filter: FilterSettings = FilterSettings()
    controller: ControllerSettings = ControllerSettings()  # the reference controller (swarm.reference)
    tiebreak: TiebreakSettings = TiebreakSettings()
    planner: PlannerConfig = PlannerConfig()
    airframe: AirframeSettings = AirframeSettings()
    backend: Literal["sim", "crazyflie"] = "sim"  # simulated in PyBullet, or a real Crazyflie
    crazyflie: CrazyflieSettings | None = None  # required with backend: crazyflie
    _pair_keep_out_m: tuple[float, float] | None = PrivateAttr(None)  # ScenarioConfig._keep_out

    _fin = field_validator("start", "start_velocity", "goal", "speed_mps")(_finite)

    @model_validator(mode="after")
    def _path(self) -> AgentConfig:
        if self.goal is not None and self.waypoints is not None:
            raise ValueError("give either goal or waypoints, not both")
        if self.backend == "crazyflie":
            if self.crazyflie is None:
                raise ValueError("backend crazyflie needs a crazyflie: {uri: ...} section")
            if self.command_level is not CommandLevel.ATTITUDE:
                raise ValueError("a real Crazyflie is flown at command_level: attitude (roll, pitch, yaw rate, thrust)")
            lo, hi = np.asarray(self.crazyflie.geofence_min_m), np.asarray(self.crazyflie.geofence_max_m)
            for name, pt in [("start", self.start), *(("path", w) for w in self.path()[1:])]:
                if np.any(np.asarray(pt) < lo) or np.any(np.asarray(pt) > hi):
                    raise ValueError(f"{name} {pt} is outside the geofence {list(lo)} .. {list(hi)}")
        return self

    @model_validator(mode="after")
    def _filter_level(self) -> AgentConfig:
        from swarm.plugins import filter_class
        from swarm.safety.external import levels_of

        levels = levels_of(filter_class(self.filter.kind))
        if self.filter.enabled and self.command_level not in levels:
            raise ValueError(
                f"filter.kind: {self.filter.kind} filters the {', '.join(lv.value for lv in levels)} level, "
                f"not this agent's command_level {self.command_level.value}"
            )
        return self

    def plan_request(self) -> PlanRequest:
        """What its planner is asked (``swarm.planner.PlanRequest``): its configured path from its
        start, and its planner's kind, options and clearance, its safety radius."""
        from swarm.planner import PlanRequest

        params = self.airframe.params()
        return PlanRequest(
            self.id, self.planner.kind, dict(self.planner.options), params,
            params.body_radius_m + self.filter.margin_m, self.planner.clearance_m, np.asarray(self.path(), dtype=float),
        )  # fmt: skip

    def quad_params(self) -> QuadParams:
        """The airframe the filter and the world use. A real Crazyflie's thrust-to-weight
        is at most what its setpoint can ask (``crazyflie.thrust.max_thrust_N``): a
        guarantee computed with thrust the drone cannot give is none. Its keep-out is the
        largest of its swarm's airframes' (:meth:`ScenarioConfig._keep_out`)."""
        p = self.airframe.params()
        if self._pair_keep_out_m is not None:
            p = replace(p, keep_out_xy_m=self._pair_keep_out_m[0], keep_out_z_m=self._pair_keep_out_m[1])
        if self.crazyflie is None:
            return p
        ttw = self.crazyflie.thrust.max_thrust_N / p.weight_N
        return replace(p, thrust_to_weight=min(p.thrust_to_weight, ttw)) if ttw < p.thrust_to_weight else p

    @property
    def mocap_body(self) -> str:
        """Rigid-body name of a real drone in the motion-capture system."""
        return (self.crazyflie.mocap_body if self.crazyflie else None) or self.id

    def path(self) -> list[list[float]]:
        """Waypoints from the start: [start, ...waypoints] or [start, goal] or [start]."""
        if self.waypoints:
            return [list(self.start), *self.waypoints]
        return [list(self.start), list(self.goal)] if self.goal is not None else [list(self.start)]

    @property
    def final_goal(self) -> list[float]:
        return self.path()[-1]


class ObstacleConfig(_Strict):
    id: str = Field(pattern=r"^[A-Za-z0-9_-]{1,32}$")
    shape: Literal["sphere", "cylinder"]
    center: Vec3  # m, world, at t = 0 (a point on the axis for a cylinder)
    radius_m: float = Field(gt=0)
    velocity: Vec3 = [0.0, 0.0, 0.0]  # m/s, world, constant
    axis: Vec3 | None = None  # cylinder axis [world], any direction
    length_m: float = Field(20.0, gt=0)  # cylinder length in the physics world; the barrier treats it as infinite

    _fin = field_validator("center", "velocity", "axis")(_finite)

    @model_validator(mode="after")
    def _axis(self) -> ObstacleConfig:
        if self.shape == "cylinder":
            if self.axis is None or math.hypot(*self.axis) < 1e-9:
                raise ValueError("a cylinder needs a non-zero axis")
        elif self.axis is not None:
            raise ValueError("a sphere has no axis")
        return self


class TimeSettings(_Strict):
    mode: TimeMode = TimeMode.LOCKSTEP
    physics_hz: float = Field(240.0, gt=0)
    control_hz: float = Field(120.0, gt=0)  # must divide physics_hz
    lockstep_timeout_s: float = Field(5.0, gt=0, le=600)  # wall time the world waits for a late agent
    # a lockstep tick that waits longer than this share of lockstep_timeout_s is a stall: logged
    # with the agents it waited for, counted in the status (the progress bar) and metrics.json
    stall_warn_fraction: float = Field(0.2, gt=0, le=1)
    # realtime, rotor level (or late_command: brake): an older command is replaced by braking
    command_timeout_s: float = Field(0.05, gt=0)
    # realtime, attitude level: a late command as the Crazyflie firmware treats it (firmware:
    # held, levelled out with its thrust from 500 ms, motors off from 2 s), or brake: a hover
    # after command_timeout_s, kinder than any firmware, for a machine that stalls its agents
    late_command: Literal["firmware", "brake"] = "firmware"
    # realtime with real drones: how far [s] the world's clock may fall behind the wall clock.
    # Real drones do not wait, and their measurements are stamped on the wall clock: a world
    # further behind flies the ticks it lacks with the commands it holds, unpublished (counted
    # in metrics.json, skipped_ticks), and goes on towards the wall clock's tick; a real
    # drone's measurement is stamped at most this far after the world's physics. So no agent
    # hears of a real drone's state more than about twice this after the newest tick: well
    # inside the 1 s a neighbour's state may be ahead (swarm.net.statewire.Plausible.ahead_s),
    # so a late world never hides a real drone from the simulated agents.
    max_lag_s: float = Field(0.25, gt=0, le=0.5)
    start_timeout_s: float = Field(60.0, gt=0, le=3600)  # wall time to wait for every process to come up
    land_timeout_s: float = Field(15.0, gt=0, le=600)  # after the end: how long real drones get to land
    # swarm run: pin each process to one CPU (the world to the first, the recorder to the
    # last, agents round-robin). With more processes than cores, a process that stays on
    # one core keeps its caches and is not moved around by the scheduler, so more realtime
    # ticks are on time (docs/design.md, "One CPU per process")
    pin_cpus: bool = True

    @model_validator(mode="after")
    def _ratio(self) -> TimeSettings:
        ratio = self.physics_hz / self.control_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError(
                f"physics_hz ({self.physics_hz}) must be a whole multiple of control_hz ({self.control_hz})"
            )
        return self

    @property
    def substeps(self) -> int:
        return round(self.physics_hz / self.control_hz)


class TlsFiles(NamedTuple):
    root_ca: Path  # the certificate authority every process trusts
    certificate: Path  # this process's certificate (signed by root_ca; names network.host)
    private_key: Path
    own: bool  # a certificate of this process alone (made per run), naming it: it identifies the sender


class TlsSettings(_Strict):
    """Zenoh's TLS transport: links encrypted, each side proving who it is by certificate
    (``mutual``: the connecting side too). With no files given, ``swarm run`` (or ``swarm
    secrets``, to copy to other machines) makes a certificate authority and one certificate
    per process for ``network.host`` (``swarm.net.access.make_tls``): with ``mutual`` on, both
    ends of every link then know the other's name, and every message is checked against
    its sender's own keys. Files given: every process uses them."""

    enabled: bool = False
    root_ca: str | None = None  # PEM files; relative paths are from the working directory
    certificate: str | None = None
    private_key: str | None = None
    mutual: bool = True

    @model_validator(mode="after")
    def _all_or_none(self) -> TlsSettings:
        given = [f for f in (self.root_ca, self.certificate, self.private_key) if f]
        if given and len(given) != 3:
            raise ValueError("network.tls: give root_ca, certificate and private_key together, or none of them")
        return self

    def files(self, secrets: Path, user: str) -> TlsFiles:
        """The files process ``user`` uses: the given ones, or its own in ``secrets``."""
        if self.root_ca and self.certificate and self.private_key:
            return TlsFiles(Path(self.root_ca), Path(self.certificate), Path(self.private_key), False)
        tls = secrets / "tls"
        return TlsFiles(secrets / "ca.pem", tls / f"{user}.pem", tls / f"{user}.key", True)


class NetworkSettings(_Strict):
    """Zenoh. Default: peers on loopback, multicast scouting off, every process
    connecting to the world's listener (``port`` 0 lets ``swarm run`` pick a free one)."""

    mode: Literal["peer", "client"] = "peer"
    host: str = "127.0.0.1"
    port: int = Field(0, ge=0, le=65535)
    connect: list[str] = []  # extra endpoints (a router, other machines)
    # each run's processes authenticate with credentials of their own (Zenoh usrpwd) and may
    # publish only under their own keys (Zenoh access control; swarm.net.access); false: anyone
    # who reaches the ports may join the run
    access_control: bool = True
    tls: TlsSettings = TlsSettings()
    topology: Literal["auto", "mesh", "star", "router"] = "auto"
    """Which processes link to which (``swarm.net.transport.process_config``). ``mesh``: every
    process listens and Zenoh's gossip links every pair, so any peer that joins sees all
    traffic. ``star``: only the hubs listen, the world on ``port``, the recorder on
    ``port + 1``, the launcher on ``port + 2`` and, with ``neighbours.interest: bundle``,
    the bundle relay (``swarm router`` as a peer) on ``port + 3``; the others link to the
    hubs alone, with Zenoh's low-latency transport (a ``put`` is written to the socket by
    the calling thread), so every message takes one link and no process routes. Agents
    never hear each other directly: it needs ``neighbours.source: world``, or ``agents``
    with ``interest: bundle`` (or ``auto``), and peer mode without extra endpoints; an
    outside peer sees only the hubs' messages.
    ``router``: a Zenoh router (``swarm router``) listens on ``host:port`` and every
    other process is a client linked to it alone; the router forwards each message to
    the sessions subscribed to its key (and checks, per sender, what it may publish).
    ``auto``: star when those hold and ``host`` is loopback; else the router for
    ``neighbours.source: agents``; else mesh. Traffic between hosts takes the router
    (the netns test), where each link is one Zenoh client's."""


class FailureSettings(_Strict):
    neighbour_timeout_s: float = Field(0.1, gt=0)  # older: extrapolated, radius grows
    neighbour_growth_mps: float = Field(0.5, ge=0)  # radius growth per second of age
    neighbour_hard_limit_s: float = Field(1.0, gt=0)  # older, or liveliness gone: on_lost
    on_lost: Literal["keep_stopped", "drop"] = "keep_stopped"
    # what the world does with a dead agent's simulated drone: land it, stop its motors, or
    # (firmware) fly it as the Crazyflie firmware does with no setpoints: its last setpoint,
    # levelled out with its thrust from 500 ms, motors off from 2 s (swarm.crazyflie_fw)
    on_agent_death: Literal["land", "motors_off", "firmware"] = "land"


class NeighbourSettings(_Strict):
    """Where an agent learns the other agents' motion."""

    source: Literal["agents", "world"] = "agents"
    """``agents``: each agent publishes its state and subscribes to its neighbours' (the
    decentralised path of docs/design.md, "Neighbours"). ``world``: agents use the roster of
    measured body centres the world sends with every clock tick, as a motion-capture system
    would broadcast them (one message a tick that grows with N)."""
    interest: Literal["auto", "bundle", "cells", "all"] = "auto"
    """With ``source: agents`` (``auto``: ``bundle`` in a star or through a router when every
    drone is simulated, else ``cells``: docs/design.md, "Neighbours by bundles"): ``bundle``:
    each agent publishes its state on its own key and the run's bundle relay (``swarm
    router``) sends it, once per tick, one message with the states of the agents within its
    interest radius (``swarm.net.bundle``; needs ``network.topology: star`` or ``router``);
    ``cells``: states are published under the grid cell of the agent's body centre and each
    agent subscribes to the cells within its interest radius (``swarm.net.cells``), one message
    per neighbour; ``all``: every agent subscribes to every other agent's state (N - 1
    deliveries per agent and tick)."""
    margin_m: float = Field(0.5, gt=0, le=10)
    """Interest radius = the agent's sensing radius + this [m]: what it and a neighbour can
    close between a state's time and its use. The world names, with each tick, the live
    agents within the sensing radius + half of it (the ones a lockstep tick waits for)."""
    hysteresis_m: float = Field(0.5, gt=0, le=10)
    """Cells are declared for the interest radius + this [m], and declared again after a
    quarter of it of the agent's own motion (``swarm.net.cells.Interest``)."""
    cell_m: float | None = Field(None, gt=0, le=1000)
    """Side of a cell [m]; None: half the largest interest radius of the scenario."""


class DeadlockSettings(_Strict):
    """When the metrics call an agent deadlocked (``swarm.offline.metrics.deadlock_start``)."""

    speed_mps: float = Field(0.05, gt=0)  # slower than this ...
    hold_s: float = Field(2.0, gt=0)  # ... for this long, outside the goal tolerance


class MocapSettings(_Strict):
    """The motion-capture system the world relays for real drones (libmotioncapture:
    vicon, qualisys, optitrack, vrpn, ..., or ``mock`` for tests), or ``sitl``: software-
    in-the-loop Crazyflies (``swarm.world.sitl_cf``) that ``swarm run`` starts itself, one per
    real agent at its ``udp://127.0.0.1:PORT``, on the ground below its start with its yaw
    turned by ``options.yaw_offset_deg``, the release ``options.firmware``; their poses
    are the capture (``options.port``, 0 or absent: a free one)."""

    type: str = Field(pattern=r"^[a-z_]+$")
    hostname: str | None = None
    options: dict[str, str] = {}  # passed to motioncapture.connect as they are (e.g. mock: rigid_bodies)
    rate_hz: float = Field(100.0, gt=0)  # nominal frame rate: a longer gap counts dropped frames
    lost_after_s: float = Field(0.1, gt=0)  # a body not seen for this long is lost
    velocity_filter_s: float = Field(0.02, ge=0)  # time constant of the velocity / body-rate low-pass


MAX_DURATION_S = 24 * 3600.0  # a longer run is a typo (and would put the launcher's wall-clock limit out of reach)
MAX_CELLS = 512  # cell subscriptions an agent may hold (swarm.net.cells): each is a Zenoh subscriber
AGENTS_PER_CPU = 32  # limits.max_agents' default, per CPU of the machine (what has run: docs/benchmarks.md)


MonitorAction = Literal["warn", "slow", "hold", "land"]


class MonitorGrades(_Strict):
    """What the safety monitor does on each of its checks (``swarm.safety.monitor``): ``warn``
    counts and reports it, ``slow`` flies the reference at ``slow_fraction`` of its speed,
    ``hold`` holds the drone where it is, ``land`` lands it where it is (latched)."""

    estimate_std: MonitorAction = "slow"
    estimate_age: MonitorAction = "hold"
    estimate_lost: MonitorAction = "land"
    neighbour_std: MonitorAction = "slow"
    neighbour_age: MonitorAction = "slow"
    infeasible: MonitorAction = "warn"
    disturbance: MonitorAction = "land"
    world_late: MonitorAction = "hold"
    tick_overrun: MonitorAction = "warn"


class MonitorSettings(_Strict):
    """The safety monitor in every agent (``swarm.safety.monitor``, docs/design.md, "The safety
    monitor"): each tick it checks what the filter's margins assume and acts on a breach."""

    enabled: bool = True
    # m: the largest position deviation (one axis's standard deviation) an estimate may have;
    # null: std_envelope_factor times the steady-state one the noise margin was designed for
    # (swarm.tuning.design_std: a frame or two dropped in a row is within it, a gap of five is not)
    std_envelope_m: float | None = Field(None, gt=0, allow_inf_nan=False)
    std_envelope_factor: float = Field(1.5, ge=1, le=100, allow_inf_nan=False)
    estimate_age_s: float = Field(0.15, gt=0, le=10, allow_inf_nan=False)  # own estimate without a frame
    # s: ... past this it is lost (the estimator's gate takes any frame after 1 s: gate_reset_s)
    estimate_lost_s: float = Field(1.0, gt=0, le=10, allow_inf_nan=False)
    # s: a neighbour's state older than this; null: failure.neighbour_timeout_s
    neighbour_age_s: float | None = Field(None, gt=0, le=10, allow_inf_nan=False)
    infeasible_s: float = Field(0.25, gt=0, le=60, allow_inf_nan=False)  # no clean solve for this long
    disturbance_s: float = Field(0.5, gt=0, le=60, allow_inf_nan=False)  # disturbance at its clip this long
    world_late_s: float = Field(0.1, gt=0, le=10, allow_inf_nan=False)  # realtime: world behind the wall clock
    slow_fraction: float = Field(0.5, gt=0, le=1, allow_inf_nan=False)
    land_speed_mps: float = Field(0.3, gt=0, le=2, allow_inf_nan=False)
    settle_s: float = Field(0.5, ge=0, le=60, allow_inf_nan=False)  # an action holds this long after its breach
    grades: MonitorGrades = MonitorGrades()

    @model_validator(mode="after")
    def _ages(self) -> MonitorSettings:
        if self.estimate_lost_s <= self.estimate_age_s:
            raise ValueError("estimate_lost_s must be longer than estimate_age_s")
        return self


class Ros2Settings(_Strict):
    """The run seen and steered from ROS 2 (``swarm.ros2``, docs/ros2.md): a bridge process
    that publishes the swarm as ROS 2 topics the way rmw_zenoh maps them, through the
    run's Zenoh router, and takes a goal per drone and land / stop for all. Off by default
    (nothing starts, nothing is subscribed)."""

    enabled: bool = False
    domain_id: int = Field(0, ge=0, le=232)  # ROS_DOMAIN_ID: the first chunk of every key
    namespace: str = Field("", pattern=r"^$|^[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")  # "lab": /lab/cf1/pose
    frame_id: str = Field("world", pattern=r"^[A-Za-z_][A-Za-z0-9_/]*$")  # the fixed frame of poses and /tf
    rate_hz: float = Field(30.0, gt=0, le=1000)  # poses, velocities, /tf and /clock (at most one per tick)
    status_hz: float = Field(10.0, gt=0, le=1000)  # each drone's filter status and the obstacles' markers
    bag: bool = False  # write the run as a ROS 2 bag (MCAP, ros2msg/cdr) into <run>/ros2_bag at its end


class ScriptSettings(_Strict):
    """A run steered by a script (``swarm.script``, docs/scripting.md): its drones hold where
    they start until a script's client sends them take-off, go-to, land or stop; the run lasts
    until the script says it is done or ``duration_s`` (the limit) passes. Through the run's
    Zenoh router, whose access control lets the run's ``script`` user steer ``drones`` alone.
    Off by default (nothing is subscribed)."""

    enabled: bool = False
    drones: list[str] | None = None  # the drones a script may steer (None: every drone)
    # the volume a goal must lie in [m, world]: [[x_min, y_min, z_min], [x_max, y_max, z_max]]
    bounds_m: list[Vec3] = Field([[-10.0, -10.0, 0.0], [10.0, 10.0, 4.0]], min_length=2, max_length=2)
    min_speed_mps: float = Field(0.05, gt=0)  # a go-to's speed [m/s] from its duration is at least this

    @model_validator(mode="after")
    def _box(self) -> ScriptSettings:
        lo, hi = self.bounds_m
        if not all(math.isfinite(v) for v in (*lo, *hi)):
            raise ValueError("bounds_m: must be finite")
        if any(a >= b for a, b in zip(lo, hi, strict=True)):
            raise ValueError(f"bounds_m: {list(lo)} is not below {list(hi)} on every axis")
        return self


def machine_cpus() -> int:
    """CPUs this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


class LimitSettings(_Strict):
    """What the machine is trusted to carry; raise it knowingly."""

    max_agents: int | None = Field(None, gt=0)  # None: AGENTS_PER_CPU per CPU of this machine

    @property
    def agents(self) -> int:
        return self.max_agents or AGENTS_PER_CPU * machine_cpus()


class WorldSettings(_Strict):
    """The simulated world."""

    # its imperfections: downwash, drag, motors, wind, sensing, comms (swarm.realism.settings)
    realism: RealismSettings = RealismSettings()


class ScenarioConfig(_Strict):
    version: Literal[1]
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    seed: int = 0
    duration_s: float = Field(gt=0, le=MAX_DURATION_S)
    goal_tolerance_m: float = Field(0.15, gt=0)
    stop_when_all_reached: bool = True
    time: TimeSettings = TimeSettings()
    network: NetworkSettings = NetworkSettings()
    failure: FailureSettings = FailureSettings()
    neighbours: NeighbourSettings = NeighbourSettings()
    deadlock: DeadlockSettings = DeadlockSettings()
    agents: list[AgentConfig] = Field(min_length=1)
    obstacles: list[ObstacleConfig] = []
    mocap: MocapSettings | None = None  # required when any agent is a real Crazyflie
    gui: bool = False
    limits: LimitSettings = LimitSettings()
    ros2: Ros2Settings = Ros2Settings()
    script: ScriptSettings = ScriptSettings()
    world: WorldSettings = WorldSettings()
    monitor: MonitorSettings = MonitorSettings()

    @model_validator(mode="after")
    def _machine(self) -> ScenarioConfig:
        n, cap = len(self.agents), self.limits.agents
        if n > cap:
            raise ValueError(
                f"agents: {n} agents are more than this machine is trusted to run ({cap}: {AGENTS_PER_CPU} per CPU "
                f"on {machine_cpus()} CPUs); set limits.max_agents: {n} to try anyway"
            )
        return self

    @model_validator(mode="after")
    def _keep_out(self) -> ScenarioConfig:
        """A pair of drones keeps the larger of its two airframes' keep-out ellipsoids, per
        axis (``airframe.keep_out_xy_m``, ``keep_out_z_m``). An agent learns its neighbours'
        airframes only from this config, so every agent keeps the largest of its swarm's
        against every other drone (:meth:`AgentConfig.quad_params`): it holds each pair's, and
        a pair's two rows stay mirror images, as a shared condition needs."""
        par = [a.airframe.params() for a in self.agents]
        keep = (max(p.keep_out_xy_m for p in par), max(p.keep_out_z_m for p in par))
        for a in self.agents:
            a._pair_keep_out_m = keep
        return self

    @model_validator(mode="after")
    def _physical(self) -> ScenarioConfig:
        """Starts, goals and waypoints a drone can be at: above the floor, clear of the
        obstacles (at t = 0 for the start; static ones for the path) and of each other's
        safety radius (body radius plus the larger margin)."""
        radius = [a.airframe.params().body_radius_m for a in self.agents]
        for i, a in enumerate(self.agents):
            if a.start[2] < 0.0:
                raise ValueError(f"agents.{i}.start: {a.start} is below the floor (z < 0)")
            floor = a.filter.floor_z_m if a.filter.enabled else None
            for j, pt in enumerate(a.path()[1:]):
                field_ = "goal" if a.goal is not None else f"waypoints.{j}"
                if pt[2] < 0.0 or (floor is not None and pt[2] < floor):
                    raise ValueError(
                        f"agents.{i}.{field_}: {pt} is below the floor "
                        f"({'z < 0' if pt[2] < 0.0 else f'filter.floor_z_m {floor} m'})"
                    )
            for o in self.obstacles:
                keep = radius[i] + a.filter.margin_m
                if _surface_distance(o, a.start) < keep:
                    raise ValueError(f"agents.{i}.start: {a.start} {_too_near(o, a.start, keep)}")
                if any(o.velocity):
                    continue
                for j, pt in enumerate(a.path()[1:]):
                    if _surface_distance(o, pt) < keep:
                        field_ = "goal" if a.goal is not None else f"waypoints.{j}"
                        raise ValueError(f"agents.{i}.{field_}: {pt} {_too_near(o, pt, keep)}")
        for i, a in enumerate(self.agents):
            for j in range(i):
                b = self.agents[j]
                keep = radius[i] + radius[j] + max(a.filter.margin_m, b.filter.margin_m)
                for what, p, q in (("start", a.start, b.start), ("goal", a.final_goal, b.final_goal)):
                    if math.dist(p, q) < keep:
                        raise ValueError(
                            f"agents.{i}.{what}: {a.id} at {p} and {b.id} at {q} are closer than "
                            f"their safety radii ({keep:.3f} m)"
                        )
        return self

    @model_validator(mode="after")
    def _plugin_plans(self) -> ScenarioConfig:
        """Each agent's plugin planner (``swarm.planner``) plans its path now, so that one that
        raises or gives a path that cannot be flown stops the run before anything flies."""
        from swarm.planner import PlanError, is_builtin, plugin_path
        from swarm.planning import StaticObstacles
        from swarm.plugins import PLANNERS, plugin_class

        still = None
        for i, a in enumerate(self.agents):
            if is_builtin(plugin_class(PLANNERS, a.planner.kind)):
                continue
            still = still or StaticObstacles.of(list(self.obstacles))
            try:
                plugin_path(a.plan_request(), still)
            except PlanError as exc:
                raise ValueError(f"agents.{i}.planner.kind: {exc}") from None
        return self

    @model_validator(mode="after")
    def _sensing(self) -> ScenarioConfig:
        """Each filtered agent's sensing radius must show it a neighbour early enough to
        cancel their closing speed before the safety radius (docs/design.md, "What the rows
        guarantee", under "The barrier math"): ``R - r >= v_c^2 / (2 a) + v_c / control_hz``, with ``v_c`` the two
        agents' speeds added (head on), ``a = g tan(max tilt)`` the agent's own braking
        alone (the other may not brake) and one tick for its state to arrive; ``r`` the
        larger radius of the pair's keep-out (the ellipsoid's up and down, with
        ``filter.ellipsoid``)."""
        if len(self.agents) < 2:
            return self
        speed = [max(a.speed_mps, math.hypot(*a.start_velocity)) for a in self.agents]
        for i, a in enumerate(self.agents):
            if not a.filter.enabled:
                continue
            par = a.airframe.params()
            j = max((j for j in range(len(self.agents)) if j != i), key=lambda j: speed[j])
            other = self.agents[j].airframe.params().body_radius_m
            r = par.body_radius_m + other + a.filter.margin_m
            if a.filter.ellipsoid:  # the keep-out ellipsoid's radius up and down, where it is larger
                r = max(r, a.quad_params().keep_out_z_m + a.filter.margin_m)
            v_c = speed[i] + speed[j]
            need = v_c**2 / (2 * par.g_mps2 * math.tan(par.max_tilt_rad)) + v_c / self.time.control_hz
            if a.filter.sensing_radius_m - r < need:
                raise ValueError(
                    f"agents.{i}.filter.sensing_radius_m: {a.filter.sensing_radius_m} m cannot see "
                    f"{self.agents[j].id} in time: closing at {v_c:.2f} m/s a pair needs {need + r:.3f} m "
                    f"({need:.3f} m to brake and one tick, plus the safety radius {r:.3f} m)"
                )
        return self

    @model_validator(mode="after")
    def _real_drones(self) -> ScenarioConfig:
        real = [a.id for a in self.agents if a.backend == "crazyflie"]
        if real and self.mocap is None:
            raise ValueError(f"agents {real} are real Crazyflies: add a mocap section")
        if real and self.time.mode is not TimeMode.REALTIME:
            raise ValueError(f"agents {real} are real Crazyflies: time.mode must be realtime")
        return self

    @model_validator(mode="after")
    def _estimates_need_states(self) -> ScenarioConfig:
        if self.world.realism.sensing.enabled and self.neighbours.source == "world":
            raise ValueError(
                "world.realism.sensing: the agents act on motion-capture estimates, but neighbours.source: world "
                "gives them every drone's true state (the roster); use neighbours.source: agents"
            )
        rotors = [a.id for a in self.agents if a.backend == "sim" and a.command_level is CommandLevel.ROTORS]
        if self.world.realism.sensing.enabled and rotors:
            raise ValueError(
                f"agents.{rotors[0]}.command_level: rotors closes the attitude loop in the agent, and with "
                "world.realism.sensing it would close it on the motion capture's attitude, without a gyro: the "
                "drones crash (EXPERIMENTS.md section 5); use command_level: attitude (the firmware's loop), "
                "or world.realism.sensing.enabled: false"
            )
        return self

    @model_validator(mode="after")
    def _unique(self) -> ScenarioConfig:
        for what, items in (("agents", self.agents), ("obstacles", self.obstacles)):
            seen: set[str] = set()
            for it in items:
                if it.id in seen:
                    raise ValueError(f"duplicate {what} id {it.id!r}")
                seen.add(it.id)
        return self

    @model_validator(mode="after")
    def _cells(self) -> ScenarioConfig:
        """Cells so small that an agent would subscribe to more than MAX_CELLS of them."""
        if self.uses_cells:
            reach = max(self.interest_radius_m(a.id) for a in self.agents) + self.neighbours.hysteresis_m
            n = (2 * reach / self.cell_m + 1) ** 3 * math.pi / 6
            if n > MAX_CELLS:
                least = 2 * reach / ((MAX_CELLS * 6 / math.pi) ** (1 / 3) - 1)
                raise ValueError(
                    f"neighbours.cell_m: cells of {self.cell_m:g} m would make each agent subscribe to "
                    f"about {n:.0f} cells (at most {MAX_CELLS}); use {least:.2f} m or more"
                )
        return self

    @model_validator(mode="after")
    def _bundles(self) -> ScenarioConfig:
        if self.neighbours.source == "agents" and self.neighbours.interest == "bundle" and self.topology == "mesh":
            raise ValueError(
                "neighbours.interest: bundle needs the run's bundle relay (network.topology: star, router or auto), "
                "not mesh; use interest: cells or all"
            )
        return self

    @model_validator(mode="after")
    def _ros2(self) -> ScenarioConfig:
        """ROS 2 participants join through the run's router; agent ids are ROS name tokens."""
        if not self.ros2.enabled:
            return self
        if self.network.topology not in ("auto", "router"):
            raise ValueError(
                f"ros2.enabled: ROS 2 participants join through the run's Zenoh router; network.topology "
                f"{self.network.topology} has none (use router or auto)"
            )
        for i, a in enumerate(self.agents):
            if not a.id[0].isalpha() or "-" in a.id:
                raise ValueError(f"agents.{i}.id: {a.id!r} is not a ROS 2 name (a letter first, no '-') for ros2")
        return self

    @model_validator(mode="after")
    def _script(self) -> ScenarioConfig:
        """A script joins through the run's router and steers drones of the run."""
        if not self.script.enabled:
            return self
        if self.network.topology not in ("auto", "router"):
            raise ValueError(
                f"script.enabled: a script joins through the run's Zenoh router; network.topology "
                f"{self.network.topology} has none (use router or auto)"
            )
        ids = [a.id for a in self.agents]
        for i, d in enumerate(self.script.drones or []):
            if d not in ids:
                raise ValueError(f"script.drones.{i}: no agent {d!r} in this config (agents: {', '.join(ids)})")
        return self

    @model_validator(mode="after")
    def _star(self) -> ScenarioConfig:
        if self.network.topology == "star":
            why = self._star_blocker()
            if why:
                raise ValueError(f"network.topology: star {why}")
        return self

    def _star_blocker(self) -> str | None:
        """Why a star cannot link this scenario's processes, or None."""
        if self.neighbours.source == "agents" and not self._wants_bundles:
            return (
                "links agents only to the hubs; neighbours.source: agents needs interest: bundle (the relay's), "
                "or the mesh for interest: cells or all"
            )
        if self.network.mode != "peer" or self.network.connect:
            return "needs network.mode: peer and no network.connect endpoints"
        last = len(self.star_hubs) - 1
        if self.network.port > 65535 - last:
            return f"needs network.port <= {65535 - last} (the hubs listen on port to port + {last})"
        return None

    @property
    def _wants_bundles(self) -> bool:
        """``neighbours.interest`` is bundle, or auto in a swarm of simulated drones alone."""
        if self.neighbours.interest == "auto":
            return not any(a.backend == "crazyflie" for a in self.agents)
        return self.neighbours.interest == "bundle"

    @property
    def star_hubs(self) -> tuple[str, ...]:
        """The processes that listen in a star, hub i on ``network.port + i``: the world,
        the recorder, the launcher, and with agents as the neighbour source the bundle relay
        (``swarm.net.transport.links``)."""
        hubs = ("world", "recorder", "launcher")
        return (*hubs, "router") if self.neighbours.source == "agents" else hubs

    @property
    def topology(self) -> Literal["mesh", "star", "router"]:
        """``network.topology`` with ``auto`` resolved (see :class:`NetworkSettings`)."""
        if self.network.topology != "auto":
            return self.network.topology
        if self.ros2.enabled or self.script.enabled:  # ROS 2 participants and scripts join through the router
            return "router"
        loopback = self.network.host in ("localhost", "::1") or self.network.host.startswith("127.")
        if loopback and self._star_blocker() is None:
            return "star"
        return "router" if self.neighbours.source == "agents" else "mesh"

    @property
    def uses_cells(self) -> bool:
        """Agents publish their states by cell and subscribe to the cells near them."""
        return self.neighbours.source == "agents" and self.interest == "cells"

    @property
    def uses_bundles(self) -> bool:
        """The bundle relay (``swarm router``) bundles the agents' states for each agent
        (``swarm.net.bundle``)."""
        return self.neighbours.source == "agents" and self.interest == "bundle"

    @property
    def interest(self) -> Literal["bundle", "cells", "all"]:
        """``neighbours.interest`` with ``auto`` resolved: bundles in a swarm of simulated
        drones (through a star or a router), else cells."""
        if self.neighbours.interest != "auto":
            return self.neighbours.interest
        return "bundle" if self._wants_bundles and self.topology != "mesh" else "cells"

    @property
    def uses_ticks(self) -> bool:
        """The world sends each simulated agent its own tick message (its measurement, the
        obstacles and the neighbours near it) instead of the clock's roster."""
        return self.uses_cells or self.uses_bundles

    def interest_radius_m(self, agent_id: str) -> float:
        """The radius [m] within which ``agent_id`` hears every neighbour (swarm.net.cells)."""
        return self.agent(agent_id).filter.sensing_radius_m + self.neighbours.margin_m

    def near_radius_m(self, agent_id: str) -> float:
        """The radius [m] within which the world names ``agent_id``'s live neighbours."""
        return self.agent(agent_id).filter.sensing_radius_m + self.neighbours.margin_m / 2

    @property
    def cell_m(self) -> float:
        """Side [m] of the cells (``neighbours.cell_m``, or half the largest interest radius:
        an agent then hears the neighbours in about 1.6 times its interest disc, with
        about 130 cell subscriptions)."""
        return self.neighbours.cell_m or max(self.interest_radius_m(a.id) for a in self.agents) / 2

    @property
    def steerable(self) -> list[str]:
        """The drones a script may steer (``script.drones``, or every drone); none without a script."""
        if not self.script.enabled:
            return []
        return list(self.script.drones) if self.script.drones is not None else [a.id for a in self.agents]

    def agent(self, agent_id: str) -> AgentConfig:
        for a in self.agents:
            if a.id == agent_id:
                return a
        raise ConfigError(f"no agent with id {agent_id!r} (have {[a.id for a in self.agents]})")


def _too_near(o: ObstacleConfig, pt: list[float], keep_m: float) -> str:
    """Why point ``pt`` [m, world] cannot be where a drone starts or ends near obstacle ``o``,
    which it must stay ``keep_m`` from (body radius plus margin)."""
    d = _surface_distance(o, pt)
    if d < 0:
        return (
            f"is inside obstacle {o.id!r} ({-d:.3f} m below its surface): move it at least {keep_m:.3f} m "
            "outside (body radius + filter margin)"
        )
    return (
        f"is {d:.3f} m from obstacle {o.id!r}'s surface, inside its safety radius: move it at least "
        f"{keep_m:.3f} m off (body radius + filter margin)"
    )


def _surface_distance(o: ObstacleConfig, pt: list[float]) -> float:
    """Distance [m] from ``pt`` (world) to the surface of obstacle ``o`` at t = 0
    (negative inside); a cylinder is its infinite axis, as the barrier treats it."""
    d = np.asarray(pt, float) - np.asarray(o.center, float)
    if o.shape == "cylinder":
        ax = np.asarray(o.axis, float)
        ax = ax / np.linalg.norm(ax)
        d = d - (d @ ax) * ax
    return float(np.linalg.norm(d)) - o.radius_m


def resolve(raw: dict[str, Any], source: str = "<config>", lines: dict[Loc, int] | None = None) -> ScenarioConfig:
    """Layer defaults and agent types into each agent and validate everything. An error
    names the key as written (``defaults.filter.gama``, not the agents' merged copies) and,
    with the file's ``lines`` (``swarm.config_where.key_lines``), its line."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: the top level must be a mapping")
    original = raw
    raw = dict(raw)
    defaults = raw.pop("defaults", {}) or {}
    types = raw.pop("agent_types", {}) or {}
    if not isinstance(defaults, dict):
        raise ConfigError(f"{source}: defaults: must be a mapping")
    if not isinstance(types, dict):
        raise ConfigError(f"{source}: agent_types: must be a mapping")
    agents = raw.get("agents")
    limits = raw.get("limits")
    cap = limits.get("max_agents") if isinstance(limits, dict) else None
    cap = cap if isinstance(cap, int) and not isinstance(cap, bool) and cap > 0 else AGENTS_PER_CPU * machine_cpus()
    if isinstance(agents, list) and len(agents) > cap:  # before validating thousands of them
        raise ConfigError(
            f"{source}: agents: {len(agents)} agents are more than this machine is trusted to run "
            f"({cap}); set limits.max_agents: {len(agents)} to try anyway"
        )
    if isinstance(agents, list):
        layered = []
        for i, a in enumerate(agents):
            if not isinstance(a, dict):
                raise ConfigError(f"{source}: agents.{i}: must be a mapping")
            a = dict(a)
            tname = a.pop("type", None)
            if tname is not None and tname not in types:
                raise ConfigError(f"{source}: agents.{i}.type: unknown agent type {tname!r} (have {sorted(types)})")
            layered.append(_merge(_merge(defaults, types.get(tname, {}) if tname else {}), a))
        raw["agents"] = layered
    try:
        return ScenarioConfig.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError(explain(exc.errors(), original, source, lines or {}, ScenarioConfig)) from None
    except ValueError as exc:  # raised by our own models (e.g. QuadParams)
        raise ConfigError(f"{source}: {exc}") from None


_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
MAX_CONFIG_BYTES = 1 << 20  # a 64-agent scenario is about 10 KB; every process of a run reads the file


def load(path: str | Path, overrides: dict[str, Any] | None = None) -> ScenarioConfig:
    """Read, layer and validate a scenario file. ``overrides`` are merged on top
    (e.g. ``{"time": {"mode": "realtime"}}`` from the command line)."""
    p = Path(path)
    try:
        size = p.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise ConfigError(f"{p}: {size} bytes is larger than a scenario file may be ({MAX_CONFIG_BYTES} bytes)")
        data = p.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read ({exc.strerror})") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not a YAML text file (byte {exc.start} is not UTF-8)") from None
    if "\x00" in text:
        raise ConfigError(f"{p}: not a YAML text file (it holds NUL bytes)")
    try:
        raw = yaml.load(text, Loader=_YAML_LOADER)  # a safe loader (libyaml when present)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: not valid YAML ({exc})") from None
    if overrides:
        raw = _merge(raw if isinstance(raw, dict) else {}, overrides)
    cfg = resolve(raw, str(p), key_lines(text))
    for a in cfg.agents:  # build the physical parameters now, so their errors surface here
        try:
            a.airframe.params()
        except ValueError as exc:
            raise ConfigError(f"{p}: agents.{a.id}.airframe: {exc}") from None
    return cfg


def dump(cfg: ScenarioConfig) -> str:
    """The resolved config as YAML (what a run folder stores)."""
    return yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False)
