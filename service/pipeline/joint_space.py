"""The joint metric: joint differences wrapped to (-pi, pi] for periodic joints only.

A joint is periodic when its range covers the full circle (a continuous joint).
A limited joint is not a circle: +174 deg and -174 deg on the iiwa's joint 7 are
348 deg apart, because the arm cannot pass through 180 deg. Wrapping it would
merge components that are really separate.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

TWO_PI = 2.0 * np.pi


def wrap_to_pi(angle_rad: FloatArray) -> FloatArray:
    """Map angles to (-pi, pi]."""
    return angle_rad - TWO_PI * np.ceil((angle_rad - np.pi) / TWO_PI)


def wrap_periodic(q_rad: FloatArray, periodic: BoolArray) -> FloatArray:
    """Wrap the periodic joints of `q_rad` (..., n) into (-pi, pi]; limited joints unchanged."""
    return np.where(periodic, wrap_to_pi(q_rad), q_rad)


def joint_difference(q_a_rad: FloatArray, q_b_rad: FloatArray, periodic: BoolArray) -> FloatArray:
    """q_a - q_b per joint (..., n), the shortest way round for periodic joints only."""
    dq_rad = q_a_rad - q_b_rad
    return np.where(periodic, wrap_to_pi(dq_rad), dq_rad)


def joint_distance(q_a_rad: FloatArray, q_b_rad: FloatArray, periodic: BoolArray) -> FloatArray:
    """Joint-metric distance (...,) in rad: sqrt of the sum of squared joint differences."""
    dq_rad = joint_difference(q_a_rad, q_b_rad, periodic)
    return np.sqrt(np.sum(dq_rad * dq_rad, axis=-1))
