"""Rigid-transform helpers on (position, quaternion xyzw) poses, numpy only."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

Pose = tuple[tuple[float, float, float], tuple[float, float, float, float]]


def quat_to_matrix(q: np.ndarray | Sequence[float]) -> np.ndarray:
    """3x3 rotation matrix of a quaternion (x, y, z, w) (normalised here).

    Computed as Bullet's ``btMatrix3x3::setRotation`` computes it, so it equals pybullet's
    ``getMatrixFromQuaternion`` bit for bit: the reference CLIPort moves camera points to the world with
    that matrix, and the fused maps must match its maps exactly.
    """
    x, y, z, w = (float(c) for c in q)
    n = x * x + y * y + z * z + w * w
    s = 2.0 / n if n > 0 else 0.0
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz = w * xs, w * ys, w * zs
    xx, xy, xz = x * xs, x * ys, x * zs
    yy, yz, zz = y * ys, y * zs, z * zs
    return np.array(
        [
            [1.0 - (yy + zz), xy - wz, xz + wy],
            [xy + wz, 1.0 - (xx + zz), yz - wx],
            [xz - wy, yz + wx, 1.0 - (xx + yy)],
        ]
    )


def matrix_to_quat(m: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a 3x3 rotation matrix."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
    q = np.array([x, y, z, w])
    q = q / np.linalg.norm(q)
    return tuple(float(c) for c in q)  # type: ignore[return-value]  # tuple() of an iterable has no length in its type


def euler_to_quat(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Quaternion (x, y, z, w) of extrinsic XYZ Euler angles (PyBullet's ``getQuaternionFromEuler``
    convention; equal to it to the last bit or two)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def yaw_to_quat(yaw: float) -> tuple[float, float, float, float]:
    """Quaternion (x, y, z, w) of a rotation by ``yaw`` radians about world +z: exactly the reference
    CLIPort's ``eulerXYZ_to_quatXYZW((0, 0, yaw))`` (no sign flip: (0, 0, sin(yaw / 2), cos(yaw / 2)))."""
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def quat_to_yaw(q: np.ndarray | tuple[float, ...]) -> float:
    """Rotation about +z (radians, in (-pi, pi]) of a quaternion (x, y, z, w).

    The z angle of the reference CLIPort's ``quatXYZW_to_eulerXYZ`` (Euler angles about the static z,
    then x, then y axes: R = Ry Rx Rz), which its tasks and training labels read: for a rotation about
    z alone it is that rotation's angle; for a tilted one it is ``atan2(R[1, 0], R[1, 1])``.
    """
    x, y, z, w = (float(c) for c in q)
    return math.atan2(2 * (x * y + w * z), 1 - 2 * (x * x + z * z))


def at_height(pose: Pose, z: float = 0.0) -> Pose:
    """``pose`` moved vertically to height ``z`` (by default onto the table), orientation kept."""
    return (float(pose[0][0]), float(pose[0][1]), z), pose[1]


def multiply(a: Pose, b: Pose) -> Pose:
    """Compose poses: the pose of frame b (given in frame a) in a's parent frame."""
    ra = quat_to_matrix(a[1])
    pos = np.asarray(a[0], dtype=float) + ra @ np.asarray(b[0], dtype=float)
    rot = ra @ quat_to_matrix(b[1])
    return tuple(float(c) for c in pos), matrix_to_quat(rot)  # type: ignore[return-value]  # tuple() of an iterable has no length in its type


def invert(a: Pose) -> Pose:
    """Inverse of a pose."""
    r = quat_to_matrix(a[1]).T
    pos = -r @ np.asarray(a[0], dtype=float)
    return tuple(float(c) for c in pos), matrix_to_quat(r)  # type: ignore[return-value]  # tuple() of an iterable has no length in its type


def apply(pose: Pose, point: np.ndarray | tuple[float, ...]) -> np.ndarray:
    """Transform a 3-D point (or an (N, 3) array) from the pose's frame into its parent frame."""
    return np.asarray(point, dtype=float) @ quat_to_matrix(pose[1]).T + np.asarray(pose[0], dtype=float)
