"""training.evaluate.baselines.restart_dls: the random-restart DLS baseline finds exact solutions.

Its accepted solutions (the service's own acceptance) are checked by independent FK:
the closed form for the planar arm, the tests' DH table for the iiwa pose; a fixed seed
gives the same restarts and so the same solutions.
"""

from __future__ import annotations

import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.acceptance import accept
from service.pipeline.correction import task_error_norms
from service.pipeline.joint_space import JointLimits
from service.pipeline.targets import Target
from service.pipeline.types import Correction, Tolerance
from training.evaluate.baselines.restart_dls import random_restart_dls
from training.evaluate.references.iiwa14 import LIMITS_RAD
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose
from training.evaluate.references.planar3r import planar3r_position
from training.evaluate.references.rotations import rotation_angle_rad
from training.kinematics import load_chain


def _accepted(
    model: ServedModel, q: np.ndarray, position: np.ndarray, rotation: np.ndarray | None
) -> np.ndarray:
    """The solutions the service's acceptance keeps (tolerance 1e-6, joint limits)."""
    manifest = model.manifest
    target = Target(
        position_m=position[manifest.task.position_axes],
        rotation=rotation,
        condition=np.zeros(1, np.float32),
    )
    position_error, orientation_error = task_error_norms(model.kinematics(q), target, manifest.task)
    limits = JointLimits.of(manifest.joints)
    unused_jacobian = np.full((len(q), 1, q.shape[1]), np.nan)  # acceptance does not read it
    correction = Correction(q, position_error, orientation_error, unused_jacobian)
    return q[accept(correction, Tolerance(1e-6, 1e-6), limits).accepted]


def test_planar_solutions_reach_the_target(planar3r: ServedModel) -> None:
    chain = load_chain(REPO_MODELS_DIR / "robots" / "planar3r.urdf", "ee")
    target = np.array([0.8, 1.1, 0.0])
    result = random_restart_dls(
        chain, planar3r.manifest.joints, planar3r.manifest.task, target, None, 200, seed=0
    )
    q = _accepted(planar3r, result.q_rad, target, None)
    assert len(q) > 100
    np.testing.assert_allclose(
        planar3r_position(q), np.broadcast_to(target[:2], (len(q), 2)), atol=1e-6
    )
    again = random_restart_dls(
        chain, planar3r.manifest.joints, planar3r.manifest.task, target, None, 200, seed=0
    )
    np.testing.assert_array_equal(again.q_rad, result.q_rad)


def test_iiwa_pose_solutions_reach_the_pose_within_the_limits() -> None:
    model = load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=0)
    chain = load_chain(REPO_MODELS_DIR / "robots" / "iiwa14.urdf", "ee")
    q_target = np.random.default_rng(4).uniform(-LIMITS_RAD, LIMITS_RAD, (1, 7))
    goal = iiwa14_pose(q_target)[0]
    result = random_restart_dls(
        chain, model.manifest.joints, model.manifest.task, goal[:3, 3], goal[:3, :3], 300, seed=1
    )
    q = _accepted(model, result.q_rad, goal[:3, 3], goal[:3, :3])
    assert len(q) > 10
    reached = iiwa14_pose(q)
    assert np.linalg.norm(reached[:, :3, 3] - goal[:3, 3], axis=1).max() <= 1e-6
    rotations = np.broadcast_to(goal[:3, :3], reached[:, :3, :3].shape)
    assert rotation_angle_rad(reached[:, :3, :3], rotations).max() <= 1e-6
    assert np.all(np.abs(q) <= LIMITS_RAD)
