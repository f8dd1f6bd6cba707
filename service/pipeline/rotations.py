"""Rotations: unit quaternions with named fields, rotation logarithm, 6-D representation,
and the axis task's error (the angle between a tool axis and its target direction)."""

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


def matrix_to_quaternion(rotation: FloatArray) -> tuple[float, float, float, float]:
    """The unit quaternion (w, x, y, z) of a rotation matrix (3, 3), scalar first."""
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return (float(w), float(x), float(y), float(z))


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


def axis_frame(axis: FloatArray, tool_axis: FloatArray) -> FloatArray:  # (3,), (3,) -> (3, 3)
    """The axis task's target as the kernels take it: rows b1, b2, u.

    b1, b2 are unit, orthogonal to the target axis a* (unit) and b1 x b2 = a*; u is the
    tool axis in the end-effector frame. b1 is a* crossed with the base axis least
    aligned with a*, so the frame is a fixed function of a*."""
    b1, b2 = normal_basis(np.asarray(axis, dtype=np.float64)[None])[0]
    return np.stack([b1, b2, np.asarray(tool_axis, dtype=np.float64)])


def normal_basis(axis: FloatArray) -> FloatArray:  # (B, 3) unit -> (B, 2, 3)
    """Per row, b1, b2 unit, orthogonal to the axis and b1 x b2 = the axis: b1 is the axis
    crossed with the base axis least aligned with it."""
    least = np.eye(3)[np.argmin(np.abs(axis), axis=1)]  # (B, 3)
    b1 = np.cross(axis, least)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    return np.stack([b1, np.cross(axis, b1)], axis=1)


def axis_error(
    frame: FloatArray,  # (3, 3) rows b1, b2, u as `axis_frame`
    rotation: FloatArray,  # (B, 3, 3) end-effector rotations
    angular_jacobian: FloatArray,  # (B, 3, n) the geometric Jacobian's angular rows
) -> tuple[FloatArray, FloatArray]:  # e (B, 2), J (B, 2, n)
    """The axis task's error e = target - current and its Jacobian (the compiled
    kernel's `residual_rows` computes the same).

    With a = R u the tool axis in the base frame and s = (b1 . a, b2 . a), the current
    value is s (0 on the fibre) and e = -(theta / sin theta) s, where theta =
    atan2(|s|, a . a*) is the angle between a and a*: |e| is that angle, pi where a is
    opposite a* (s = 0 there too, but no answer). J's row k is (a x b_k) . z_i per joint
    i, the derivative of b_k . a (a turns by z_i x a per radian of joint i)."""
    # Every sum is written out in the compiled kernel's order, so the two agree to the
    # last bit of arctan2 (numpy's and the C library's may differ there).
    b1, b2, u = frame
    target = np.cross(b1, b2)
    a = rotation[:, :, 0] * u[0] + rotation[:, :, 1] * u[1] + rotation[:, :, 2] * u[2]  # (B, 3)
    s = np.stack([a[:, 0] * b[0] + a[:, 1] * b[1] + a[:, 2] * b[2] for b in (b1, b2)], axis=1)
    sin = np.sqrt(s[:, 0] * s[:, 0] + s[:, 1] * s[:, 1])  # (B,)
    cos = a[:, 0] * target[0] + a[:, 1] * target[1] + a[:, 2] * target[2]
    theta = np.arctan2(sin, cos)
    scale = np.where(sin > 1e-8, theta / np.where(sin > 1e-8, sin, 1.0), 1.0)
    error = -scale[:, None] * s
    error[(sin <= 1e-8) & (cos < 0.0)] = [np.pi, 0.0]
    normal = np.cross(a[:, None, :], np.stack([b1, b2])[None])  # (B, 2, 3): a x b_k
    jacobian = (
        normal[:, :, 0, None] * angular_jacobian[:, None, 0, :]
        + normal[:, :, 1, None] * angular_jacobian[:, None, 1, :]
        + normal[:, :, 2, None] * angular_jacobian[:, None, 2, :]
    )  # (B, 2, n)
    return error, jacobian
