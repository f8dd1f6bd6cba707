"""Every returned configuration re-checked by the robot's reference forward kinematics.

The service measures its answers with its own kinematics (the URDF's chain, the exported
kinematics.onnx); the report's `reference_fk` block checks them again with code that
shares nothing with either: the planar 3R's closed form, the iiwa's and the Panda's DH
tables and, for the UR5, example-robot-data's URDF read by references/urdf_chain.py
(training/evaluate/references, numpy float64). The target is the reference FK of
the target configuration, and each returned configuration (accepted samples and path
points) must reach it within the served tolerances: the position, and the rotation
angle (pose) or the tool axis's angle to the target's (axis).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from service.models.registry import ServedModel
from training.evaluate.methods import MethodTarget
from training.evaluate.references import axis, iiwa14, panda
from training.evaluate.references.planar3r import planar3r_position
from training.evaluate.references.rotations import rotation_angle_rad


def _planar_pose(q_rad: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses of the planar 3R: its closed-form position in the plane z = 0."""
    poses = np.broadcast_to(np.eye(4), (len(q_rad), 4, 4)).copy()
    poses[:, :2, 3] = planar3r_position(q_rad)
    return poses


# robot -> (N, n) joint angles to (N, 4, 4) poses of its end effector.
REFERENCE_POSES: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "planar3r": _planar_pose,
    "iiwa14": iiwa14.dh_pose,
    "panda": panda.dh_pose,
    "ur5": lambda q_rad: axis.ur5_chain().pose(q_rad),
}


@dataclass(frozen=True)
class ReferenceFkCheck:
    """The answers' worst errors by the reference FK, and whether they are within the
    served tolerances."""

    configurations: int  # returned configurations checked (samples and path points)
    max_position_error_m: float
    max_orientation_error_rad: float | None  # None for a position task
    within_tolerance: bool


def reference_fk_check(
    model: ServedModel, q_targets: np.ndarray, answers: Sequence[MethodTarget]
) -> ReferenceFkCheck | None:
    """The largest position (m) and orientation (rad, pose tasks) error of any returned
    configuration by the reference FK, over `answers` to the targets `q_targets` reaches
    (T, n); None for a robot without a reference FK."""
    poses = REFERENCE_POSES.get(model.manifest.robot)
    if poses is None:
        return None
    task = model.manifest.task
    orientation = bool(task.orientation_rows)
    position_errors, orientation_errors = [np.zeros(0)], [np.zeros(0)]
    for q_target, answer in zip(q_targets, answers, strict=True):
        target = poses(q_target[None])[0]
        reached = poses(answer.returned)
        position_errors.append(np.linalg.norm(reached[:, :3, 3] - target[:3, 3], axis=1))
        if task.tool_axis is not None and len(reached):
            tool = np.asarray(task.tool_axis)
            a, goal = reached[:, :3, :3] @ tool, target[:3, :3] @ tool  # (P, 3), (3,)
            sine = np.linalg.norm(np.cross(a, goal), axis=1)
            orientation_errors.append(np.arctan2(sine, a @ goal))
        elif orientation and len(reached):
            rotations = np.broadcast_to(target[:3, :3], reached[:, :3, :3].shape)
            orientation_errors.append(rotation_angle_rad(reached[:, :3, :3], rotations))
    defaults = model.manifest.defaults
    max_position_m = float(np.concatenate(position_errors).max(initial=0.0))
    max_orientation_rad = float(np.concatenate(orientation_errors).max(initial=0.0))
    within = max_position_m <= defaults.tolerance_position_m and (
        not orientation or max_orientation_rad <= defaults.tolerance_orientation_rad
    )
    return ReferenceFkCheck(
        configurations=sum(len(a.returned) for a in answers),
        max_position_error_m=max_position_m,
        max_orientation_error_rad=max_orientation_rad if orientation else None,
        within_tolerance=within,
    )
