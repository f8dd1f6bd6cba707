"""coaxial: the sets where joints j - 1 and j + 1 share one axis are found from the
kinematics alone, and on them the slide is an exact self-motion, checked by forward
kinematics independent of the service's (the iiwa14's DH table, the planar arm's closed
form): the iiwa14's shoulder (q2 = 0, q1 + q3 fixed), elbow (q4 = 0) and wrist (q6 = 0),
and the planar arm folded back on itself (q2 = pi, where joint 3 lands on joint 1)."""

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.coaxial import find_coaxial_sets, slide_range
from tests.support.iiwa14_dh import LIMITS_RAD, iiwa14_pose


@pytest.fixture(scope="module")
def iiwa14() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-position", threads=1)


def test_the_iiwa14_has_its_shoulder_elbow_and_wrist_sets(iiwa14: ServedModel) -> None:
    lower, upper, periodic = iiwa14.manifest.joints.arrays()
    sets = find_coaxial_sets(iiwa14.kinematics, lower, upper, periodic)
    assert [s.joint for s in sets] == [1, 3, 5]
    assert [s.moving for s in sets] == [(0, 2), (2, 4), (4, 6)]
    for coaxial in sets:
        assert coaxial.angle_rad == pytest.approx(0.0, abs=1e-9)
        # The DH frames turn joints j - 1 and j + 1 the same way: their sum is what moves.
        i, k = coaxial.moving
        assert coaxial.slide[i] == 1.0 and coaxial.slide[k] == -1.0
        rng = np.random.default_rng(coaxial.joint)
        q = rng.uniform(-LIMITS_RAD, LIMITS_RAD, (20, 7))
        q[:, coaxial.joint] = coaxial.angle_rad
        low, high = slide_range(coaxial, q, lower, upper, periodic)
        a = rng.uniform(low, high)  # (20,) inside the limits
        slid = q + a[:, None] * coaxial.slide
        assert np.all(np.abs(slid) <= LIMITS_RAD + 1e-12)
        np.testing.assert_allclose(iiwa14_pose(slid), iiwa14_pose(q), atol=1e-12)
        # Off the set the same move is no self-motion.
        q[:, coaxial.joint] += 0.3
        assert np.abs(iiwa14_pose(q + 0.5 * coaxial.slide) - iiwa14_pose(q)).max() > 1e-2


def test_the_planar_arm_folded_back_turns_about_its_base(planar3r: ServedModel) -> None:
    lower, upper, periodic = planar3r.manifest.joints.arrays()
    sets = find_coaxial_sets(planar3r.kinematics, lower, upper, periodic)
    assert len(sets) == 1 and sets[0].joint == 1
    assert abs(sets[0].angle_rad) == pytest.approx(np.pi, abs=1e-9)
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (10, 3))
    q[:, 1] = sets[0].angle_rad

    def tip(q: np.ndarray) -> np.ndarray:  # unit links: the closed form
        angles = np.cumsum(q, axis=1)
        return np.stack([np.cos(angles).sum(1), np.sin(angles).sum(1)], axis=1)

    for a in (-2.0, 0.7, 3.0):
        np.testing.assert_allclose(tip(q + a * sets[0].slide), tip(q), atol=1e-12)
