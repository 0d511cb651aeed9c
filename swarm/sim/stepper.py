"""The world's physics stepper: PyBullet bodies for the drones and obstacles, the command each
simulated drone holds, and the substeps that fly them (docs/design.md, "Processes and
messages"). No transport: the world process (``swarm.world.main``) hands it the commands it
takes and asks it for states and contacts.

A held command is flown as the drone would fly it: at the attitude level by the Crazyflie
firmware's attitude loop, younger than 500 ms as it is, then levelled out with its thrust, and
from 2 s motors off (its watchdog, ``swarm.crazyflie_fw``); at the rotor level its thrusts,
clipped to the rotor limits. The world's own fallbacks fly a drone without a fresh command in
realtime (braking to a hover) and a dead agent's drone (landing, motors off, or the firmware's
watchdog).

With ``world.realism`` (``swarm.realism``) the simulated drones are built as the plant's
airframes (their mass factors), their rotors make the plant's thrusts (lag, thrust factors)
and the plant's downwash, drag, ground effect and wind act on them each substep; motion
capture sees them at its frame rate (noise, latency, drops: :meth:`Stepper.frames`); a
command reaches its drone after its seeded delay, in the order sent, or never (:meth:`Stepper.send`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from swarm.config import ScenarioConfig, TimeMode
from swarm.control import AttitudeController, AttitudeSetpoint, OnboardController, OnboardGains, onboard_rotor_thrusts
from swarm.crazyflie_fw import WDT_SHUTDOWN_S, WDT_STABILIZE_S
from swarm.model import CommandLevel, QuadModel, QuadState
from swarm.realism.comms import LOST, DelayLine, MessageKind
from swarm.realism.plant import Plant
from swarm.realism.sensing import MocapFrame, MocapSensor
from swarm.sim.physics import DroneStates, PhysicsWorld

GROUND_IMPACT_MPS = 0.5
"""A drone touching the ground slower than this [m/s] stands, takes off or lands on it:
not a collision (a real drone takes off from the ground and lands on it)."""
_STOP = np.zeros(3)
_DESCEND = np.array([0.0, 0.0, -0.3])  # m/s, landing


@dataclass
class Drone:
    """What the physics holds for one drone."""

    model: QuadModel
    level: CommandLevel
    onboard: OnboardController
    att: AttitudeController
    dead: bool = False  # its agent is gone: the world's fallback flies it
    command: np.ndarray | None = None  # rotors: f (4,) N; attitude: roll, pitch, yaw rate, thrust
    command_t_s: float = 0.0  # sim time of the tick the held command answered
    braking_ticks: int = 0  # realtime: ticks flown on the braking fallback (command too old)
    yaw_sp_rad: float = 0.0  # the onboard controller's integrated yaw setpoint


def _setpoint(drone: Drone, t_s: float) -> tuple[float, ...] | np.ndarray:
    """Roll, pitch [rad], yaw rate [rad/s], thrust [N] at sim time ``t_s``: level hover
    before the agent's first command, then its newest command as the Crazyflie firmware
    flies it (swarm.crazyflie_fw): as it is while younger than 500 ms, levelled out with
    its thrust until 2 s, then motors off."""
    if drone.command is None:
        return (0.0, 0.0, 0.0, drone.model.params.weight_N)
    age = t_s - drone.command_t_s
    if age > WDT_SHUTDOWN_S:
        return (0.0, 0.0, 0.0, 0.0)
    if age > WDT_STABILIZE_S:
        return (0.0, 0.0, 0.0, float(drone.command[3]))
    return drone.command


def _velocity_hold(drone: Drone, state: QuadState, v_des_w: np.ndarray) -> np.ndarray:
    """The world's own fallback: fly level at ``v_des_w`` [m/s, world] with the thrust
    vector ``m (g e3 + 2 (v_des - v))``. Braking (a command too old, as the firmware's
    setpoint timeout) holds zero velocity; landing (a dead agent) descends."""
    p = drone.model.params
    F = p.mass_kg * (np.array([0.0, 0.0, p.g_mps2]) + 2.0 * (v_des_w - state.v_w))
    return drone.att.from_thrust_vector(state, F)


class Stepper:
    """The physics of one scenario: its drones (``names``; the simulated ones ``flown``, the
    real ones placed from motion capture) and obstacles in PyBullet. Not thread-safe; owned
    by the world process."""

    def __init__(self, cfg: ScenarioConfig, gui: bool = False) -> None:
        self.cfg = cfg
        self.sim = PhysicsWorld(cfg.time.physics_hz, gui=gui or cfg.gui)
        self.drones: dict[str, Drone] = {}
        self.real = {a.id for a in cfg.agents if a.backend == "crazyflie"}  # placed from motion capture
        self.firmware_death = cfg.failure.on_agent_death == "firmware"  # a dead agent's drone: the firmware's watchdog
        self.lockstep = cfg.time.mode is TimeMode.LOCKSTEP
        realism = cfg.world.realism
        flown_cfg = [a for a in cfg.agents if a.id not in self.real]
        nominal = [a.quad_params() for a in flown_cfg]
        plant = realism.plant(nominal, 1.0 / cfg.time.physics_hz, cfg.seed)
        self.plant: Plant | None = None if plant.p.ideal else plant  # the plant's extra forces, motors
        built = {a.id: QuadModel(f) for a, f in zip(flown_cfg, plant.airframes, strict=True)}  # (mass factors)
        sensing = realism.sensing.enabled
        self.mocap: MocapSensor | None = realism.mocap(len(flown_cfg), cfg.seed) if sensing else None
        self.comms = (
            None if realism.comms.params().perfect else realism.comms_model(cfg.seed, 1.0 / cfg.time.control_hz)
        )
        self.in_flight: DelayLine[tuple[str, np.ndarray, float]] = DelayLine()  # commands on their way
        self.due_k: dict[str, int] = {}  # per drone: the tick its newest command on its way arrives at
        self.commands_lost = 0
        self.seen: list[list[MocapFrame]] = [[] for _ in flown_cfg]  # per flown drone: frames not yet sent
        for a in cfg.agents:
            model = QuadModel(a.quad_params())
            self.sim.add_drone(
                a.id,
                built.get(a.id, model),
                np.asarray(a.start, float),
                a.yaw_rad,
                np.asarray(a.start_velocity, float),
                kinematic=a.id in self.real,
            )
            self.drones[a.id] = Drone(
                model, a.command_level, OnboardController(model, a.yaw_rad), AttitudeController(model)
            )
        for o in cfg.obstacles:
            if o.shape == "sphere":
                self.sim.add_sphere(o.id, np.asarray(o.center), o.radius_m, np.asarray(o.velocity))
            else:
                self.sim.add_cylinder(
                    o.id, np.asarray(o.center), np.asarray(o.axis), o.radius_m, o.length_m, np.asarray(o.velocity)
                )
        self.names = list(self.drones)
        self.flown = [a for a in self.names if a not in self.real]  # simulated drones: PyBullet flies them
        self.index = {a: i for i, a in enumerate(self.names)}
        self.flown_index = {a: i for i, a in enumerate(self.flown)}
        self.l_m = np.array([self.drones[a].model.params.l_m for a in self.names])  # body-centre offsets [m]
        self.radius_m = np.array([self.drones[a].model.params.body_radius_m for a in self.names])  # bounding radii [m]
        self.onboard_gains: dict[tuple[str, ...], OnboardGains] = {}  # drones -> their stacked gains

    @property
    def t_s(self) -> float:
        """Sim time [s] of the physics."""
        return self.sim.t_s

    def hold(self, name: str, command: np.ndarray, t_s: float) -> None:
        """Fly ``command`` (of the drone's level) from now, answering the tick at sim time ``t_s``."""
        d = self.drones[name]
        d.command, d.command_t_s = command, t_s

    def send(self, name: str, command: np.ndarray, t_s: float, k: int) -> None:
        """Agent ``name``'s command answering tick ``k`` at sim time ``t_s``: flown now, or with
        ``world.realism.comms.command`` from the tick its seeded fate delivers it at (:meth:`deliver`),
        or never (counted in ``commands_lost``). The link keeps the order the commands were sent
        in, as the Crazyradio's does: cflib's radio driver sends one packet at a time from its
        queue and resends it until it is acknowledged (``cflib/crtp/radiodriver.py``), and the
        firmware's commander flies whichever setpoint arrived last (``commanderSetSetpoint``,
        ``src/modules/src/commander.c``); so a command that comes late holds back the ones sent
        after it, and none overtakes an older one."""
        if self.comms is None:
            self.hold(name, command, t_s)
            return
        fate = self.comms.fate(name, "world", MessageKind.COMMAND, k)
        if fate != LOST:
            fate = max(fate, self.due_k.get(name, 0) - k)  # (behind the commands still on their way)
            self.due_k[name] = k + fate
        if not self.in_flight.put(k, fate, (name, command, t_s)):
            self.commands_lost += 1

    def deliver(self, k: int) -> None:
        """The commands on their way that reach their drones by tick ``k`` (``world.realism.comms``),
        in the order they were sent: the last one is held."""
        for name, command, t_s in self.in_flight.due(k):
            self.hold(name, command, t_s)

    def capture(self, t_s: float, fs: DroneStates) -> None:
        """Motion capture at sim time ``t_s`` [s] of the simulated drones (states ``fs``,
        ``flown`` order): the frames that have arrived by then are kept for :meth:`frames_of`
        (``world.realism.sensing``; nothing without it). Call it at every physics step's time."""
        if self.mocap is not None:
            for f in self.mocap.step(t_s, fs.x_w, fs.q):
                self.seen[f.drone].append(f)

    def frames_of(self, name: str) -> list[MocapFrame]:
        """The frames of simulated drone ``name`` that arrived since the last call."""
        i = self.flown_index[name]
        out, self.seen[i] = self.seen[i], []
        return out

    def read(self, names: list[str] | None = None) -> DroneStates:
        """Ground truth of the drones ``names`` (every drone when None)."""
        return self.sim.read_states(self.names if names is None else names)

    def warm_up(self) -> None:
        """Call every compiled kernel of a substep with the argument types the ticks use (a
        cold kernel otherwise compiles during the first tick), changing no drone."""
        for d in self.drones.values():
            st0 = QuadState.hover()
            d.onboard.rotor_thrusts(st0, AttitudeSetpoint(0.0, 0.0, 0.0, d.model.params.weight_N), self.sim.dt_s)
            d.att.from_thrust_vector(st0, np.array([0.0, 0.0, d.model.params.weight_N]))
            d.onboard.yaw_sp_rad = d.yaw_sp_rad
        fs = self.sim.read_states(self.flown)  # reading only: the drones do not move
        if self.flown:  # _onboard_thrusts' call, with its argument layouts, changing no drone
            n = len(self.flown)
            self._onboard_call(fs, list(range(n)), tuple(self.flown), np.zeros((n, 4)), np.zeros(n))

    def stale(self) -> set[str]:
        """Realtime: the drones whose held command is older than the timeout (a rotor
        command, or any with ``late_command: brake``): not flown."""
        if self.lockstep:
            return set()
        cfg, drones, t_s = self.cfg, self.drones, self.sim.t_s
        return {
            a
            for a in self.names
            if not drones[a].dead
            and drones[a].command is not None
            and (drones[a].level is CommandLevel.ROTORS or cfg.time.late_command == "brake")
            and t_s - drones[a].command_t_s > cfg.time.command_timeout_s
        }

    def substep(
        self, fs: DroneStates | None, first: bool, poses: dict[str, tuple[np.ndarray, np.ndarray]], v_tick_w: np.ndarray
    ) -> set[tuple[str, str]]:
        """One physics step: the real drones placed at their ``poses`` (x [m, world], q), every
        simulated drone flying its command from its states ``fs`` (``flown`` order; None: read
        now), PyBullet stepped. Returns the pairs of bodies in contact, a drone resting on or
        touching the ground slower than :data:`GROUND_IMPACT_MPS` (at the tick's velocities
        ``v_tick_w`` (n, 3), ``names`` order) left out."""
        if fs is None:
            fs = self.sim.read_states(self.flown)
        if not first:  # (the tick's own time was captured with its measurement)
            self.capture(self.sim.t_s, fs)
        for a, (x_w, q) in poses.items():
            self.sim.set_pose(a, x_w, q)
        f_N = self.rotor_thrusts(fs, self.stale(), first)
        if self.plant is not None:
            out = self.plant.step(fs.x_w, fs.v_w, fs.R, f_N)
            f_N = out.f_N
            self.sim.apply_external_all(self.flown, out.force_w, out.torque_b, fs)
        self.sim.apply_rotors_all(self.flown, f_N, fs)
        return {p for p in self.sim.step() if "ground" not in p or self._impact(p, v_tick_w)}

    def _impact(self, pair: tuple[str, str], v_w: np.ndarray) -> bool:
        """A ground contact of ``pair``'s drone at :data:`GROUND_IMPACT_MPS` or faster."""
        drone = pair[0] if pair[1] == "ground" else pair[1]
        i = self.index.get(drone)
        return i is None or float(np.linalg.norm(v_w[i])) >= GROUND_IMPACT_MPS

    def rotor_thrusts(self, fs: Any, stale: set[str], first_substep: bool) -> np.ndarray:
        """Rotor thrusts [N] (len(flown), 4): the onboard controller for attitude commands
        (and before the first command), the agent's thrusts for rotor commands, the world's
        own fallbacks for dead agents and stale commands."""
        drones, flown = self.drones, self.flown
        f_all = np.zeros((len(flown), 4))
        att = [
            i
            for i, a in enumerate(flown)
            if (not drones[a].dead or self.firmware_death)
            and a not in stale
            and (drones[a].level is CommandLevel.ATTITUDE or drones[a].command is None)
        ]
        if att:
            f_all[att] = self._onboard_thrusts(fs, att)
        attitude = set(att)
        for i, a in enumerate(flown):
            d = drones[a]
            if i in attitude:
                continue
            if d.dead:
                landed = self.cfg.failure.on_agent_death == "motors_off" or fs.x_w[i, 2] < 0.05
                if not landed:
                    f_all[i] = _velocity_hold(d, fs.state(i), _DESCEND)
            elif a in stale:
                f_all[i] = _velocity_hold(d, fs.state(i), _STOP)
                if first_substep:
                    d.braking_ticks += 1
            elif d.command is not None:  # rotor level: the agent's thrusts, held (`att` has the drones without one)
                f_all[i] = np.clip(d.command, 0.0, d.model.params.f_max_N)
        return f_all

    def _onboard_thrusts(self, fs: Any, att: list[int]) -> np.ndarray:
        """The onboard attitude controller of the drones ``att`` (indices into ``flown``),
        flying their setpoints as the firmware does (``_setpoint``), in one compiled call."""
        drones, dt_s = self.drones, self.sim.dt_s
        att_names = tuple(self.flown[i] for i in att)
        sp = np.array([_setpoint(drones[a], self.sim.t_s) for a in att_names])
        for a, yaw_rate in zip(att_names, sp[:, 2].tolist(), strict=True):
            drones[a].yaw_sp_rad += yaw_rate * dt_s
        return self._onboard_call(fs, att, att_names, sp, np.array([drones[a].yaw_sp_rad for a in att_names]))

    def _onboard_call(
        self, fs: Any, att: list[int], names: tuple[str, ...], sp: np.ndarray, yaw_sp_rad: np.ndarray
    ) -> np.ndarray:
        """The one compiled call of the onboard controller for the drones ``names`` (indices
        ``att`` into ``flown``): setpoints ``sp`` (k, 4) as ``_setpoint`` gives them (the yaw
        rate column unused), yaw setpoints ``yaw_sp_rad`` (k,); their gains stacked once per set."""
        gains = self.onboard_gains.get(names)
        if gains is None:
            gains = self.onboard_gains[names] = OnboardGains.stack([self.drones[a].onboard.gains for a in names])
        return onboard_rotor_thrusts(fs.q[att], fs.Omega_b[att], sp[:, 0], sp[:, 1], yaw_sp_rad, sp[:, 3], *gains)

    def close(self) -> None:
        self.sim.close()
