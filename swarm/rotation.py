"""Rotations. THE quaternion convention of the whole project lives here.

Quaternions are stored **scalar-last**: ``q = (qx, qy, qz, qw)``, the order PyBullet
uses, unit norm, rotating body-frame vectors into the world frame
(``v_w = R(q) v_b``). Every other module converts through these functions.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]

E3 = np.array([0.0, 0.0, 1.0])


def norm(v: FloatArray) -> float:
    """``|v|`` of a 1-D float64 array, bit for bit ``np.linalg.norm(v)`` (which computes
    ``sqrt(v.dot(v))`` for it) without that function's dispatch."""
    return math.sqrt(float(v.dot(v)))


def hat(a: FloatArray) -> FloatArray:
    """Skew matrix of a (3,) vector: ``hat(a) @ b == cross(a, b)``."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def vee(S: FloatArray) -> FloatArray:
    """Inverse of :func:`hat` for a (3, 3) skew matrix (its skew part)."""
    return np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]]) / 2.0


def quat_to_R(q: FloatArray) -> FloatArray:
    """(3, 3) rotation body to world from a scalar-last unit quaternion (x, y, z, w)."""
    x, y, z, w = q.tolist() if isinstance(q, np.ndarray) else q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


@njit(cache=True)
def quat_to_R_into(q, R):
    """:func:`quat_to_R` for compiled code: writes the rotation of the scalar-last unit
    quaternion ``q`` (4,) into ``R`` (3, 3) (no allocation per call)."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    R[0, 0], R[0, 1], R[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
    R[1, 0], R[1, 1], R[1, 2] = 2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)
    R[2, 0], R[2, 1], R[2, 2] = 2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)


def R_to_quat(R: FloatArray) -> FloatArray:
    """Scalar-last unit quaternion (x, y, z, w) of a (3, 3) rotation, qw >= 0."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, s / 4])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s])
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = np.array([(R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = np.array([(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4, (R[1, 0] - R[0, 1]) / s])
    q = q / np.linalg.norm(q)
    return q if q[3] >= 0 else -q


def quat_derivative(q: FloatArray, Omega_b: FloatArray) -> FloatArray:
    """dq/dt (scalar-last) for body rates ``Omega_b`` (3,) rad/s, body frame."""
    x, y, z, w = q
    wx, wy, wz = Omega_b
    return 0.5 * np.array(
        [
            w * wx + y * wz - z * wy,
            w * wy + z * wx - x * wz,
            w * wz + x * wy - y * wx,
            -x * wx - y * wy - z * wz,
        ]
    )


def euler_to_quat(roll: float, pitch: float, yaw: float) -> FloatArray:
    """Scalar-last quaternion of ZYX Euler angles (rad): R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.array(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ]
    )


def R_to_euler(R: FloatArray) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw) in rad of a rotation body to world."""
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    roll = float(np.arctan2(R[2, 1], R[2, 2]))
    yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    return roll, pitch, yaw
