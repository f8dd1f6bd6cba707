"""references.planar3r: the closed-form SMM lies on the fibre and has the closed-form count."""

from __future__ import annotations

import numpy as np

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
