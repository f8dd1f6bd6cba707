"""iiwa14 check: the bundled pose model's answers, re-checked by the paper's DH table, are
exact, within the limits and fully accounted for, and are matched against the exact
components of the S-R-S IK.
"""

from __future__ import annotations

from service.models.registry import ServedModel
from training.evaluate.iiwa14 import TOLERANCE, check


def test_pose_answers_are_exact_by_dh_fk_within_limits_and_accounted(
    iiwa14_pose_model: ServedModel,
) -> None:
    report = check(iiwa14_pose_model, num_targets=2, seed=3, num_samples=300)
    assert report.ok_fraction == 1.0 and report.returned > 0
    assert report.max_position_error_m <= TOLERANCE
    assert report.max_orientation_error_rad <= TOLERANCE
    assert report.limit_violations == 0 and report.accounting_errors == 0
    assert report.recall is not None and 0.0 < report.recall <= 1.0
    assert set(report.median_stage_ms) >= {"sample", "correct", "total"}
