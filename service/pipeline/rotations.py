"""Rotations: unit quaternions with named fields, rotation logarithm, 6-D representation."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from service.pipeline.arrays import FloatArray


def quaternion_to_matrix(w: float, x: float, y: float, z: float) -> FloatArray:
    """Rotation matrix (3, 3) of the unit quaternion w + xi + yj + zk (normalised here)."""
    # scipy orders quaternions scalar-last; the named fields make the order explicit.
    return np.asarray(Rotation.from_quat([x, y, z, w]).as_matrix(), dtype=np.float64)


def rotation_log(rotation: FloatArray) -> FloatArray:
    """Rotation vector (B, 3) (axis * angle, rad) of rotation matrices (B, 3, 3).

    A row that is no rotation at all (non-finite, or a non-positive determinant, as a
    faulty network may produce) gets a NaN vector instead of failing the whole batch.
    """
    rotvec = np.full((rotation.shape[0], 3), np.nan)
    valid = np.all(np.isfinite(rotation), axis=(1, 2))  # (B,)
    with np.errstate(over="ignore", invalid="ignore"):
        valid[valid] = np.linalg.det(rotation[valid]) > 0.0
    if valid.any():
        rotvec[valid] = Rotation.from_matrix(rotation[valid]).as_rotvec()
    return rotvec


def rotation_error(rotation_target: FloatArray, rotation: FloatArray) -> FloatArray:
    """Base-frame rotation vector e (B, 3) with exp([e]) R = R*: log(R* R^T)."""
    return rotation_log(rotation_target @ np.swapaxes(rotation, -1, -2))


def rotation_6d(rotation: FloatArray) -> FloatArray:
    """Continuous 6-D representation (B, 6) of rotations (B, 3, 3): the first two columns."""
    return np.concatenate([rotation[..., :, 0], rotation[..., :, 1]], axis=-1)
