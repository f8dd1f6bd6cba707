"""targets: every way the evaluation draws held-out targets.

The uniform draw is the generator's own draw for the seed (so reports reproduce), stays
within the limits, and the targets are the model's FK of those configurations; the iiwa
check's targets are the paper's DH FK; the planar draw by distance puts half of its
targets inside rho = 1 and half beyond; the near-boundary mask picks the outer 10 %.
"""

from __future__ import annotations

import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel
from service.pipeline.joint_space import JointLimits
from training.evaluate.references.urdf_chain import read_chain
from training.evaluate.targets import (
    dh_targets,
    distance_from_base_m,
    held_out_targets,
    near_boundary,
    planar_targets_by_distance,
    uniform_configurations,
)


def test_uniform_configurations_are_the_seeded_generators_draw_within_the_limits() -> None:
    lower_rad, upper_rad = np.array([-1.0, -2.0, 0.0]), np.array([1.0, 0.5, 3.0])
    limits = JointLimits(lower_rad, upper_rad, np.zeros(3, dtype=bool))
    q_rad = uniform_configurations(limits, 40, seed=7)
    expected = np.random.default_rng(7).uniform(lower_rad, upper_rad, (40, 3))
    np.testing.assert_array_equal(q_rad, expected)
    assert ((q_rad >= lower_rad) & (q_rad <= upper_rad)).all()


def test_held_out_targets_are_the_models_fk_of_the_drawn_configurations(
    planar3r: ServedModel,
) -> None:
    targets = held_out_targets(planar3r, 5, seed=3)
    limits = planar3r.limits
    np.testing.assert_array_equal(targets.q_rad, uniform_configurations(limits, 5, seed=3))
    fk = planar3r.kinematics(targets.q_rad)
    np.testing.assert_array_equal(targets.position_m, fk.position_m)
    np.testing.assert_array_equal(targets.rotation, fk.rotation)


def test_dh_targets_are_the_independent_dh_fk_within_the_iiwa_limits() -> None:
    targets = dh_targets(6, seed=3)
    assert targets.q_rad.shape == (6, 7) and targets.pose.shape == (6, 4, 4)
    urdf = read_chain(REPO_MODELS_DIR / "robots" / "iiwa14.urdf", "ee")  # float64, not DH
    assert ((targets.q_rad >= urdf.lower) & (targets.q_rad <= urdf.upper)).all()
    np.testing.assert_allclose(targets.pose, urdf.pose(targets.q_rad), atol=1e-12)


def test_planar_targets_by_distance_cover_both_regimes() -> None:
    position_m = planar_targets_by_distance(11, seed=2)
    rho_m = np.linalg.norm(position_m, axis=1)
    assert position_m.shape == (11, 2)
    assert ((rho_m > 0.05) & (rho_m < 0.95)).sum() == 5  # two loops
    assert ((rho_m > 1.05) & (rho_m < 2.95)).sum() == 6  # one arc
    np.testing.assert_array_equal(position_m, planar_targets_by_distance(11, seed=2))


def test_near_boundary_marks_the_outer_tenth_of_the_reach(planar3r: ServedModel) -> None:
    # Planar 3R, unit links: q = 0 reaches 3 m; folding the elbow brings the hand in.
    q_rad = np.array([[0.0, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 1.5, 0.0], [0.0, 3.0, 0.0]])
    distance_m = distance_from_base_m(planar3r, q_rad)
    assert abs(distance_m[0] - 3.0) < 1e-6
    np.testing.assert_array_equal(near_boundary(planar3r, q_rad), distance_m >= 0.9 * 3.0)
    assert near_boundary(planar3r, q_rad).tolist() == [True, True, False, False]
