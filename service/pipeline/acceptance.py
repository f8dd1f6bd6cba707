"""Stage 4: keep the samples that reach the target within tolerance and lie within the limits."""

from __future__ import annotations

import numpy as np

from service.pipeline.arrays import BoolArray, FloatArray
from service.pipeline.types import Acceptance, Correction


def accept(
    correction: Correction,
    tolerance_position_m: float,
    tolerance_orientation_rad: float,
    lower_rad: FloatArray,  # (n,)
    upper_rad: FloatArray,  # (n,)
    periodic: BoolArray,  # (n,)
) -> Acceptance:
    """Tolerance mask (NaN and inf errors fail it) and joint-limit mask (periodic joints pass)."""
    within_tolerance = (correction.position_error_m <= tolerance_position_m) & (
        correction.orientation_error_rad <= tolerance_orientation_rad
    )
    q = correction.q_rad  # (N, n)
    inside = (q >= lower_rad) & (q <= upper_rad)  # (N, n), False for NaN
    within_limits = np.all(inside | periodic, axis=1) & np.all(np.isfinite(q), axis=1)
    return Acceptance(within_tolerance=within_tolerance, within_limits=within_limits)
