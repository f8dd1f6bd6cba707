"""Rotations: unit quaternions with named fields, rotation logarithm, 6-D representation."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from service.pipeline import native
from service.pipeline.arrays import FloatArray

_COS_150_DEG = float(np.cos(np.radians(150.0)))


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
    return _log(rotation.reshape(len(rotation), 9))


def rotation_error(rotation_target: FloatArray, rotation: FloatArray) -> FloatArray:
    """Base-frame rotation vector e (B, 3) with exp([e]) R = R*: log(R* R^T).

    rotation_target is one target (3, 3) for the whole batch (the compiled kernel,
    `native.rotation_error`: every correction and connect step) or one per row (B, 3, 3).
    """
    if rotation_target.ndim == 2:
        return native.rotation_error(rotation_target, rotation)
    return rotation_log(rotation_target @ np.swapaxes(rotation, -1, -2))


# Entries of a row-major 3 x 3 matrix M flattened to 9: M21, M02, M10 (the skew part's
# vee is (M21 - M12, M02 - M20, M10 - M01) / 2) and the rows and columns the determinant
# by cofactors along the first row takes.
_SKEW_PLUS, _SKEW_MINUS = [7, 2, 3], [5, 6, 1]
_COFACTOR = ([0, 1, 2], [4, 5, 3], [8, 6, 7], [5, 3, 4], [7, 8, 6])


def _log(matrix: FloatArray) -> FloatArray:  # (B, 9) -> (B, 3)
    """rotation_log of row-major flattened matrices M (B, 9). Every step acts on whole
    columns; the determinant is taken by cofactors (a LAPACK LU per row costs ten
    times more), and only rows over 150 degrees go through scipy."""
    first, a, b, c, d = (matrix[:, k] for k in _COFACTOR)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        determinant = np.einsum("bi,bi->b", first, a * b - c * d)
        valid = np.isfinite(matrix).all(axis=1) & (determinant > 0.0)  # (B,)
        # (B, 3): sin(theta) * axis
        sin_axis = 0.5 * (matrix[:, _SKEW_PLUS] - matrix[:, _SKEW_MINUS])
        sin = np.sqrt(np.einsum("bi,bi->b", sin_axis, sin_axis))
        cos = 0.5 * (matrix[:, ::4].sum(axis=1) - 1.0)  # entries 0, 4, 8: the trace
        angle = np.arctan2(sin, cos)
        # theta / sin(theta); where sin(theta) < 1e-8 (under 150 degrees: theta < 1e-8) its
        # series 1 + theta^2 / 6 rounds to 1 in float64.
        scale = np.ones_like(sin)
        np.divide(angle, sin, out=scale, where=sin > 1e-8)
        rotvec = sin_axis * scale[:, None]
    wide = valid & (cos < _COS_150_DEG)
    if wide.any():
        rows = matrix[wide].reshape(-1, 3, 3)
        rotvec[wide] = Rotation.from_matrix(rows).as_rotvec()
    if not valid.all():
        rotvec[~valid] = np.nan
    return rotvec


def rotation_6d(rotation: FloatArray) -> FloatArray:
    """Continuous 6-D representation (B, 6) of rotations (B, 3, 3): the first two columns."""
    return np.concatenate([rotation[..., :, 0], rotation[..., :, 1]], axis=-1)
