"""coaxial: the sets where joints j - 1 and j + 1 share one axis are found from the
kinematics alone, and on them the slide is an exact self-motion, checked by forward
kinematics independent of the service's (the iiwa14's DH table, the planar arm's closed
form): the iiwa14's shoulder (q2 = 0, q1 + q3 fixed), elbow (q4 = 0) and wrist (q6 = 0),
and the planar arm folded back on itself (q2 = pi, where joint 3 lands on joint 1); and a
step across a set is refused where the fibre does not reach the set (the link lengths
say so) and kept where a walk along the fibre crosses it."""

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.connect.coaxial import find_coaxial_sets, slide_range
from tests.service.pipeline.fibre_support import fibre_space, null_space_walk, pose_fibre
from training.evaluate.references.iiwa14 import LIMITS_RAD, inverse_kinematics
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose
from training.evaluate.references.planar3r import planar3r_position


@pytest.fixture(scope="module")
def iiwa14() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-position", threads=1)


def test_the_iiwa14_has_its_shoulder_elbow_and_wrist_sets(iiwa14: ServedModel) -> None:
    limits = iiwa14.limits
    sets = find_coaxial_sets(iiwa14.kinematics, limits)
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
        low, high = slide_range(coaxial, q, limits)
        a = rng.uniform(low, high)  # (20,) inside the limits
        slid = q + a[:, None] * coaxial.slide
        assert np.all(np.abs(slid) <= LIMITS_RAD + 1e-12)
        np.testing.assert_allclose(iiwa14_pose(slid), iiwa14_pose(q), atol=1e-12)
        # Off the set the same move is no self-motion.
        q[:, coaxial.joint] += 0.3
        assert np.abs(iiwa14_pose(q + 0.5 * coaxial.slide) - iiwa14_pose(q)).max() > 1e-2


def test_the_planar_arm_folded_back_turns_about_its_base(planar3r: ServedModel) -> None:
    sets = find_coaxial_sets(planar3r.kinematics, planar3r.limits)
    assert len(sets) == 1 and sets[0].joint == 1
    assert abs(sets[0].angle_rad) == pytest.approx(np.pi, abs=1e-9)
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (10, 3))
    q[:, 1] = sets[0].angle_rad

    for a in (-2.0, 0.7, 3.0):
        slid = planar3r_position(q + a * sets[0].slide)  # the closed form
        np.testing.assert_allclose(slid, planar3r_position(q), atol=1e-12)


def test_a_step_may_cross_a_set_only_where_the_fibre_reaches_it(iiwa14: ServedModel) -> None:
    """A step between two points of a position fibre that crosses q2 = 0 is refused where
    the link lengths keep the fibre off that set, and kept where a walk along the fibre
    really crosses the wrist set q6 = 0."""
    limits = iiwa14.limits
    sets = find_coaxial_sets(iiwa14.kinematics, limits)
    shoulder, wrist = sets[0], sets[2]
    # The end effector is 0.555 m from the elbow-up point; q2 = 0 allows at most 0.526.
    q_a = np.array([-1.8321, 0.3116, -2.7316, 1.2636, 2.7301, 1.4829, -2.7446])
    position = iiwa14_pose(q_a[None])[0, :3, 3]
    assert np.linalg.norm(position - np.array([0, 0, 0.78])) > 0.40 + 0.126
    fibre = pose_fibre(iiwa14, q_a)
    # The same pose with the shoulder flipped (the S-R-S IK, branch s = -1): q2 < 0.
    pose = iiwa14_pose(q_a[None])[0]
    psi = np.linspace(-np.pi, np.pi, 3600, endpoint=False)
    twins = np.concatenate([
        inverse_kinematics(pose[:3, 3], pose[:3, :3], psi, (-1, elbow, wrist_sign))
        for elbow in (1, -1) for wrist_sign in (1, -1)
    ])  # fmt: skip
    q_b = twins[np.argmin(np.linalg.norm(twins - q_a, axis=1))]
    np.testing.assert_allclose(iiwa14_pose(q_b[None])[0, :3, 3], position, atol=1e-9)
    assert q_b[1] < 0.0 < q_a[1]
    crossed = fibre_space(fibre, limits, (shoulder,)).crossings_on_fibre(q_a[None], q_b[None], 1e-4)
    assert not crossed[0]
    # A walk along one component through q6 = 0: each of its steps is kept.
    walk = null_space_walk(iiwa14, np.array([0.3, 0.5, -0.4, -1.3, 0.6, 0.9, 0.2]), 400, 0)
    across = np.flatnonzero(np.sign(walk[1:, 5]) != np.sign(walk[:-1, 5]))
    assert len(across) >= 1
    walk_fibre = pose_fibre(iiwa14, walk[0])
    kept = fibre_space(walk_fibre, limits, (wrist,)).crossings_on_fibre(
        walk[across], walk[across + 1], 1e-4
    )
    assert kept.all()
    # A step that crosses no set is never refused.
    across_shoulder = fibre_space(walk_fibre, limits, (shoulder,))
    assert across_shoulder.crossings_on_fibre(walk[:5], walk[1:6], 1e-4).all()
