"""references.rotations: the angle between two rotations and Rodrigues' rotation, checked
against scipy's rotations.

The angle equals the magnitude of scipy's relative rotation vector over random pairs
(batched, and with extra leading axes), stays accurate for angles of 1e-10 rad (where the
trace alone gives 0) and near pi; Rodrigues' rotation about a unit axis equals scipy's
from the rotation vector.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from training.evaluate.references.rotations import rodrigues, rotation_angle_rad


def test_rotation_angle_is_the_relative_rotation_vectors_length() -> None:
    r_a = Rotation.random(200, random_state=1)
    r_b = Rotation.random(200, random_state=2)
    expected = (r_a * r_b.inv()).magnitude()
    angle = rotation_angle_rad(r_a.as_matrix(), r_b.as_matrix())
    np.testing.assert_allclose(angle, expected, rtol=0, atol=1e-12)
    stacked = rotation_angle_rad(r_a.as_matrix().reshape(20, 10, 3, 3),
                                 r_b.as_matrix().reshape(20, 10, 3, 3))  # fmt: skip
    np.testing.assert_allclose(stacked.reshape(-1), expected, rtol=0, atol=1e-12)


def test_rotation_angle_is_accurate_near_zero_and_near_pi() -> None:
    axis = np.array([0.6, 0.0, 0.8])
    base = Rotation.random(1, random_state=3).as_matrix()  # (1, 3, 3)
    for angle in (1e-10, 1e-6, 0.5):  # relative accuracy, where the trace alone gives 0
        turned = Rotation.from_rotvec(angle * axis).as_matrix()[None] @ base
        assert abs(rotation_angle_rad(turned, base)[0] - angle) <= 1e-6 * angle
    turned = Rotation.from_rotvec((np.pi - 1e-6) * axis).as_matrix()[None] @ base
    assert abs(rotation_angle_rad(turned, base)[0] - (np.pi - 1e-6)) <= 1e-9


def test_rodrigues_is_the_rotation_by_the_rotation_vector() -> None:
    rng = np.random.default_rng(4)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.uniform(-np.pi, np.pi, 50)
    expected = Rotation.from_rotvec(angle[:, None] * axis).as_matrix()
    np.testing.assert_allclose(rodrigues(axis, angle), expected, rtol=0, atol=1e-14)
