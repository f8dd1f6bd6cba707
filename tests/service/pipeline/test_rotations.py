"""rotations: quaternion fields map to the right matrix; log is the inverse of Rodrigues' exp."""

import numpy as np
from scipy.spatial.transform import Rotation

from service.pipeline.rotations import (
    quaternion_to_matrix,
    rotation_6d,
    rotation_error,
    rotation_log,
)


def rodrigues(rotvec: np.ndarray) -> np.ndarray:
    angle = np.linalg.norm(rotvec)
    k = rotvec / angle
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * skew + (1 - np.cos(angle)) * skew @ skew


def test_quaternion_fields_are_named_not_ordered() -> None:
    half = np.pi / 4  # 90 deg about z: w = cos 45, z = sin 45
    rotation = quaternion_to_matrix(w=np.cos(half), x=0.0, y=0.0, z=np.sin(half))
    np.testing.assert_allclose(rotation, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)


def test_log_inverts_rodrigues_and_error_vanishes_at_the_target() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        rotvec = rng.normal(size=3)
        rotvec *= rng.uniform(0.01, 3.1) / np.linalg.norm(rotvec)
        rotation = rodrigues(rotvec)
        np.testing.assert_allclose(rotation_log(rotation[None])[0], rotvec, atol=1e-10)
        np.testing.assert_allclose(rotation_error(rotation[None], rotation[None]), 0, atol=1e-12)
        other = rodrigues(rng.normal(size=3))
        # exp(e) R = R*: the error is expressed in the base frame.
        error = rotation_error(rotation[None], other[None])[0]
        np.testing.assert_allclose(rodrigues(error) @ other, rotation, atol=1e-10)


def test_6d_representation_is_the_first_two_columns() -> None:
    rotation = rodrigues(np.array([0.3, -0.2, 0.9]))
    np.testing.assert_allclose(rotation_6d(rotation[None])[0], rotation[:, :2].T.ravel())


def test_rotation_log_of_a_non_rotation_is_nan_in_its_row_only() -> None:
    """A faulty network's non-finite or degenerate matrix fails its own row, not the batch."""
    good = rodrigues(np.array([0.3, -0.2, 0.1]))
    batch = np.stack([good, np.full((3, 3), np.nan), np.zeros((3, 3)), np.diag([1, 1, -1.0])])
    rotvec = rotation_log(batch)
    np.testing.assert_allclose(rotvec[0], [0.3, -0.2, 0.1], atol=1e-12)
    assert np.isnan(rotvec[1:]).all()


def test_rotation_log_agrees_with_scipy_at_every_angle() -> None:
    """The skew-part formula (under 150 degrees) and the scipy path (above) both match
    scipy's rotation vector, from 1e-9 rad up to pi."""
    rng = np.random.default_rng(3)
    axis = rng.normal(size=(3000, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.concatenate([np.geomspace(1e-9, 1e-3, 1000), np.linspace(1e-3, np.pi, 2000)])
    rotvec = axis * angle[:, None]
    matrices = Rotation.from_rotvec(rotvec).as_matrix()
    np.testing.assert_allclose(rotation_log(matrices), rotvec, atol=1e-9)


def test_one_target_for_the_batch_gives_the_per_row_error() -> None:
    """A (3, 3) target (one product for the batch, its log read off the transpose) and the
    same target repeated per row agree, at small and wide angles and on a faulty row."""
    rng = np.random.default_rng(4)
    target = Rotation.random(random_state=5).as_matrix()
    angle = np.concatenate([rng.uniform(0.0, 0.1, 50), rng.uniform(2.7, np.pi, 50)])
    axis = rng.normal(size=(100, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    rotation = Rotation.from_rotvec(axis * angle[:, None]).as_matrix() @ target
    rotation[7] = np.nan
    one = rotation_error(target, rotation)
    per_row = rotation_error(np.broadcast_to(target, rotation.shape), rotation)
    np.testing.assert_allclose(one, per_row, atol=1e-12)
    assert np.isnan(one[7]).all() and np.isfinite(np.delete(one, 7, axis=0)).all()
    np.testing.assert_allclose(np.linalg.norm(np.delete(one, 7, axis=0), axis=1),
                               np.delete(angle, 7), atol=1e-9)  # fmt: skip
