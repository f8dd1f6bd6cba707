"""plots: the count-accuracy plot bins targets by distance as a hand count does; a
returned path is drawn in order, a loop closed and broken where a periodic joint wraps;
each returned component gets its own colour.
"""

from __future__ import annotations

import numpy as np

from training.evaluate.plots import component_colours, count_accuracy_by_distance, path_segments


def test_count_accuracy_bins_targets_by_distance() -> None:
    distance = np.array([0.1, 0.2, 0.6, 0.7, 0.8, 1.0])
    right = np.array([True, False, True, True, False, True])
    fraction, totals = count_accuracy_by_distance(distance, right, np.array([0.0, 0.5, 1.0]))
    np.testing.assert_array_equal(totals, [2, 4])  # the last edge belongs to the last bin
    np.testing.assert_allclose(fraction, [0.5, 0.75])


def test_a_path_is_drawn_in_order_closed_and_broken_at_a_periodic_wrap() -> None:
    q = np.array([[3.0, 0.0], [3.1, 0.1], [-3.1, 0.2], [-3.0, 0.3]])
    # Periodic first joint: the line breaks between 3.1 and -3.1 rather than crossing.
    pieces = path_segments(q, closed=False, periodic=np.array([True, False]))
    assert [len(p) for p in pieces] == [2, 2]
    np.testing.assert_array_equal(np.concatenate(pieces), q)
    # A limited joint does not wrap: one line.
    assert len(path_segments(q, closed=False, periodic=np.array([False, False]))) == 1
    # A closed loop comes back to its first point.
    loop = path_segments(q[:2], closed=True, periodic=np.array([True, False]))
    assert len(loop) == 1
    np.testing.assert_array_equal(loop[0][-1], q[0])


def test_each_component_gets_its_own_colour() -> None:
    for count in (1, 2, 10, 15, 40):
        colours = component_colours(count)
        assert len(colours) == count == len(set(colours))
