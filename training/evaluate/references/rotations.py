"""Rotation helpers of the references (numpy, float64): the angle between two rotations
and the rotation about an axis (Rodrigues), batched.

Shared by the references, the tests and tools/container_test, which check answers with
them; nothing here comes from scipy, pytorch-kinematics or service/.
"""

from __future__ import annotations

import numpy as np


def rotation_angle_rad(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray:
    """(...,) angle of the relative rotation r_a r_b^T (..., 3, 3), from its trace and its
    skew part (the trace alone loses precision near 0)."""
    relative = r_a @ np.swapaxes(r_b, -1, -2)  # (..., 3, 3)
    cos = (np.trace(relative, axis1=-2, axis2=-1) - 1.0) / 2.0
    skew = (relative - np.swapaxes(relative, -1, -2)) / 2.0
    sin = np.linalg.norm(np.stack([skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]], -1), axis=-1)
    return np.arctan2(sin, np.clip(cos, -1.0, 1.0))


def rodrigues(axis: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """(B, 3, 3) rotations by angle_rad (B,) about the unit axis (3,)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angle_rad)[:, None, None], np.cos(angle_rad)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)
