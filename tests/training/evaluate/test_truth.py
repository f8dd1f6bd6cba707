"""truth: the 4-D ground truth has components, and falls back to the generating
configuration where the fibre is thinner than its grid.
"""

from __future__ import annotations

import numpy as np

from service.models.registry import ServedModel
from training.evaluate.truth import ground_truth


def test_position_ground_truth_has_components_and_stands_in_at_the_workspace_edge(
    iiwa14_position_model: ServedModel,
) -> None:
    model = iiwa14_position_model
    inside = ground_truth(model, np.array([0.3, 0.8, 0.2, -1.2, 0.4, 0.9, 0.1]), seed=0)
    assert inside.count >= 1 and inside.size is not None and len(inside.points) > 1000
    # The arm straight out: the target is at full reach, the fibre is thinner than any
    # grid, and the generating configuration stands for it as one component.
    straight = np.array([0.3, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    edge = ground_truth(model, straight, seed=0)
    assert edge.count == 1
    np.testing.assert_array_equal(edge.points, straight[None])
