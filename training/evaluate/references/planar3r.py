"""Closed-form ground truth for the planar 3R (unit links): FK, Jacobian and the whole SMM.

SMM of a target p at distance rho from the base: for every end-effector angle phi the
wrist w = p - (cos phi, sin phi) must be within the 2R's reach (|w| <= 2), and each
elbow branch s = +-1 gives one configuration. For rho < 1 every phi is feasible and
the two branches are two disjoint loops (2 components); for 1 < rho < 3 phi covers an
arc at whose ends the branches meet (1 component); beyond 3 there is none.

Pure numpy, independent of the service's kinematics: the tests and the evaluation
check the service against it.
"""

from __future__ import annotations

import numpy as np

from service.pipeline.joint_space import wrap_to_pi

LINK_M = 1.0


def planar3r_position(q_rad: np.ndarray) -> np.ndarray:
    """End-effector position (..., 2) of configurations (..., 3): sum of unit links."""
    angle = np.cumsum(q_rad, axis=-1)  # (..., 3) absolute link angles
    return LINK_M * np.stack([np.cos(angle).sum(-1), np.sin(angle).sum(-1)], axis=-1)


def planar3r_jacobian(q_rad: np.ndarray) -> np.ndarray:
    """Position Jacobian (..., 2, 3): column j sums the links from joint j outwards."""
    angle = np.cumsum(q_rad, axis=-1)
    # d p / d q_j = sum_{k >= j} (-sin a_k, cos a_k)
    tail_cos = np.flip(np.cumsum(np.flip(np.cos(angle), -1), -1), -1)
    tail_sin = np.flip(np.cumsum(np.flip(np.sin(angle), -1), -1), -1)
    return LINK_M * np.stack([-tail_sin, tail_cos], axis=-2)


def expected_component_count(rho_m: float) -> int:
    if rho_m < 1.0:
        return 2
    if rho_m < 3.0:
        return 1
    return 0


def closed_form_smm(target_m: np.ndarray, phi_step_rad: float = 0.01) -> list[np.ndarray]:
    """The SMM of `target_m` (2,) as a list of components, each (k, 3) rad, sampled in phi."""
    phi = np.arange(0.0, 2 * np.pi, phi_step_rad)  # (K,)
    wrist = target_m[None, :] - np.stack([np.cos(phi), np.sin(phi)], axis=1)  # (K, 2)
    d2 = np.sum(wrist**2, axis=1)
    feasible = d2 <= (2 * LINK_M) ** 2
    phi, wrist, d2 = phi[feasible], wrist[feasible], d2[feasible]
    cos_q2 = np.clip((d2 - 2 * LINK_M**2) / (2 * LINK_M**2), -1.0, 1.0)
    branches = []
    for elbow in (1.0, -1.0):
        q2 = elbow * np.arccos(cos_q2)
        q1 = np.arctan2(wrist[:, 1], wrist[:, 0]) - np.arctan2(np.sin(q2), 1 + np.cos(q2))
        q3 = phi - q1 - q2
        branches.append(wrap_to_pi(np.stack([q1, q2, q3], axis=1)))
    count = expected_component_count(float(np.linalg.norm(target_m)))
    if count == 2:
        return branches
    if count == 1:
        return [np.concatenate(branches)]
    return []
