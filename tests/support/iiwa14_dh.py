"""Independent forward kinematics of the KUKA LBR iiwa14, straight from the paper's DH table.

Written for the tests only (numpy, float64): it shares no code with the URDF, pytorch-
kinematics or the ONNX export, so agreement with them is evidence, not a tautology.
Standard DH: A_i = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i); the end effector is 0.045 m beyond
the link-7 frame along its z axis.
"""

from __future__ import annotations

import numpy as np

D_M = np.array([0.360, 0.0, 0.420, 0.0, 0.400, 0.0, 0.081])
A_M = np.zeros(7)
ALPHA_RAD = np.radians([-90.0, 90.0, 90.0, -90.0, -90.0, 90.0, 0.0])
END_EFFECTOR_OFFSET_M = 0.045
LIMITS_RAD = np.radians([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 175.0])


def dh_transform(q_rad: np.ndarray, d_m: float, a_m: float, alpha_rad: float) -> np.ndarray:
    """(B, 4, 4) standard DH link transforms for joint angles q_rad (B,)."""
    ct, st = np.cos(q_rad), np.sin(q_rad)
    ca, sa = np.cos(alpha_rad), np.sin(alpha_rad)
    transform = np.zeros((len(q_rad), 4, 4))
    transform[:, 0] = np.stack([ct, -st * ca, st * sa, a_m * ct], axis=1)
    transform[:, 1] = np.stack([st, ct * ca, -ct * sa, a_m * st], axis=1)
    transform[:, 2, 1:] = [sa, ca, d_m]
    transform[:, 3, 3] = 1.0
    return transform


def iiwa14_pose(q_rad: np.ndarray) -> np.ndarray:
    """(B, 4, 4) end-effector pose in the base frame for configurations (B, 7)."""
    q_rad = np.atleast_2d(q_rad)
    pose = np.tile(np.eye(4), (len(q_rad), 1, 1))
    for i in range(7):
        pose = pose @ dh_transform(q_rad[:, i], D_M[i], A_M[i], ALPHA_RAD[i])
    flange = np.eye(4)
    flange[2, 3] = END_EFFECTOR_OFFSET_M
    return pose @ flange


def rotation_angle_rad(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray:
    """(B,) angle of the relative rotation r_a r_b^T, from its trace (independent of scipy)."""
    relative = r_a @ np.swapaxes(r_b, -1, -2)
    cos = (np.trace(relative, axis1=-2, axis2=-1) - 1.0) / 2.0
    # Near 0 the trace loses precision; the skew part keeps it.
    skew = (relative - np.swapaxes(relative, -1, -2)) / 2.0
    sin = np.linalg.norm(np.stack([skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]], -1), axis=-1)
    return np.arctan2(sin, np.clip(cos, -1.0, 1.0))


def within_limits(q_rad: np.ndarray) -> np.ndarray:
    return np.all(np.abs(q_rad) <= LIMITS_RAD, axis=-1)
