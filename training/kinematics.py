"""The URDF read by pytorch-kinematics: the one kinematics source of truth.

`ForwardKinematics` is the module exported to kinematics.onnx for the service;
`chain_spec` is the same chain as data, written to chain.json for the service's numpy
kernel (`service.models.chain`); `measured_reach_m` is the reach L the manifest records.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytorch_kinematics as pk
import torch
from pytorch_kinematics.urdf_parser_py.urdf import URDF
from scipy.optimize import minimize
from scipy.stats import qmc

from service.manifest import ChainJoint, ChainSpec, JointSpec
from service.models.chain import SerialChainKinematics
from service.pipeline.joint_space import JointLimits
from training.urdf import read_serial_chain

# measured_reach_m: 2^17 scrambled Sobol configurations find the basin of the farthest
# point (on the iiwa the best sample is 6e-4 m short); L-BFGS-B from the best few then
# climbs to it (the iiwa: 1.306 m exactly in float64), in well under a second.
REACH_SOBOL_LOG2 = 17
REACH_REFINED = 8


def load_chain(
    urdf_path: Path, end_effector_link: str, base_link: str | None = None
) -> pk.SerialChain:
    """Serial chain from `base_link` (default: the URDF's root) to `end_effector_link`, exact
    in float64.

    The chain is picked out of the URDF's tree and validated by `training.urdf` (branches,
    and the joints above the base link, are dropped; an unsupported joint on the chain
    raises ValueError naming it); pytorch-kinematics reads that chain alone.

    pytorch-kinematics 0.10 parses URDF origins (xyz, rpy) and joint axes in float32,
    which puts a float64 chain ~3e-8 m off the URDF (a rotation of pi/2 is not exact in
    float32). The chain's static frame offsets and axes are rebuilt here from the URDF
    text in float64, so FK agrees with an exact DH evaluation to ~1e-16 m.
    """
    picked = read_serial_chain(urdf_path.read_text(), end_effector_link, base_link)
    chain = pk.build_serial_chain_from_urdf(
        picked.urdf_text.encode(), end_effector_link, picked.base_link
    )
    chain = chain.to(dtype=torch.float64)
    _set_exact_offsets(chain, URDF.from_xml_string(picked.urdf_text))
    return chain


def _origin_matrix(origin: object) -> np.ndarray:
    """4x4 transform of a URDF origin: translation xyz, then fixed-axis roll, pitch, yaw."""
    transform = np.eye(4)
    if origin is None:
        return transform
    roll, pitch, yaw = (float(v) for v in getattr(origin, "rpy", None) or (0.0, 0.0, 0.0))
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    r_x = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    r_y = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    r_z = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    transform[:3, :3] = r_z @ r_y @ r_x
    transform[:3, 3] = [float(v) for v in getattr(origin, "xyz", None) or (0.0, 0.0, 0.0)]
    return transform


def _set_exact_offsets(chain: pk.SerialChain, robot: URDF) -> None:
    """Overwrite the chain's float32-parsed frame offsets and joint axes with float64 ones."""
    joints = {joint.child: joint for joint in robot.joints}
    links = robot.link_map
    offsets = chain._static_offsets.clone()  # (num_frames, 4, 4)
    for index, name in chain.idx_to_frame.items():
        if index == 0:  # the base link is the origin (pytorch-kinematics resets it too)
            offsets[0] = torch.eye(4, dtype=offsets.dtype)
            continue
        link = links[name]
        joint = joints.get(name)
        exact = _origin_matrix(getattr(link, "origin", None)) @ _origin_matrix(
            None if joint is None else joint.origin
        )
        offsets[index] = torch.from_numpy(exact)
        if joint is not None and joint.type != "fixed":
            axis = np.asarray(joint.axis if joint.axis is not None else (1.0, 0.0, 0.0), float)
            dof = chain.get_joint_parameter_names().index(joint.name)
            chain.axes[dof] = torch.from_numpy(axis / np.linalg.norm(axis))
    chain._static_offsets = offsets
    chain._serial_dof_axes = chain.axes.clone()


def chain_spec(chain: pk.SerialChain) -> ChainSpec:
    """The chain's frames as chain.json: fixed transforms folded up to each movable joint.

    Frame f of the chain sits at world_f = world_{f-1} @ offset_f @ Rot(axis_f, q_f), with
    no rotation for a fixed joint. The offsets from one movable joint to the next (and
    from the last to the end effector) are multiplied here, in float64, from the chain's
    own tensors (the exact ones `load_chain` set), so the spec is the chain pytorch-kinematics
    evaluates. Only serial chains of revolute (and continuous) joints are supported.
    """
    offsets = chain._static_offsets.detach().cpu().numpy().astype(np.float64)  # (F, 4, 4)
    parents = chain._direct_parent_idx.tolist()
    if parents != list(range(-1, len(parents) - 1)):
        raise ValueError(f"not a serial chain: frame parents {parents}")
    names = chain.get_joint_parameter_names()
    axes = chain.axes.detach().cpu().numpy().astype(np.float64)  # (n, 3)
    joints: list[ChainJoint] = []
    carry = np.eye(4)
    for frame, (dof, kind) in enumerate(
        zip(chain.joint_indices.tolist(), chain.joint_type_indices.tolist(), strict=True)
    ):
        carry = carry @ offsets[frame]
        if dof < 0:
            continue
        if kind != 1:  # pytorch_kinematics.frame.Joint.TYPES: fixed, revolute, prismatic
            raise ValueError(f"joint {names[dof]!r}: only revolute and continuous joints")
        if dof != len(joints):
            raise ValueError(f"joint {names[dof]!r} is not in chain order")
        joints.append(ChainJoint(name=names[dof], origin=carry.tolist(), axis=axes[dof].tolist()))
        carry = np.eye(4)
    return ChainSpec(
        base_link=chain.idx_to_frame[0],
        end_effector_link=chain.idx_to_frame[len(parents) - 1],
        joints=joints,
        tip=carry.tolist(),
    )


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


def measured_reach_m(chain: pk.SerialChain, joints: JointSpec, seed: int = 0) -> float:
    """L of the paper: the largest distance of the end effector from the base-link origin
    over the joint limits, measured (not typed into a robot file).

    2^REACH_SOBOL_LOG2 configurations (scrambled Sobol in the limits) are evaluated; the
    REACH_REFINED farthest are refined by L-BFGS-B inside the limits on -|p(q)|^2, whose
    gradient is -2 p^T J_v (the Jacobian's linear rows). FK is the service's numpy kernel
    on `chain_spec(chain)`, the chain.json that ships (pytorch-kinematics' to 1e-15, and
    ~50x faster on a batch).
    """
    kinematics = SerialChainKinematics(chain_spec(chain))
    limits = JointLimits.of(joints)
    sobol = qmc.Sobol(d=joints.count, scramble=True, seed=seed).random_base2(REACH_SOBOL_LOG2)
    q = limits.lower_rad + (limits.upper_rad - limits.lower_rad) * sobol  # (S, n)
    distance_m = np.linalg.norm(kinematics(q).position_m, axis=1)  # (S,)
    best = np.argsort(-distance_m)[:REACH_REFINED]

    def negative_squared_distance(q_one: np.ndarray) -> tuple[float, np.ndarray]:
        answer = kinematics(q_one[None])
        p = answer.position_m[0]  # (3,)
        j_v = answer.jacobian[0, :3]  # (3, n)
        return -float(p @ p), -2.0 * (p @ j_v)

    reach_m = float(distance_m[best[0]])
    for start in q[best]:
        result = minimize(
            negative_squared_distance,
            start,
            jac=True,
            method="L-BFGS-B",
            bounds=list(zip(limits.lower_rad, limits.upper_rad, strict=True)),
            options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 1000},
        )
        reach_m = max(reach_m, math.sqrt(-float(result.fun)))
    return reach_m
