"""Forward kinematics and geometric Jacobian of a serial chain, from chain.json.

The same answer as kinematics.onnx (the chain's FK and Jacobian exported from
pytorch-kinematics): q (B, n) float64 -> position (B, 3), rotation (B, 3, 3) and the
geometric Jacobian (B, 6, n), base frame, linear rows first (J_v = z_i x (p_ee - p_i),
J_w = z_i for revolute joint i with world axis z_i through p_i). Both come from the same
URDF chain (`training.export` writes chain.json beside kinematics.onnx and checks both
against pytorch-kinematics); the registry checks this kernel against kinematics.onnx at
load and refuses the model if they differ.

Construction folds everything constant. chain.json gives per joint the fixed transform
from the previous joint's frame (fixed joints already folded in) and a unit axis. A
constant rotation Q_i with Q_i e_z = axis_i turns the joint into a rotation about its
frame's z axis, Rot(axis_i, q) = Q_i Rz(q) Q_i^T, and Q_i^T is folded into the next
joint's fixed transform (or the tip's); for the usual z axes Q_i is exactly the
identity. A call is then one compiled pass over the rows (`native.chain_kinematics`):
per joint one constant product and Rz(q_i).

A non-finite joint value gives non-finite outputs in its own row only, without a
warning. `python -m tools.kinematics_bench` times a call against kinematics.onnx.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import ValidationError

from service.errors import ModelVerificationError
from service.manifest import ChainSpec
from service.pipeline import native
from service.pipeline.arrays import FloatArray
from service.pipeline.types import KinematicsResult


def _z_to_axis(axis: FloatArray) -> FloatArray:  # axis (3,) unit -> (3, 3)
    """A rotation Q with Q e_z = axis; exactly the identity for +z and diag(1, -1, -1) for -z."""
    if axis[0] == 0.0 and axis[1] == 0.0:
        return np.diag([1.0, 1.0, 1.0]) if axis[2] > 0 else np.diag([1.0, -1.0, -1.0])
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    x = np.cross(helper, axis)
    x /= np.linalg.norm(x)
    y = np.cross(axis, x)
    return np.column_stack([x, y, axis])


class SerialChainKinematics:
    """The `Kinematics` Protocol on a serial chain of revolute joints: pure batched numpy."""

    def __init__(self, spec: ChainSpec) -> None:
        self.spec = spec
        self.joint_count = len(spec.joints)
        # Per joint i, A_i = Q_{i-1}^T origin_i Q_i (no Q_{i-1} for the first): its fixed
        # transform with the axis alignments folded in on both sides, so that joint i's
        # frame is the previous one times A_i times Rz(q_i).
        carry = np.eye(4)
        fixed = []
        for joint in spec.joints:
            align = np.eye(4)
            align[:3, :3] = _z_to_axis(np.asarray(joint.axis, dtype=np.float64))
            fixed.append(carry @ np.asarray(joint.origin, dtype=np.float64) @ align)
            carry = align.T
        self.fixed = np.ascontiguousarray(np.stack(fixed))  # (n, 4, 4)
        self.tip = np.ascontiguousarray(carry @ np.asarray(spec.tip, dtype=np.float64))  # (4, 4)

    @classmethod
    def from_file(cls, path: Path) -> SerialChainKinematics:
        """Read and validate chain.json; ModelVerificationError naming the file if it is not one."""
        try:
            return cls(ChainSpec.model_validate_json(path.read_bytes()))
        except (OSError, ValidationError) as error:
            raise ModelVerificationError(f"{path}: unreadable chain: {error}") from error

    def __call__(self, q_rad: FloatArray) -> KinematicsResult:  # q_rad (B, n), float64
        q = np.asarray(q_rad, dtype=np.float64)
        n = self.joint_count
        if q.ndim != 2 or q.shape[1] != n:
            raise ValueError(f"joint values have shape {q.shape}; expected (B, {n})")
        position, rotation, jacobian = native.chain_kinematics(self.fixed, self.tip, q)
        return KinematicsResult(position_m=position, rotation=rotation, jacobian=jacobian)
