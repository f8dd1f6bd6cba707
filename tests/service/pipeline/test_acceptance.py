"""acceptance: tolerance and limit masks, with every sample accounted for exactly once."""

import numpy as np

from service.pipeline.acceptance import accept
from service.pipeline.joint_space import JointLimits
from service.pipeline.types import Correction, SampleCounts, Tolerance

TOLERANCE = Tolerance(position_m=1e-6, orientation_rad=1e-6)


def test_masks_and_counts() -> None:
    q = np.array([[0.0, 0.0], [0.0, 2.5], [3.0, 0.0], [0.0, 0.0], [np.nan, 0.0]])
    correction = Correction(
        q_rad=q,
        position_error_m=np.array([1e-9, 1e-9, 1e-9, 1e-3, np.inf]),
        orientation_error_rad=np.zeros(5),
        jacobian=np.full((5, 1, 2), np.nan),  # acceptance does not read it
    )
    periodic = np.array([True, False])
    limits = JointLimits(np.array([-np.pi, -2.0]), np.array([np.pi, 2.0]), periodic)
    acceptance = accept(correction, TOLERANCE, limits)
    assert acceptance.within_tolerance.tolist() == [True, True, True, False, False]
    # Joint 1 is periodic (3.0 passes); joint 2 is limited to +-2 (2.5 fails).
    assert acceptance.within_limits.tolist() == [True, False, True, True, False]
    assert acceptance.accepted.tolist() == [True, False, True, False, False]
    counts = SampleCounts.of(acceptance)
    assert (
        counts.sampled,
        counts.accepted,
        counts.rejected_tolerance,
        counts.rejected_joint_limits,
    ) == (5, 2, 2, 1)
    assert counts.accepted + counts.rejected_tolerance + counts.rejected_joint_limits == 5


def test_orientation_tolerance_applies() -> None:
    correction = Correction(
        q_rad=np.zeros((2, 1)),
        position_error_m=np.zeros(2),
        orientation_error_rad=np.array([1e-7, 1e-5]),
        jacobian=np.full((2, 1, 1), np.nan),  # acceptance does not read it
    )
    limits = JointLimits(np.array([-1.0]), np.array([1.0]), np.array([False]))
    acceptance = accept(correction, TOLERANCE, limits)
    assert acceptance.accepted.tolist() == [True, False]
