"""planar3r check: the bundled planar 3R model against the closed form: counts, exactness
and coverage.
"""

from __future__ import annotations

from service.models.registry import ServedModel
from training.evaluate.planar3r import check


def test_fifty_random_targets_get_the_right_count_exactly_and_coverage_is_real(
    planar3r: ServedModel,
) -> None:
    report = check(planar3r, num_targets=50)
    assert report.count_correct >= 49, report.wrong
    assert report.max_fk_error_m <= 1e-6
    # Every closed-form point of the SMM at rho = 2 (0.01 rad steps of phi) has a returned
    # configuration within 0.1 rad on the joint metric.
    assert report.coverage_max_rad <= 0.1
