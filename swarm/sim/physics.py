"""PyBullet backend: drones as rigid bodies driven by rotor thrusts, kinematic obstacles,
a ground plane, and contacts. DIRECT mode by default (no display), GUI on request.

Each drone's base frame is its centre of mass (PyBullet's quaternions are scalar-last,
the project's order, see :mod:`swarm.rotation`). Rotor thrusts act at the rotor
positions along body z, plus the yaw reaction torque; mass and the inertia diagonal
are the model's. The collision shape is a flat cylinder of the airframe's bounding
radius centred ``l`` above the centre of mass (the body centre the barriers use, ``swarm.model.body_centre``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as pb
from numba import njit

from swarm.model import QuadModel, QuadState
from swarm.rotation import E3, FloatArray, quat_to_R_into


@dataclass
class Body:
    name: str
    uid: int
    kind: str  # "drone" | "obstacle" | "ground"


def _quat_z_to(axis: FloatArray) -> list[float]:
    """Scalar-last quaternion rotating +z onto ``axis``."""
    a = axis / np.linalg.norm(axis)
    c = float(a[2])
    if c > 1 - 1e-12:
        return [0.0, 0.0, 0.0, 1.0]
    if c < -1 + 1e-12:
        return [1.0, 0.0, 0.0, 0.0]
    v = np.cross(E3, a)
    s = math.sqrt((1 + c) * 2)
    return [v[0] / s, v[1] / s, v[2] / s, s / 2]


@njit(cache=True)
def _frames(a):
    """Rotations body to world (n, 3, 3) and body rates (n, 3) [rad/s, body] of rows
    ``a`` = (position, scalar-last quaternion, velocity, angular velocity [world])."""
    n = a.shape[0]
    R = np.empty((n, 3, 3))
    Om = np.empty((n, 3))
    for i in range(n):
        quat_to_R_into(a[i, 3:7], R[i])
        for k in range(3):  # R^T omega_w
            Om[i, k] = R[i, 0, k] * a[i, 10] + R[i, 1, k] * a[i, 11] + R[i, 2, k] * a[i, 12]
    return R, Om


@dataclass
class DroneStates:
    """Ground truth of several drones at once, stacked in the order they were asked for."""

    x_w: FloatArray  # (n, 3) m, world: centre of mass
    v_w: FloatArray  # (n, 3) m/s, world
    q: FloatArray  # (n, 4) scalar-last, body to world
    Omega_b: FloatArray  # (n, 3) rad/s, body
    R: FloatArray  # (n, 3, 3) body to world

    def state(self, i: int) -> QuadState:
        return QuadState(self.x_w[i], self.v_w[i], self.q[i], self.Omega_b[i])


class PhysicsWorld:
    """One PyBullet client. Not thread-safe; owned by the world process."""

    def __init__(self, physics_hz: float, g_mps2: float = 9.81, gui: bool = False) -> None:
        self.client = pb.connect(pb.GUI if gui else pb.DIRECT)
        self.dt_s = 1.0 / physics_hz
        pb.setGravity(0, 0, -g_mps2, physicsClientId=self.client)
        pb.setTimeStep(self.dt_s, physicsClientId=self.client)
        pb.setPhysicsEngineParameter(deterministicOverlappingPairs=1, physicsClientId=self.client)
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=self.client)
        ground = pb.createMultiBody(0, plane, physicsClientId=self.client)
        self.bodies: dict[int, Body] = {ground: Body("ground", ground, "ground")}
        self.drones: dict[str, int] = {}
        self._mixer: dict[str, FloatArray] = {}  # per drone: B, [T, tau] = B f
        self._mixer_stacks: dict[tuple[str, ...], FloatArray] = {}  # drone names -> (n, 4, 4)
        self.obstacles: dict[str, tuple[int, FloatArray, FloatArray]] = {}  # id -> uid, c0, velocity
        self.kinematic: set[str] = set()  # drones placed from motion capture
        self.t_s = 0.0

    # --- building -------------------------------------------------------------------
    def add_drone(
        self,
        name: str,
        model: QuadModel,
        start_w: FloatArray,
        yaw_rad: float = 0.0,
        velocity_w: FloatArray | None = None,
        kinematic: bool = False,
    ) -> None:
        """A drone body. ``kinematic``: a real drone, placed by :meth:`set_pose` from motion
        capture every step (mass 0 to PyBullet: it pushes, is never pushed)."""
        p = model.params
        shape = pb.createCollisionShape(
            pb.GEOM_CYLINDER,
            radius=p.body_radius_m,
            height=0.03,
            collisionFramePosition=[0, 0, p.l_m],
            physicsClientId=self.client,
        )
        visual = pb.createVisualShape(
            pb.GEOM_CYLINDER,
            radius=p.body_radius_m,
            length=0.03,
            visualFramePosition=[0, 0, p.l_m],
            rgbaColor=[0.2, 0.4, 0.9, 1],
            physicsClientId=self.client,
        )
        q = pb.getQuaternionFromEuler([0, 0, yaw_rad])
        mass = 0.0 if kinematic else p.mass_kg
        uid = pb.createMultiBody(mass, shape, visual, list(start_w), q, physicsClientId=self.client)
        if kinematic:
            self.kinematic.add(name)
        else:
            pb.changeDynamics(
                uid,
                -1,
                localInertiaDiagonal=[p.Ixx_kgm2, p.Iyy_kgm2, p.Izz_kgm2],
                linearDamping=0.0,
                angularDamping=0.0,
                physicsClientId=self.client,
            )
        if velocity_w is not None and not kinematic:
            pb.resetBaseVelocity(uid, list(velocity_w), [0.0, 0.0, 0.0], physicsClientId=self.client)
        self._mixer[name] = model.B
        self.drones[name] = uid
        self.bodies[uid] = Body(name, uid, "drone")

    def add_sphere(self, name: str, center_w: FloatArray, radius_m: float, velocity_w: FloatArray) -> None:
        col = pb.createCollisionShape(pb.GEOM_SPHERE, radius=radius_m, physicsClientId=self.client)
        vis = pb.createVisualShape(
            pb.GEOM_SPHERE, radius=radius_m, rgbaColor=[0.9, 0.3, 0.2, 1], physicsClientId=self.client
        )
        uid = pb.createMultiBody(0, col, vis, list(center_w), physicsClientId=self.client)
        self._add_obstacle(name, uid, center_w, velocity_w)

    def add_cylinder(
        self,
        name: str,
        center_w: FloatArray,
        axis_w: FloatArray,
        radius_m: float,
        length_m: float,
        velocity_w: FloatArray,
    ) -> None:
        col = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=radius_m, height=length_m, physicsClientId=self.client)
        vis = pb.createVisualShape(
            pb.GEOM_CYLINDER,
            radius=radius_m,
            length=length_m,
            rgbaColor=[0.9, 0.6, 0.2, 1],
            physicsClientId=self.client,
        )
        uid = pb.createMultiBody(
            0, col, vis, list(center_w), _quat_z_to(np.asarray(axis_w, float)), physicsClientId=self.client
        )
        self._add_obstacle(name, uid, center_w, velocity_w)

    def _add_obstacle(self, name: str, uid: int, c0: FloatArray, vel: FloatArray) -> None:
        self.obstacles[name] = (uid, np.asarray(c0, float), np.asarray(vel, float))
        self.bodies[uid] = Body(name, uid, "obstacle")

    # --- stepping -------------------------------------------------------------------
    def obstacle_center(self, name: str) -> FloatArray:
        _uid, c0, vel = self.obstacles[name]
        return c0 + vel * self.t_s

    def read_states(self, names: list[str]) -> DroneStates:
        """Ground truth of the drones ``names``, one PyBullet query pair per drone and
        the frame conversions for all of them at once."""
        if not names:
            z = np.zeros((0, 3))
            return DroneStates(z, z, np.zeros((0, 4)), z, np.zeros((0, 3, 3)))
        flat: list[float] = []  # per drone: position (3), quaternion (4), velocity (3), angular velocity (3)
        get_pose, get_vel, client = pb.getBasePositionAndOrientation, pb.getBaseVelocity, self.client
        for name in names:
            uid = self.drones[name]
            p, q = get_pose(uid, physicsClientId=client)
            v, w = get_vel(uid, physicsClientId=client)
            flat += p
            flat += q
            flat += v
            flat += w
        a = np.array(flat).reshape(-1, 13)
        R, Omega_b = _frames(a)
        return DroneStates(a[:, 0:3], a[:, 7:10], a[:, 3:7], Omega_b, R)

    def apply_rotors_all(self, names: list[str], f_N: FloatArray, states: DroneStates) -> None:
        """Rotor thrusts ``f_N`` (n, 4) [N] of the drones ``names`` for the next step
        (PyBullet clears forces every step), at ``states`` (in the same order).

        Applied as the exact equivalent wrench: the collective ``T = B[0] f`` along body z
        at the centre of mass, and the torque ``B[1:4] f`` (roll and pitch from the rotor
        offsets, yaw from the rotors' drag)."""
        if not names:
            return
        key = tuple(names)
        B = self._mixer_stacks.get(key)
        if B is None:
            B = self._mixer_stacks[key] = np.stack([self._mixer[n] for n in names])
        wrench = np.einsum("nij,nj->ni", B, f_N)
        force_w = wrench[:, 0:1] * states.R[:, :, 2]
        torque_w = np.einsum("nij,nj->ni", states.R, wrench[:, 1:])
        for name, F, x, tau in zip(names, force_w.tolist(), states.x_w.tolist(), torque_w.tolist(), strict=True):
            uid = self.drones[name]
            pb.applyExternalForce(uid, -1, F, x, pb.WORLD_FRAME, physicsClientId=self.client)
            pb.applyExternalTorque(uid, -1, tau, pb.WORLD_FRAME, physicsClientId=self.client)

    def apply_external_all(
        self, names: list[str], force_w: FloatArray, torque_b: FloatArray, states: DroneStates
    ) -> None:
        """Extra forces ``force_w`` (n, 3) [N, world] at the drones' centres of mass and
        torques ``torque_b`` (n, 3) [N m, body] for the next step (the plant's downwash,
        drag, ground effect: ``swarm.realism.plant``), at ``states`` (in the order of ``names``).

        Applied as :meth:`apply_rotors_all` applies the rotors' wrench: the force at the
        base position in ``WORLD_FRAME``, the torque turned into the world frame (``R tau``)
        in ``WORLD_FRAME``; PyBullet adds them to the rotors' and clears all after the step."""
        if not names:
            return
        torque_w = np.einsum("nij,nj->ni", states.R, torque_b)
        rows = zip(names, np.asarray(force_w, float).tolist(), states.x_w.tolist(), torque_w.tolist(), strict=True)
        for name, F, x, tau in rows:
            uid = self.drones[name]
            pb.applyExternalForce(uid, -1, F, x, pb.WORLD_FRAME, physicsClientId=self.client)
            pb.applyExternalTorque(uid, -1, tau, pb.WORLD_FRAME, physicsClientId=self.client)

    def step(self) -> list[tuple[str, str]]:
        """Advance one physics step; returns the pairs of bodies in contact (ground
        excluded for drones resting on it is the caller's choice: all pairs are given)."""
        self.t_s += self.dt_s
        for _name, (uid, c0, vel) in self.obstacles.items():
            if vel.any():
                _pos, q = pb.getBasePositionAndOrientation(uid, physicsClientId=self.client)
                pb.resetBasePositionAndOrientation(uid, list(c0 + vel * self.t_s), q, physicsClientId=self.client)
        pb.stepSimulation(physicsClientId=self.client)
        pairs = set()
        for c in pb.getContactPoints(physicsClientId=self.client):
            a, b = self.bodies.get(c[1]), self.bodies.get(c[2])
            if a is None or b is None or (a.kind != "drone" and b.kind != "drone"):
                continue
            pairs.add(tuple(sorted((a.name, b.name))))
        # PyBullet finds no contact between two bodies of mass 0: test a kinematic (real)
        # drone against the obstacles, the ground and the other kinematic drones directly
        statics = [self.drones[n] for n in self.kinematic]
        statics += [uid for uid, b in self.bodies.items() if b.kind != "drone"]
        for name in self.kinematic:
            uid = self.drones[name]
            for other in statics:
                if other == uid:
                    continue
                if pb.getClosestPoints(uid, other, 0.0, physicsClientId=self.client):
                    pairs.add(tuple(sorted((name, self.bodies[other].name))))
        return sorted(pairs)  # type: ignore[arg-type]

    def set_pose(self, name: str, x_w: FloatArray, q: FloatArray) -> None:
        """Place a kinematic drone where motion capture saw it (``q`` scalar-last)."""
        pb.resetBasePositionAndOrientation(self.drones[name], list(x_w), list(q), physicsClientId=self.client)

    def close(self) -> None:
        if pb.isConnected(self.client):
            pb.disconnect(self.client)
