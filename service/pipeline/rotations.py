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

    Below 150 degrees (every correction and connect step near the fibre) the vector is
    read off the skew part, (theta / sin theta) vee((R - R^T) / 2), a few array
    operations; larger angles, where sin theta loses the axis, go through scipy. A row
    that is no rotation at all (non-finite, or a non-positive determinant, as a faulty
    network may produce) gets a NaN vector instead of failing the whole batch.
    """
    rotvec = np.full((rotation.shape[0], 3), np.nan)
    valid = np.all(np.isfinite(rotation), axis=(1, 2))  # (B,)
    with np.errstate(over="ignore", invalid="ignore"):
        valid[valid] = np.linalg.det(rotation[valid]) > 0.0
    if not valid.any():
        return rotvec
    r = rotation[valid]  # (V, 3, 3)
    sin_axis = 0.5 * np.stack(
        [r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], axis=1
    )  # (V, 3) = sin(theta) * axis
    sin = np.linalg.norm(sin_axis, axis=1)
    cos = 0.5 * (np.trace(r, axis1=1, axis2=2) - 1.0)
    angle = np.arctan2(sin, cos)
    # theta / sin(theta), with its series 1 + theta^2 / 6 where sin(theta) vanishes.
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(sin > 1e-8, angle / sin, 1.0 + angle * angle / 6.0)
    out = sin_axis * scale[:, None]
    wide = cos < np.cos(np.radians(150.0))
    if wide.any():
        out[wide] = Rotation.from_matrix(r[wide]).as_rotvec()
    rotvec[valid] = out
    return rotvec


def rotation_error(rotation_target: FloatArray, rotation: FloatArray) -> FloatArray:
    """Base-frame rotation vector e (B, 3) with exp([e]) R = R*: log(R* R^T)."""
    return rotation_log(rotation_target @ np.swapaxes(rotation, -1, -2))


def rotation_6d(rotation: FloatArray) -> FloatArray:
    """Continuous 6-D representation (B, 6) of rotations (B, 3, 3): the first two columns."""
    return np.concatenate([rotation[..., :, 0], rotation[..., :, 1]], axis=-1)
