"""data: Sobol points in the limits, FK labels vs the closed form, normalised training pairs,
and the labeller that makes fresh pairs with the normalisation fitted once."""

import math

import numpy as np
import torch

from service.manifest import REPO_MODELS_DIR
from training.data import (
    Labeller,
    build_flow_data,
    end_effector_poses,
    fresh_seed,
    joint_normalisation,
    sobol_configurations,
)
from training.evaluate.references.planar3r import planar3r_position
from training.kinematics import ForwardKinematics, joint_spec, load_chain
from training.robots import robot_spec

PLANAR = robot_spec("planar3r")


def planar_fk() -> ForwardKinematics:
    return ForwardKinematics(load_chain(REPO_MODELS_DIR / PLANAR.urdf, PLANAR.end_effector_link))


def test_sobol_configurations_fill_the_limits_deterministically() -> None:
    joints = joint_spec(planar_fk().chain)
    q = sobol_configurations(joints, 4096, seed=3)
    assert q.dtype == torch.float64 and q.shape == (4096, 3)
    assert float(q.min()) >= -math.pi and float(q.max()) < math.pi
    assert torch.equal(q, sobol_configurations(joints, 4096, seed=3))
    # Low discrepancy: every octant of the cube holds close to 1/8 of the points.
    octant = ((q > 0).long() * torch.tensor([1, 2, 4])).sum(1)
    assert torch.bincount(octant, minlength=8).min() >= 4096 // 8 - 8


def test_labels_match_the_closed_form_fk() -> None:
    fk = planar_fk()
    q = sobol_configurations(joint_spec(fk.chain), 1000, seed=0)
    position, rotation = end_effector_poses(fk, q, chunk=300)
    np.testing.assert_allclose(position[:, :2], planar3r_position(q.numpy()), atol=1e-12)
    np.testing.assert_allclose(position[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rotation), 1.0, atol=1e-12)


def test_flow_data_is_normalised_to_the_unit_box() -> None:
    fk = planar_fk()
    joints = joint_spec(fk.chain)
    data = build_flow_data(fk, joints, PLANAR.task("position"), 2000, seed=0)
    assert data.q_1.shape == (2000, 3) and data.condition.shape == (2000, 2)
    assert float(data.q_1.abs().max()) <= 1.0 and float(data.condition.abs().max()) <= 1.0 + 1e-6
    norm = joint_normalisation(joints)
    np.testing.assert_allclose(norm.normalise(np.array(joints.upper_rad)), 1.0)


def denormalised_planar_condition(data_q_1: torch.Tensor, labeller: Labeller) -> np.ndarray:
    """The normalised condition of q_1 by the closed-form planar FK (not the FK module)."""
    q = labeller.joint_normalisation.denormalise(data_q_1.double().numpy())
    return labeller.condition_normalisation.normalise(planar3r_position(q))


def test_the_labeller_labels_fresh_draws_consistently_with_the_fitted_normalisation() -> None:
    """Pairs from the labeller are (normalised q, normalised FK(q)) under the normalisations
    fitted once on the initial data (checked against the closed-form FK); the same seed
    draws the same configurations, another seed other ones."""
    fk = planar_fk()
    data = build_flow_data(fk, joint_spec(fk.chain), PLANAR.task("position"), 2000, seed=0)
    labeller = data.labeller
    assert labeller is not None
    assert labeller.condition_normalisation == data.condition_normalisation
    fresh = labeller(3000, seed=fresh_seed(0, 1))
    assert fresh.q_1.shape == (3000, 3) and fresh.condition.shape == (3000, 2)
    np.testing.assert_allclose(
        fresh.condition.numpy(), denormalised_planar_condition(fresh.q_1, labeller), atol=1e-5
    )
    assert torch.equal(fresh.q_1, labeller(3000, seed=fresh_seed(0, 1)).q_1)
    assert not torch.equal(fresh.q_1, labeller(3000, seed=fresh_seed(0, 2)).q_1)
    # The initial pairs are exactly the labeller's pairs of the initial draw.
    assert torch.equal(data.condition, labeller(2000, seed=0).condition)


def test_fresh_seeds_are_deterministic_and_distinct_per_epoch_and_run() -> None:
    """(seed, epoch) -> one scramble seed, the same every time, different for other pairs."""
    seeds = {fresh_seed(s, e) for s in range(5) for e in range(50)}
    assert len(seeds) == 250
    assert fresh_seed(42, 3) == fresh_seed(42, 3)
