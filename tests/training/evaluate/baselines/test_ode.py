"""training.evaluate.baselines.ode: the paper's null-space RK5 trace closes and stays on the fibre.

Checked against the planar closed form (FK and the closed-form SMM) and, for the iiwa14
pose, against the tests' DH FK and the S-R-S IK loops; an r > 1 task is refused.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.joint_space import joint_distance
from training.evaluate.baselines.ode import CLOSURE_RAD, trace_smm
from training.evaluate.references.iiwa14 import BRANCHES, inverse_kinematics
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose
from training.evaluate.references.planar3r import closed_form_smm, planar3r_position
from training.evaluate.references.rotations import rotation_angle_rad


def test_planar_trace_closes_on_the_closed_form_loop(planar3r: ServedModel) -> None:
    q_start = np.array([0.3, 1.0, -0.5])
    trace = trace_smm(planar3r.kinematics, planar3r.manifest.task, q_start)
    assert trace.closed
    target = planar3r_position(q_start)
    assert np.abs(planar3r_position(trace.q_rad) - target).max() < 1e-8
    truth = np.concatenate(closed_form_smm(target, phi_step_rad=2e-4))
    periodic = np.ones(3, dtype=bool)
    gaps = [joint_distance(truth, q, periodic).min() for q in trace.q_rad]
    assert max(gaps) < 2e-2  # the closed form, sampled in phi, is sparse at its folds
    wrapped = np.angle(np.exp(1j * (trace.q_rad[-1] - q_start)))
    assert np.linalg.norm(wrapped) < CLOSURE_RAD


def test_iiwa_trace_closes_on_an_exact_ik_loop(iiwa14_pose_model: ServedModel) -> None:
    q_start = np.array([0.3, 0.6, 0.0, -1.2, 0.0, 0.9, 0.0])
    trace = trace_smm(iiwa14_pose_model.kinematics, iiwa14_pose_model.manifest.task, q_start)
    assert trace.closed and trace.length_rad > 1.0
    goal = iiwa14_pose(q_start[None])[0]
    reached = iiwa14_pose(trace.q_rad)
    assert np.linalg.norm(reached[:, :3, 3] - goal[:3, 3], axis=1).max() < 1e-8
    rotations = np.broadcast_to(goal[:3, :3], reached[:, :3, :3].shape)
    assert rotation_angle_rad(reached[:, :3, :3], rotations).max() < 1e-8
    psi = np.linspace(-np.pi, np.pi, 20000, endpoint=False)
    loops = np.concatenate(
        [inverse_kinematics(goal[:3, 3], goal[:3, :3], psi, branch) for branch in BRANCHES]
    )
    on_torus = np.angle(np.exp(1j * trace.q_rad))
    assert cKDTree(loops).query(on_torus)[0].max() < 2e-3


def test_a_task_with_more_than_one_redundant_dof_is_refused() -> None:
    position = load_model(REPO_MODELS_DIR / "iiwa14-position", threads=0)
    with pytest.raises(ValueError, match="1-D SMMs only"):
        trace_smm(position.kinematics, position.manifest.task, np.zeros(7))
