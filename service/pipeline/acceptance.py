"""Stage 4: keep the samples that reach the target within tolerance and lie within the limits
(the space then keeps those free of collision: `FibreSpace.accept`)."""

from __future__ import annotations

import numpy as np

from service.pipeline.joint_space import JointLimits
from service.pipeline.types import Acceptance, Correction, Tolerance


def accept(correction: Correction, tolerance: Tolerance, limits: JointLimits) -> Acceptance:
    """Tolerance mask (NaN and inf errors fail it) and joint-limit mask (periodic joints
    pass; a configuration that is not finite fails)."""
    q = correction.q_rad  # (N, n)
    return Acceptance(
        collision_free=np.ones(len(q), dtype=bool),
        within_tolerance=tolerance.within(
            correction.position_error_m, correction.orientation_error_rad
        ),
        within_limits=limits.contains(q) & np.all(np.isfinite(q), axis=1),
    )
