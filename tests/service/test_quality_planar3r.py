"""The bundled planar 3R model against the closed form: counts, exactness and coverage (issue 2)."""

import numpy as np

from service.models.registry import ServedModel
from training.evaluate.planar3r import check
from training.evaluate.references.planar3r import (
    closed_form_smm,
    expected_component_count,
    planar3r_position,
)


def test_closed_form_reference_is_on_the_fibre_and_counts_components() -> None:
    for target, count in [((0.5, 0.0), 2), ((2.0, 0.0), 1), ((0.0, -2.9), 1), ((3.2, 0.0), 0)]:
        components = closed_form_smm(np.array(target))
        assert len(components) == count == expected_component_count(float(np.hypot(*target)))
        for points in components:
            np.testing.assert_allclose(
                planar3r_position(points), np.broadcast_to(target, (len(points), 2)), atol=1e-12
            )


def test_fifty_random_targets_get_the_right_count_exactly_and_coverage_is_real(
    planar3r: ServedModel,
) -> None:
    report = check(planar3r, num_targets=50)
    assert report.count_correct >= 49, report.wrong
    assert report.max_fk_error_m <= 1e-6
    # Every closed-form point of the SMM at rho = 2 (0.01 rad steps of phi) has a returned
    # configuration within 0.1 rad on the joint metric.
    assert report.coverage_max_rad <= 0.1
