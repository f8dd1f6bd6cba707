"""plots: the count-accuracy plot bins targets by distance as a hand count does.
"""

from __future__ import annotations

import numpy as np

from training.evaluate.plots import count_accuracy_by_distance


def test_count_accuracy_bins_targets_by_distance() -> None:
    distance = np.array([0.1, 0.2, 0.6, 0.7, 0.8, 1.0])
    right = np.array([True, False, True, True, False, True])
    fraction, totals = count_accuracy_by_distance(distance, right, np.array([0.0, 0.5, 1.0]))
    np.testing.assert_array_equal(totals, [2, 4])  # the last edge belongs to the last bin
    np.testing.assert_allclose(fraction, [0.5, 0.75])
