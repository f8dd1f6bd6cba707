"""Held-out targets: every way the evaluation draws them, in one place.

A target is the forward kinematics of a configuration drawn uniformly within the joint
limits, with a seed distinct from training's, so every target is reachable and the
configuration that made it is known. The planar 3R's checks draw by distance from the
base instead, to cover both of its regimes (two components inside rho = 1, one beyond),
and the iiwa14 acceptance check makes its targets with the paper's DH table rather than
the model's own kinematics, so that the check shares no code with the export.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.pipeline.arrays import FloatArray
from service.pipeline.joint_space import JointLimits
from service.pipeline.types import SmmModel
from training.evaluate.references.iiwa14 import LIMITS_RAD, SHOULDER_M, dh_pose

# The paper's DH arm: its limits, no joint periodic.
IIWA14_LIMITS = JointLimits(-LIMITS_RAD, LIMITS_RAD, np.zeros(len(LIMITS_RAD), dtype=bool))


def uniform_configurations(limits: JointLimits, count: int, seed: int) -> FloatArray:  # (count, n)
    """Configurations uniform in the box of the limits, from a fresh generator."""
    lower_rad, upper_rad = limits.lower_rad, limits.upper_rad
    return np.random.default_rng(seed).uniform(lower_rad, upper_rad, (count, limits.count))


@dataclass(frozen=True)
class HeldOutTargets:
    q_rad: FloatArray  # (T, n) the configurations whose FK made the targets
    position_m: FloatArray  # (T, 3)
    rotation: FloatArray  # (T, 3, 3)


def held_out_targets(model: SmmModel, count: int, seed: int) -> HeldOutTargets:
    """`count` targets: the model's own FK of configurations uniform in its limits."""
    limits = model.limits
    q_rad = uniform_configurations(limits, count, seed)
    fk = model.kinematics(q_rad)
    return HeldOutTargets(q_rad=q_rad, position_m=fk.position_m, rotation=fk.rotation)


@dataclass(frozen=True)
class DhTargets:
    q_rad: FloatArray  # (T, 7) the configurations whose FK made the targets
    pose: FloatArray  # (T, 4, 4) by the paper's DH table


def dh_targets(count: int, seed: int) -> DhTargets:
    """iiwa14 targets made by the DH FK of the references (independent of URDF and export)."""
    q_rad = uniform_configurations(IIWA14_LIMITS, count, seed)
    return DhTargets(q_rad=q_rad, pose=dh_pose(q_rad))


def planar_targets_by_distance(count: int, seed: int) -> FloatArray:  # (count, 2) m
    """Half at rho in (0.05, 0.95), half in (1.05, 2.95), random bearing (planar 3R)."""
    rng = np.random.default_rng(seed)
    inner = rng.uniform(0.05, 0.95, count // 2)
    outer = rng.uniform(1.05, 2.95, count - count // 2)
    rho = np.concatenate([inner, outer])
    bearing = rng.uniform(-np.pi, np.pi, count)
    return rho[:, None] * np.stack([np.cos(bearing), np.sin(bearing)], axis=1)


def distance_from_base_m(model: SmmModel, q_targets: FloatArray) -> FloatArray:
    """(T,) distance of each target from the arm's base point (the iiwa's shoulder)."""
    base = SHOULDER_M if model.manifest.robot == "iiwa14" else np.zeros(3)
    return np.linalg.norm(model.kinematics(q_targets).position_m - base, axis=1)


def near_boundary(model: SmmModel, q_targets: FloatArray) -> np.ndarray:
    """(T,) targets in the outer 10 % of the reach from the base point."""
    distance = distance_from_base_m(model, q_targets)
    return distance >= 0.9 * distance.max()
