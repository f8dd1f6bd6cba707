"""limits (stage 3 for r > 1): a sample on the iiwa14's position fibre but outside the joint
limits comes back on the fibre inside them, exact by an independent DH forward kinematics,
with the joint that crossed its limit held on it; samples inside the limits, samples not
within tolerance and pulls that do not end exact are left as they were; the pipeline pulls
for r > 1 only, and its counts still account for every sample."""

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.correction import correct, error_norms
from service.pipeline.joint_space import JointLimits
from service.pipeline.limits import pull_into_limits
from service.pipeline.run import correct_samples, encode, run, sample, space_of
from service.pipeline.types import Correction, Query, Tolerance
from tests.service.pipeline.fibre_support import fibre_space, pose_fibre
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose

TOLERANCE_M = 1e-6
TOLERANCE = Tolerance(position_m=TOLERANCE_M, orientation_rad=TOLERANCE_M)


@pytest.fixture(scope="module")
def iiwa14_position() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-position", threads=1)


def corrected(model: ServedModel, q_target: np.ndarray, q_rad: np.ndarray) -> Correction:
    """The rows q_rad (B, 7) as stage 3 leaves them for q_target's position: their errors
    and Jacobians measured, nothing moved."""
    fibre = pose_fibre(model, q_target)
    error, jacobian = fibre.residual(q_rad)
    position_m, orientation_rad = error_norms(error, model.manifest.task)
    return Correction(q_rad.copy(), position_m, orientation_rad, jacobian)


def test_a_sample_outside_the_limits_is_pulled_onto_the_fibre_inside_them(
    iiwa14_position: ServedModel,
) -> None:
    limits = iiwa14_position.limits
    lower, upper = limits.lower_rad, limits.upper_rad
    q_target = np.array([0.4, 2.3, -0.6, -1.2, 0.5, 1.1, 0.3])  # q2 0.2 rad past 2.094
    assert limits.outside(q_target[None])[0].tolist() == [
        False, True, False, False, False, False, False,
    ]  # fmt: skip
    inside = np.array([0.4, 1.9, -0.6, -1.2, 0.5, 1.1, 0.3])  # not on the fibre: far off
    beyond_q4 = q_target.copy()
    beyond_q4[3] = -2.3  # two joints out, off the fibre: not within tolerance
    rows = np.stack([q_target, inside, beyond_q4])
    correction = corrected(iiwa14_position, q_target, rows)
    assert correction.position_error_m[0] < 1e-12 and correction.position_error_m[1] > 0.01

    fibre = pose_fibre(iiwa14_position, q_target)
    pulled = pull_into_limits(correction, fibre_space(fibre, limits, (), TOLERANCE))
    q = pulled.q_rad[0]
    assert np.all((q >= lower) & (q <= upper))
    assert q[1] == upper[1]  # held on the limit it crossed
    dh_position_m = iiwa14_pose(q[None])[0, :3, 3]
    expected_m = iiwa14_pose(q_target[None])[0, :3, 3]
    np.testing.assert_allclose(dh_position_m, expected_m, atol=TOLERANCE_M)
    assert pulled.position_error_m[0] <= TOLERANCE_M
    np.testing.assert_allclose(pulled.jacobian[0], fibre.residual(q[None])[1][0])
    # The other rows were not within tolerance: untouched.
    np.testing.assert_array_equal(pulled.q_rad[1:], rows[1:])
    np.testing.assert_array_equal(pulled.position_error_m[1:], correction.position_error_m[1:])


def test_rows_inside_the_limits_and_failed_pulls_are_left_as_they_were(
    iiwa14_position: ServedModel,
) -> None:
    limits = iiwa14_position.limits
    q_target = np.array([0.4, 2.3, -0.6, -1.2, 0.5, 1.1, 0.3])
    q_inside = np.array([0.2, 1.0, 0.3, -1.0, 0.4, 0.8, 0.1])
    fibre = pose_fibre(iiwa14_position, q_inside)
    correction = corrected(iiwa14_position, q_inside, q_inside[None])
    assert pull_into_limits(correction, fibre_space(fibre, limits, (), TOLERANCE)) is correction
    # No step at all: the row stays outside the limits, so it is not replaced.
    correction = corrected(iiwa14_position, q_target, q_target[None])
    target_space = fibre_space(pose_fibre(iiwa14_position, q_target), limits, (), TOLERANCE)
    unpulled = pull_into_limits(correction, target_space, steps=0)
    np.testing.assert_array_equal(unpulled.q_rad, correction.q_rad)


def test_the_pipeline_pulls_for_r_above_1_and_accounts_for_every_sample(
    iiwa14_position: ServedModel, planar3r: ServedModel
) -> None:
    manifest = iiwa14_position.manifest
    limits = JointLimits.of(manifest.joints)
    q_target = np.array([0.4, 1.7, -0.6, -1.2, 0.5, 1.1, 0.3])
    position_m = iiwa14_pose(q_target[None])[0, :3, 3]
    query = Query.for_model(manifest, position_m=position_m.tolist(), num_samples=400, seed=3)
    target = encode(iiwa14_position, query)
    q_sampled = sample(iiwa14_position, query, target)
    d = manifest.defaults
    dls_only = correct(
        q_sampled, target, manifest.task, iiwa14_position.kinematics, d.correction_steps,
        d.damping, limits,
    )  # fmt: skip
    space = space_of(iiwa14_position, target, TOLERANCE, CollisionCheck.none())
    stage3 = correct_samples(iiwa14_position, space, q_sampled)

    def exact_outside(c: Correction) -> int:
        out = limits.outside(c.q_rad).any(axis=1)
        return int((out & (c.position_error_m <= TOLERANCE_M)).sum())

    assert exact_outside(dls_only) > exact_outside(stage3)  # some were pulled in

    result = run(iiwa14_position, query)
    counts = result.counts
    assert counts.sampled == 400
    assert counts.accepted + counts.rejected_tolerance + counts.rejected_joint_limits == 400
    assert counts.rejected_joint_limits == exact_outside(stage3)
    members = np.concatenate([c.configurations_rad for c in result.components])
    assert len(members) == counts.accepted
    assert np.all((members >= limits.lower_rad) & (members <= limits.upper_rad))
    np.testing.assert_allclose(
        iiwa14_pose(members)[:, :3, 3], np.tile(position_m, (len(members), 1)), atol=2e-6
    )

    # r = 1: stage 3 is the DLS correction alone (the trace walks into the limits).
    planar = planar3r.manifest
    planar_query = Query.for_model(planar, position_m=[1.5, 0.3], num_samples=64)
    planar_target = encode(planar3r, planar_query)
    q = sample(planar3r, planar_query, planar_target)
    alone = correct(
        q, planar_target, planar.task, planar3r.kinematics, planar.defaults.correction_steps,
        planar.defaults.damping, JointLimits.of(planar.joints),
    )  # fmt: skip
    assert (alone.position_error_m <= TOLERANCE_M).any()  # so no sample is taken further
    planar_space = space_of(planar3r, planar_target, TOLERANCE, CollisionCheck.none())
    np.testing.assert_array_equal(correct_samples(planar3r, planar_space, q).q_rad, alone.q_rad)
