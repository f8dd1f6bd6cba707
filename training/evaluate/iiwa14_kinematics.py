"""Exact kinematics of the iiwa14 from the paper's DH table: forward, closed-form S-R-S
inverse, and the exact SMM of a pose (evaluation ground truth; numpy, float64).

Nothing here shares code with the URDF, pytorch-kinematics or the ONNX export.

The iiwa's DH table is offset-free: joints 1-2 meet at the shoulder S = (0, 0, 0.36),
joint 4 sits at the elbow E with |SE| = 0.42 m, joints 5-7 meet at the wrist W with
|EW| = 0.40 m, and the end effector is 0.126 m beyond W along its own z axis. For a pose
(p, R): W = p - 0.126 R z. The elbow lies on a circle around the S-W axis, whose angle
is the arm angle psi. For every psi there are 8 configurations: the shoulder twin
(q1 + pi, -q2), the elbow twin (q3 + pi, -q4) and the wrist twin (q5 + pi, -q6, q7 + pi).
Sweeping psi around the circle for each of the 8 branches gives the whole unconstrained
fibre of the pose (8 closed loops); the joint limits cut it into the feasible components.

Derivation (standard DH, a = 0): the unit vector S->E is z_2 = (c1 s2, s1 s2, c2); in
frame 2, E->W is z_4 = (-c3 s4, -s3 s4, c4); and R_47 = R_04^T R has third column
(c5 s6, s5 s6, c6) and third row (-s6 c7, s6 s7, c6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

D_M = np.array([0.360, 0.0, 0.420, 0.0, 0.400, 0.0, 0.081])  # seed Table 1; a = 0
ALPHA_RAD = np.radians([-90.0, 90.0, 90.0, -90.0, -90.0, 90.0, 0.0])
END_EFFECTOR_OFFSET_M = 0.045  # along the link-7 z axis (the flange)
LIMITS_RAD = np.radians([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 175.0])


def dh_pose(q_rad: np.ndarray) -> np.ndarray:
    """(B, 4, 4) end-effector poses of configurations (B, 7): product of standard DH links."""
    pose = np.tile(np.eye(4), (len(q_rad), 1, 1))  # (B, 4, 4)
    for i in range(7):
        ct, st = np.cos(q_rad[:, i]), np.sin(q_rad[:, i])
        ca, sa = np.cos(ALPHA_RAD[i]), np.sin(ALPHA_RAD[i])
        link = np.zeros_like(pose)
        link[:, 0, :3] = np.stack([ct, -st * ca, st * sa], axis=1)
        link[:, 1, :3] = np.stack([st, ct * ca, -ct * sa], axis=1)
        link[:, 2, 1:] = [sa, ca, D_M[i]]
        link[:, 3, 3] = 1.0
        pose = pose @ link
    pose[:, :3, 3] += END_EFFECTOR_OFFSET_M * pose[:, :3, 2]
    return pose


def rotation_angle_rad(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray:
    """(B,) angle of r_a r_b^T from its skew part and trace (accurate near zero)."""
    relative = r_a @ np.swapaxes(r_b, -1, -2)  # (B, 3, 3)
    skew = relative - np.swapaxes(relative, -1, -2)
    sin = 0.5 * np.linalg.norm(np.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], 1), axis=1)
    cos = (np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0
    return np.arctan2(sin, cos)


SHOULDER_M = np.array([0.0, 0.0, D_M[0]])
UPPER_ARM_M = D_M[2]  # |SE|
FOREARM_M = D_M[4]  # |EW|
WRIST_TO_EE_M = D_M[6] + END_EFFECTOR_OFFSET_M
BRANCHES = [(s, e, w) for s in (1, -1) for e in (1, -1) for w in (1, -1)]


def _dh_rotation(q_rad: np.ndarray, alpha_rad: float) -> np.ndarray:
    """(B, 3, 3) rotation of a standard DH link: Rz(q) Rx(alpha)."""
    ct, st = np.cos(q_rad), np.sin(q_rad)
    ca, sa = np.cos(alpha_rad), np.sin(alpha_rad)
    zero, one = np.zeros_like(ct), np.ones_like(ct)
    return np.stack(
        [
            np.stack([ct, -st * ca, st * sa], -1),
            np.stack([st, ct * ca, -ct * sa], -1),
            np.stack([zero, sa * one, ca * one], -1),
        ],
        -2,
    )


def wrist_centre(position_m: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    return position_m - WRIST_TO_EE_M * rotation[:, :, 2]  # (B, 3): along the EE z axis


def _perpendicular_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (3,) completing the unit `axis` to a right-handed frame."""
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def elbow_positions(wrist_m: np.ndarray, psi_rad: np.ndarray) -> np.ndarray | None:
    """(K, 3) elbow on its circle for arm angles psi (K,); None when W is out of reach."""
    shoulder_to_wrist = wrist_m - SHOULDER_M
    distance = float(np.linalg.norm(shoulder_to_wrist))
    if not abs(UPPER_ARM_M - FOREARM_M) < distance < UPPER_ARM_M + FOREARM_M:
        return None
    axis = shoulder_to_wrist / distance
    along = (distance**2 + UPPER_ARM_M**2 - FOREARM_M**2) / (2 * distance)
    radius = np.sqrt(max(UPPER_ARM_M**2 - along**2, 0.0))
    u, v = _perpendicular_basis(axis)
    circle = np.cos(psi_rad)[:, None] * u + np.sin(psi_rad)[:, None] * v  # (K, 3)
    return SHOULDER_M + along * axis + radius * circle


def inverse_kinematics(
    position_m: np.ndarray, rotation: np.ndarray, psi_rad: np.ndarray, branch: tuple[int, int, int]
) -> np.ndarray | None:
    """(K, 7) configurations reaching the pose (p (3,), R (3, 3)) at arm angles psi (K,).

    `branch` = (shoulder, elbow, wrist) signs, each +1 or -1. Angles are in (-pi, pi];
    the joint limits are not applied. None when the pose is out of reach.
    """
    shoulder, elbow, wrist = branch
    wrist_m = wrist_centre(position_m[None], rotation[None])[0]
    elbow_m = elbow_positions(wrist_m, psi_rad)
    if elbow_m is None:
        return None
    z2 = (elbow_m - SHOULDER_M) / UPPER_ARM_M  # (K, 3)
    q2 = shoulder * np.arccos(np.clip(z2[:, 2], -1.0, 1.0))
    q1 = np.arctan2(shoulder * z2[:, 1], shoulder * z2[:, 0])
    r_02 = _dh_rotation(q1, ALPHA_RAD[0]) @ _dh_rotation(q2, ALPHA_RAD[1])  # (K, 3, 3)
    z4 = np.einsum("kji,kj->ki", r_02, (wrist_m - elbow_m) / FOREARM_M)  # in frame 2
    q4 = elbow * np.arccos(np.clip(z4[:, 2], -1.0, 1.0))
    q3 = np.arctan2(-elbow * z4[:, 1], -elbow * z4[:, 0])
    r_04 = r_02 @ _dh_rotation(q3, ALPHA_RAD[2]) @ _dh_rotation(q4, ALPHA_RAD[3])
    r_47 = np.swapaxes(r_04, 1, 2) @ rotation  # (K, 3, 3)
    q6 = wrist * np.arccos(np.clip(r_47[:, 2, 2], -1.0, 1.0))
    q5 = np.arctan2(wrist * r_47[:, 1, 2], wrist * r_47[:, 0, 2])
    q7 = np.arctan2(wrist * r_47[:, 2, 1], -wrist * r_47[:, 2, 0])
    return np.stack([q1, q2, q3, q4, q5, q6, q7], axis=1)


@dataclass(frozen=True)
class ReferenceComponent:
    """One feasible piece of a pose's SMM: dense points along it and its arc length."""

    q_rad: np.ndarray  # (k, 7) ordered along the arc
    branch: tuple[int, int, int]
    arc_length_rad: float  # joint-space length (Euclidean; no iiwa joint is periodic)


def pose_smm(
    position_m: np.ndarray, rotation: np.ndarray, psi_steps: int = 7200, max_jump_rad: float = 0.2
) -> list[ReferenceComponent]:
    """The exact SMM of a pose within the joint limits, as its feasible components.

    Each branch's loop is sampled at `psi_steps` arm angles; consecutive feasible points
    belong to the same component unless they jump by more than `max_jump_rad` (near a
    shoulder or wrist singularity the loop can turn fast in joint space; such a jump is
    split rather than bridged). The loop closes: the last arc joins the first.
    """
    psi = np.linspace(-np.pi, np.pi, psi_steps, endpoint=False)
    components: list[ReferenceComponent] = []
    for branch in BRANCHES:
        q = inverse_kinematics(position_m, rotation, psi, branch)
        if q is None:
            return []
        feasible = np.all(np.abs(q) <= LIMITS_RAD, axis=1)  # (K,)
        step = np.linalg.norm(np.diff(q, axis=0, append=q[:1]), axis=1)  # (K,) to the next
        linked = feasible & np.roll(feasible, -1) & (step <= max_jump_rad)
        if feasible.all() and linked.all():
            components.append(ReferenceComponent(q, branch, float(step.sum())))
            continue
        # Start right after a break, so no arc straddles the end of the array.
        start = int(np.flatnonzero(~linked)[0]) + 1
        order = np.roll(np.arange(len(psi)), -start)
        arc: list[int] = []
        for index in order.tolist():
            if feasible[index]:
                arc.append(index)
            if not linked[index] and arc:
                members = np.asarray(arc)
                length = float(step[members[:-1]].sum())
                components.append(ReferenceComponent(q[members], branch, length))
                arc = []
    return components


def uniform_rotations(count: int, seed: int) -> np.ndarray:
    """(count, 3, 3) rotations uniform on SO(3) (normalised Gaussian quaternions)."""
    quaternion = np.random.default_rng(seed).normal(size=(count, 4))  # (w, x, y, z)
    w, x, y, z = (quaternion / np.linalg.norm(quaternion, axis=1, keepdims=True)).T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def position_smm_points(
    position_m: np.ndarray, num_orientations: int, psi_steps: int, seed: int
) -> np.ndarray:
    """(P, 7) dense points of the 4-D SMM of a position, within the joint limits.

    The position fibre is the union of the pose fibres over all end-effector
    orientations: orientations uniform on SO(3) x `psi_steps` arm angles x 8 branches,
    each configuration exact by the closed-form IK; those outside the limits are dropped.
    """
    psi = np.linspace(-np.pi, np.pi, psi_steps, endpoint=False)
    points = []
    for rotation in uniform_rotations(num_orientations, seed):
        for branch in BRANCHES:
            q = inverse_kinematics(position_m, rotation, psi, branch)
            if q is not None:
                points.append(q[np.all(np.abs(q) <= LIMITS_RAD, axis=1)])
    return np.concatenate(points) if points else np.zeros((0, 7))
