"""Rotations shared by every layer: roll-pitch-yaw matrices, quaternions (x, y, z, w order) and
named frame transforms.

Angles in rad; REP-103 fixed-axis roll-pitch-yaw. Quaternion helpers take arrays of shape
(..., 4) and vectors (..., 3).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np


class FrameTransform(NamedTuple):
    """The pose of frame ``child`` in frame ``parent`` (geometry_msgs/TransformStamped: header.frame_id
    = parent): ``translation`` x, y, z (m) and the rotation ``quaternion`` x, y, z, w (maps child-frame
    vectors into the parent frame)."""

    parent: str
    child: str
    translation: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]


def pose_transform(parent: str, child: str, pose: np.ndarray) -> FrameTransform:
    """The 4x4 child-to-parent ``pose`` (m) as a :class:`FrameTransform`."""
    return FrameTransform(parent, child, tuple(pose[:3, 3].tolist()), tuple(matrix_quaternion(pose[:3, :3]).tolist()))


def yaw_quaternions(yaw: np.ndarray) -> np.ndarray:
    """(N, 4) x, y, z, w quaternions of rotations about z by ``yaw`` (rad)."""
    half = 0.5 * np.asarray(yaw, dtype=np.float64)
    return np.stack([np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)], axis=-1)


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """3x3 rotation R = Rz(yaw) Ry(pitch) Rx(roll) (rad, REP-103 fixed-axis roll-pitch-yaw)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def matrix_quaternion(m: np.ndarray) -> np.ndarray:
    """x, y, z, w quaternion of a 3x3 rotation matrix."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(m).as_quat()


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a*b (rotate by b first, then a)."""
    av, aw, bv, bw = a[..., :3], a[..., 3:], b[..., :3], b[..., 3:]
    return np.concatenate([aw * bv + bw * av + np.cross(av, bv),
                           aw * bw - np.sum(av * bv, axis=-1, keepdims=True)], axis=-1)


def quaternion_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v by unit quaternions q."""
    qv, qw = q[..., :3], q[..., 3:]
    t = 2.0 * np.cross(qv, v)
    return v + qw * t + np.cross(qv, t)


@numba.njit(cache=True)
def quaternion_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of unit quaternions (N, 4) float64 in x, y, z, w order."""
    m = np.empty((len(q), 3, 3))
    for k in range(len(q)):
        x, y, z, w = q[k, 0], q[k, 1], q[k, 2], q[k, 3]
        m[k, 0, 0], m[k, 0, 1], m[k, 0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
        m[k, 1, 0], m[k, 1, 1], m[k, 1, 2] = 2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)
        m[k, 2, 0], m[k, 2, 1], m[k, 2, 2] = 2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)
    return m
