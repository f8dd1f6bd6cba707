"""fibre: Newton projection lands on the planar 3R's fibre (closed-form FK), rows already
within `until` take no step and no point is evaluated twice, the tangent is the Jacobian's
null vector with a continuous sign, the corrector solves its system, and the least
sigma_min over a batch is the SVD's, on one thread or split over several."""

from dataclasses import dataclass, replace

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.fibre import (
    Fibre,
    corrector_step,
    evaluate,
    min_singular_value,
    newton,
    project,
    smallest_singular_value,
    unit_tangent,
)
from service.pipeline.types import KinematicsResult
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
    jacobian[7] = np.nan
    tangent = unit_tangent(jacobian)
    assert np.isnan(tangent[7]).all()
    jacobian, tangent = np.delete(jacobian, 7, axis=0), np.delete(tangent, 7, axis=0)
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


@dataclass
class CountingKinematics:
    inner: Fibre

    def __post_init__(self) -> None:
        self.configurations = 0

    def __call__(self, q_rad: np.ndarray) -> KinematicsResult:
        self.configurations += len(q_rad)
        return self.inner.kinematics(q_rad)


def test_newton_steps_only_rows_above_until_and_evaluates_each_point_once(
    planar3r: ServedModel,
) -> None:
    """From evaluated points, rows within `until` are returned as they are (no step, no
    evaluation); the others take steps until within it, one evaluation per step, and the
    errors returned are those measured at the returned points."""
    fibre = planar_fibre(planar3r, np.array([0.7, 1.2]))
    exact = project(fibre, np.array([[0.3, 0.9, -0.4], [1.0, -0.5, 0.2]]), iterations=30)
    near = exact.q_rad + 0.05  # off the fibre
    counting = CountingKinematics(fibre)
    fibre = replace(fibre, kinematics=counting)
    start = evaluate(fibre, np.concatenate([exact.q_rad, near]))
    assert counting.configurations == 4
    moved = newton(fibre, start, iterations=10, until=1e-12)
    np.testing.assert_array_equal(moved.q_rad[:2], exact.q_rad)  # already within: no step
    assert np.all(moved.error_norm <= 1e-12)
    assert counting.configurations - 4 <= 2 * 4  # the two others converge in a few steps
    np.testing.assert_allclose(fibre.residual(moved.q_rad)[0], moved.error, atol=0)


def test_least_singular_value_is_the_svds() -> None:
    rng = np.random.default_rng(3)
    jacobian = rng.normal(size=(200, 2, 3))
    jacobian[5] = planar3r_jacobian(np.zeros((1, 3)))[0]  # rank 1: sigma_min 0
    jacobian[9] = np.nan
    sigma = smallest_singular_value(jacobian)
    assert min_singular_value(jacobian) == np.nanmin(sigma) < 1e-12
    assert min_singular_value(np.delete(jacobian, 5, axis=0)) == np.nanmin(np.delete(sigma, 5))
    assert min_singular_value(jacobian[9:10]) == np.inf
    # Split over threads (chunks of at least 128 rows): the least of the chunks' least.
    many = np.concatenate([np.delete(jacobian, 5, axis=0)] * 3)  # (597, 2, 3)
    many[450] = jacobian[5]
    for threads in (2, 3, 8):
        assert min_singular_value(many, threads) == min_singular_value(many) < 1e-12
    assert min_singular_value(many[:0], 2) == np.inf
