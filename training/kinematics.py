"""The URDF read by pytorch-kinematics: the one kinematics source of truth.

`ForwardKinematics` is the module exported to kinematics.onnx for the service.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytorch_kinematics as pk
import torch

from service.manifest import JointSpec


def load_chain(urdf_path: Path, end_effector_link: str) -> pk.SerialChain:
    """Serial chain from the base to `end_effector_link`, in float64."""
    chain = pk.build_serial_chain_from_urdf(urdf_path.read_bytes(), end_effector_link)
    return chain.to(dtype=torch.float64)


def joint_spec(chain: pk.SerialChain) -> JointSpec:
    """Names, limits and periodicity of the chain's joints.

    A continuous joint (no limits) and a revolute joint whose range covers the full
    circle are periodic, with limits (-pi, pi]; any other joint keeps its URDF limits.
    """
    names = chain.get_joint_parameter_names()
    lower, upper = chain.get_joint_limits()
    periodic = [
        not (math.isfinite(lo) and math.isfinite(hi)) or hi - lo >= 2 * math.pi - 1e-9
        for lo, hi in zip(lower, upper, strict=True)
    ]
    return JointSpec(
        names=list(names),
        lower_rad=[-math.pi if p else float(lo) for p, lo in zip(periodic, lower, strict=True)],
        upper_rad=[math.pi if p else float(hi) for p, hi in zip(periodic, upper, strict=True)],
        periodic=periodic,
    )


class ForwardKinematics(torch.nn.Module):
    """q (B, n) -> position (B, 3), rotation (B, 3, 3), geometric Jacobian (B, 6, n), base frame."""

    def __init__(self, chain: pk.SerialChain) -> None:
        super().__init__()
        self.chain = chain

    def forward(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        pose = self.chain.forward_kinematics(q).get_matrix()  # (B, 4, 4)
        jacobian = self.chain.jacobian(q)  # (B, 6, n)
        return pose[:, :3, 3], pose[:, :3, :3], jacobian
