"""The Crazyflie firmware's rules for the legacy RPYT setpoint, as its source states them
(bitcraze/crazyflie-firmware, tag 2026.08). Pure: numbers in, numbers out.

A client (``swarm.agents.crazyflie``) uses the encoding half; the software-in-the-loop stand-in
(``swarm.world.sitl_cf``) uses :class:`Firmware`, which applies every rule to the setpoints it
decodes, so a sign or scale error of the client shows in the stand-in's flight as it
would in a lab.

* Thrust lock (``src/modules/src/crtp_commander_rpyt.c``): ``thrustLocked`` starts true
  and is cleared only by a setpoint whose thrust is 0; while locked, and below
  ``MIN_THRUST``, the thrust is 0; above, it is capped at ``MAX_THRUST``.
* Yaw rate (same file): "legacy rate input is inverted": ``attitudeRate.yaw =
  -values->yaw``. cflib's ``Commander.send_setpoint`` sends the yaw rate as given and
  negates pitch, which the firmware copies, so a positive pitch of the caller tilts the
  thrust towards +x of the body and a positive yaw rate turns clockwise (z up).
* Thrust map (``src/platform/interface/platform_defaults_cf2.h``, ``src/drivers/src/motors.c``
  ``motorsCompensateBatteryVoltage``): with battery compensation, the Crazyflie 2.x
  default, each motor gives ``cmd / 65535 * THRUST_MAX``; the legacy power distribution
  adds the attitude terms around the thrust command, so the collective is
  ``4 * THRUST_MAX * thrust / 65535``. ``THRUST_MAX`` by release in :data:`THRUST_MAX_N`.
  CrazySim's software-in-the-loop build (``firmware: crazysim``) has no battery: its
  simulated motors are quadratic, ``a u^2 + b u`` per motor with ``u = cmd / 65535``
  (``src/modules/src/power_distribution_sitl.c``, :data:`CRAZYSIM`). :class:`ThrustMap`
  holds either.
* Supervisor (``src/modules/src/supervisor.c``, ``supervisor_state_machine.c``): flying
  means a motor above idle within the last 2 s (``IS_FLYING_HYSTERESIS_THRESHOLD``).
  While flying, a setpoint older than 500 ms (``COMMANDER_WDT_TIMEOUT_STABILIZE``) is
  levelled out: roll and pitch 0, yaw rate 0, the thrust kept; older than 2 s
  (``COMMANDER_WDT_TIMEOUT_SHUTDOWN``) the motors stop and the drone is locked. An
  emergency stop locks it too. Locked needs a reboot ("Locked, reboot required");
  tumbled while flying is crashed, which ``CMD_RECOVER_SYSTEM`` clears once upright.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

RPYT_MIN_THRUST = 1000  # crtp_commander_rpyt.c MIN_THRUST
RPYT_MAX_THRUST = 60000  # crtp_commander_rpyt.c MAX_THRUST
WDT_STABILIZE_S = 0.5  # supervisor.c COMMANDER_WDT_TIMEOUT_STABILIZE
WDT_SHUTDOWN_S = 2.0  # supervisor.c COMMANDER_WDT_TIMEOUT_SHUTDOWN
FLYING_HYSTERESIS_S = 2.0  # supervisor.c IS_FLYING_HYSTERESIS_THRESHOLD
TUMBLE_TILT_RAD = math.radians(60)  # supervisor.c SUPERVISOR_TUMBLE_CHECK_ACCEPTED_TILT_ACCZ ("60 degrees")

THRUST_MAX_N: dict[tuple[str, str], float] = {
    # (firmware release, propellers) -> THRUST_MAX [N per motor], platform_defaults_cf2.h
    ("2026.08", "standard"): 0.12,
    ("2026.08", "thrust_upgrade"): 0.18,
    ("2026.04", "standard"): 0.12,
    ("2026.04", "thrust_upgrade"): 0.18,
    ("2025.12", "standard"): 0.1125,
    ("2025.12", "thrust_upgrade"): 0.1625,
    ("2025.09", "standard"): 0.1125,
    ("2025.09", "thrust_upgrade"): 0.1625,
}
"""Releases whose battery-compensated thrust map is linear. Older releases use a nominal
table with a voltage model: calibrate ``pwm_per_newton`` by a hover test instead."""


CMD_FULL = 65535.0  # a thrust or PWM command's full scale (uint16)


@dataclass(frozen=True)
class ThrustMap:
    """A motor's thrust [N] of its 16-bit command ``cmd``: ``a u^2 + b u`` with
    ``u = (cmd - offset) / 65535`` (``a = 0``: linear). The legacy power distribution gives
    every motor the thrust command (plus attitude terms that cancel in the collective), so the
    collective thrust is four times a motor's."""

    a_N: float  # N per motor at u^2
    b_N: float  # N per motor at u
    offset: float = 0.0  # command at zero thrust

    def collective_N(self, cmd: float) -> float:
        """The collective thrust [N] of a thrust command."""
        u = (cmd - self.offset) / CMD_FULL
        return 4.0 * (self.a_N * u * u + self.b_N * u)

    def command(self, thrust_N: float) -> float:
        """The thrust command [unclipped, fractional] whose collective thrust is ``thrust_N``
        (a linear map extrapolates below zero thrust; a quadratic one takes the root with
        ``u >= 0`` and no less than zero thrust)."""
        if self.a_N == 0.0:
            return self.offset + CMD_FULL * thrust_N / (4.0 * self.b_N)
        per_motor = max(thrust_N, 0.0) / 4.0
        u = (-self.b_N + math.sqrt(self.b_N * self.b_N + 4.0 * self.a_N * per_motor)) / (2.0 * self.a_N)
        return self.offset + CMD_FULL * u


@dataclass(frozen=True)
class SitlAirframe:
    """CrazySim's simulated Crazyflie, as its firmware build states it."""

    thrust: ThrustMap  # power_distribution_sitl.c pwmToThrustA, pwmToThrustB (params quadSysId.*)
    thrust_to_torque_m: float  # power_distribution_sitl.c thrustToTorque: yaw torque [N m] per N of thrust
    arm_m: float  # platform_defaults_cf2.h ARM_LENGTH: centre to motor [m]
    mass_kg: float  # platform_defaults_cf2.h CF_MASS


CRAZYSIM = SitlAirframe(ThrustMap(0.091492681, 0.067673604), 0.005964552, 0.046, 0.027)
"""The simulated motors and frame of CrazySim's firmware (llanesc/crazyflie-firmware
``sitl-release``: ``src/modules/src/power_distribution_sitl.c``,
``src/platform/interface/platform_defaults_cf2.h``); ``tests/integration/test_firmware.py``
reads the parameters back from the running firmware."""

MOTOR_XY = ((1, -1), (-1, -1), (-1, 1), (1, 1))
"""Signs of each motor's (x forward, y left) position, M1..M4: front right, back right, back
left, front left (power_distribution_sitl.c ``powerDistributionForceTorque``: roll takes
from M1, M2; pitch from M1, M4)."""
MOTOR_YAW = (-1, 1, -1, 1)
"""Sign of each motor's yaw torque on the body, M1..M4: ``powerDistributionForceTorque``
lowers M1 and M3 for a positive (counter-clockwise) yaw torque."""


def thrust_map(firmware: str, propellers: str = "standard") -> ThrustMap:
    """The firmware's own thrust map: linear for the battery-compensated releases of
    :data:`THRUST_MAX_N`, quadratic for ``crazysim`` (:data:`CRAZYSIM`, standard propellers)."""
    if firmware == "crazysim" and propellers == "standard":
        return CRAZYSIM.thrust
    try:
        return ThrustMap(0.0, THRUST_MAX_N[(firmware, propellers)])
    except KeyError:
        known = ", ".join(sorted({f for f, _ in THRUST_MAX_N} | {"crazysim"}))
        raise ValueError(
            f"no thrust map for firmware {firmware!r} with {propellers} propellers "
            f"(known: {known}); give pwm_per_newton (or pwm_to_thrust_a and _b) from a hover test"
        ) from None


def pwm_per_newton(firmware: str, propellers: str = "standard") -> float:
    """Thrust command per newton of collective thrust for a release with a linear map."""
    m = thrust_map(firmware, propellers)
    if m.a_N != 0.0:
        raise ValueError(f"firmware {firmware!r} has a quadratic thrust map: no single pwm_per_newton")
    return CMD_FULL / (4.0 * m.b_N)


def collective_thrust_N(cmd: int, firmware: str, propellers: str = "standard") -> float:
    """The collective thrust [N] the firmware makes of a decoded RPYT thrust command."""
    return thrust_map(firmware, propellers).collective_N(cmd)


def wire_yaw_rate_dps(yaw_rate_ccw_dps: float) -> float:
    """The yaw rate to give cflib's ``send_setpoint`` for a counter-clockwise (z up) rate."""
    return -yaw_rate_ccw_dps


class SupervisorState(StrEnum):
    """The supervisor states that matter to a setpoint client (supervisor_state_machine.c)."""

    READY = "ready"  # pre-flight checks passed, motors allowed, not flying
    FLYING = "flying"
    LEVEL_OUT = "level_out"  # commander watchdog warning: level attitude, last thrust
    LANDED = "landed"
    CRASHED = "crashed"  # tumbled while flying: motors off until CMD_RECOVER_SYSTEM
    LOCKED = "locked"  # emergency stop or watchdog timeout: motors off until reboot


@dataclass
class Output:
    """What the firmware flies now: level ``roll``, ``pitch`` [rad] (positive pitch tilts
    the thrust towards +x of the body), yaw rate [rad/s, counter-clockwise], collective
    thrust [N]; all zero with the motors off."""

    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rate_radps: float = 0.0
    thrust_N: float = 0.0

    @property
    def motors_on(self) -> bool:
        return self.thrust_N > 0.0


class Firmware:
    """One Crazyflie's setpoint handling and supervisor, fed with decoded CRTP packets
    and stepped with the time [s]; :meth:`output` is what its controller tracks."""

    def __init__(self, firmware: str = "2026.04", propellers: str = "standard") -> None:
        self.firmware, self.propellers = firmware, propellers
        self.thrust_locked = True
        self.state = SupervisorState.READY
        self._sp = Output()
        self._sp_t = -math.inf  # time of the newest setpoint [s]
        self._thrust_t = -math.inf  # last time a motor was above idle [s]
        self.events: list[tuple[float, str]] = []  # (t, what) for tests and logs
        # the decoded setpoint as the firmware logs it (stabilizer.c, log group ctrltarget):
        # roll [deg], pitch [deg] (the wire's, i.e. cflib's negation of the caller's), yaw rate
        # [deg/s] (the wire's negated), thrust (the command after the lock and the cap)
        self.ctrltarget = {"roll": 0.0, "pitch": 0.0, "yaw": 0.0, "thrust": 0.0}

    def _to(self, state: SupervisorState, t: float) -> None:
        if state is not self.state:
            self.events.append((t, state.value))
            self.state = state

    def rpyt(self, t: float, roll_deg: float, pitch_wire_deg: float, yaw_wire_dps: float, thrust: int) -> None:
        """A legacy setpoint as it arrives (``<fffH``: cflib has negated pitch)."""
        if thrust == 0:
            self.thrust_locked = False
        cmd = 0 if self.thrust_locked or thrust < RPYT_MIN_THRUST else min(thrust, RPYT_MAX_THRUST)
        self.ctrltarget = {"roll": roll_deg, "pitch": pitch_wire_deg, "yaw": -yaw_wire_dps, "thrust": float(cmd)}
        self._sp = Output(
            math.radians(roll_deg),
            math.radians(-pitch_wire_deg),
            math.radians(-yaw_wire_dps),
            collective_thrust_N(cmd, self.firmware, self.propellers),
        )
        self._sp_t = t

    def stop(self, t: float) -> None:
        """The generic commander's stop setpoint: motors off (still a setpoint)."""
        self._sp, self._sp_t = Output(), t

    def emergency_stop(self, t: float) -> None:
        self._to(SupervisorState.LOCKED, t)

    def recover(self, t: float, tumbled: bool) -> bool:
        """``CMD_RECOVER_SYSTEM``: a crashed drone that is upright again may fly."""
        if self.state is SupervisorState.CRASHED and not tumbled:
            self._to(SupervisorState.READY, t)
            return True
        return self.state is not SupervisorState.CRASHED and self.state is not SupervisorState.LOCKED

    def step(self, t: float, tilt_rad: float = 0.0) -> Output:
        """The supervisor at time ``t`` [s] with the body's tilt [rad]; returns :meth:`output`.
        The transitions of supervisor_state_machine.c that a setpoint client meets:
        flying: watchdog timeout -> locked, tumbled -> crashed, watchdog warning -> level
        out, not flying -> landed; level out: timeout or tumbled -> locked (through
        free fall), a fresh setpoint -> flying (level out never lands); ready and
        landed: flying -> flying."""
        S = SupervisorState
        flying = t - self._thrust_t < FLYING_HYSTERESIS_S
        age = t - self._sp_t
        tumbled = tilt_rad > TUMBLE_TILT_RAD
        if self.state is S.FLYING:
            if flying and age > WDT_SHUTDOWN_S:
                self._to(S.LOCKED, t)
            elif flying and tumbled:
                self._to(S.CRASHED, t)
            elif flying and age > WDT_STABILIZE_S:
                self._to(S.LEVEL_OUT, t)
            elif not flying:
                self._to(S.LANDED, t)
        elif self.state is S.LEVEL_OUT:
            if age > WDT_SHUTDOWN_S or tumbled:
                self._to(S.LOCKED, t)
            elif age <= WDT_STABILIZE_S:
                self._to(S.FLYING, t)
        elif self.state in (S.READY, S.LANDED) and flying:
            self._to(S.FLYING, t)
        out = self.output()
        if out.motors_on:
            self._thrust_t = t
            if self.state in (S.READY, S.LANDED):
                self._to(S.FLYING, t)
        return out

    def output(self) -> Output:
        if self.state in (SupervisorState.LOCKED, SupervisorState.CRASHED):
            return Output()
        if self.state is SupervisorState.LEVEL_OUT:
            return Output(0.0, 0.0, 0.0, self._sp.thrust_N)
        return self._sp
