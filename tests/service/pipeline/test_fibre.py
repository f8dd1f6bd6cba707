"""fibre: Newton projection lands on the planar 3R's fibre (closed-form FK), the tangent is
the Jacobian's null vector with a continuous sign, and the corrector solves its system."""

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.fibre import corrector_step, project, smallest_singular_value, unit_tangent
from tests.service.pipeline.fibre_support import planar_fibre
from training.evaluate.references.planar3r import planar3r_jacobian, planar3r_position


def test_projection_reaches_the_target_by_the_closed_form(planar3r: ServedModel) -> None:
    target = np.array([0.7, 1.2])
    fibre = planar_fibre(planar3r, target)
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (50, 3))
    start = project(fibre, q, iterations=0)
    projected = project(fibre, start.q_rad, iterations=30)
    ok = projected.error_norm <= 1e-9
    assert ok.mean() > 0.9
    reached = planar3r_position(projected.q_rad[ok])
    np.testing.assert_allclose(reached, np.broadcast_to(target, reached.shape), atol=1e-9)


def test_locked_joints_do_not_move(planar3r: ServedModel) -> None:
    fibre = planar_fibre(planar3r, np.array([0.7, 1.2]))
    q = np.array([[0.3, 0.9, -0.4]])
    locked = np.array([[False, True, False]])
    projected = project(fibre, q, iterations=60, locked=locked)
    assert projected.q_rad[0, 1] == 0.9
    assert projected.error_norm[0] < 1e-9


def test_tangent_is_the_null_vector_and_keeps_its_sign() -> None:
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, (20, 3))
    jacobian = planar3r_jacobian(q)  # (20, 2, 3)
    tangent = unit_tangent(jacobian)
    np.testing.assert_allclose(np.einsum("bmn,bn->bm", jacobian, tangent), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(tangent, axis=1), 1.0)
    flipped = unit_tangent(jacobian, previous=-tangent)
    np.testing.assert_allclose(flipped, -tangent, atol=1e-9)


def test_corrector_step_solves_the_bordered_system() -> None:
    rng = np.random.default_rng(2)
    jacobian = rng.normal(size=(5, 2, 3))
    error = rng.normal(size=(5, 2))
    tangent = unit_tangent(jacobian)
    dq = corrector_step(jacobian, error, tangent)
    np.testing.assert_allclose(np.einsum("bmn,bn->bm", jacobian, dq), error, atol=1e-12)
    np.testing.assert_allclose(np.einsum("bn,bn->b", tangent, dq), 0.0, atol=1e-12)


def test_smallest_singular_value_vanishes_at_a_singularity() -> None:
    straight = planar3r_jacobian(np.zeros((1, 3)))  # arm stretched out: rank 1
    bent = planar3r_jacobian(np.array([[0.0, 1.0, 1.0]]))
    assert smallest_singular_value(straight)[0] < 1e-12
    assert smallest_singular_value(bent)[0] > 0.1
