"""space: a step between two points of the planar 3R's closed-form loop, either side of a
joint's peak, is inside the limits between its ends until a limit 5 mrad under the peak
cuts the loop there (`inside_between`, either way along it); a step no longer than the
check's spacing, or one whose ends lie farther from every limit than a path of stretch x
the step could go, is not checked; `motion_valid` refuses a step so cut only with a limit check."""

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.joint_space import JointLimits
from service.pipeline.space import LimitCheck
from tests.service.pipeline.fibre_support import bump_of, fibre_space, planar_fibre
from training.evaluate.references.planar3r import closed_form_smm

PERIODIC = np.ones(3, dtype=bool)
LOWER, UPPER = np.full(3, -np.pi), np.full(3, np.pi)
TOLERANCE = 1e-4


def test_a_step_over_a_joint_peak_is_inside_until_a_limit_cuts_the_peak(
    planar3r: ServedModel,
) -> None:
    target = np.array([1.5, 0.5])
    (loop,) = closed_form_smm(target, phi_step_rad=0.001)
    fibre = planar_fibre(planar3r, target)
    joint, before, peak, after = bump_of(loop)
    a, b = loop[[before]], loop[[after]]  # (1, 3) each, about 1 rad apart
    free = fibre_space(fibre, JointLimits(LOWER, UPPER, PERIODIC), ())
    limited = PERIODIC.copy()
    limited[joint] = False
    upper = UPPER.copy()
    upper[joint] = loop[peak, joint] - 0.005  # both ends 45 mrad under it
    cut = fibre_space(fibre, JointLimits(LOWER, upper, limited), ())
    check = LimitCheck(spacing_rad=0.01, stretch=2.0)
    assert cut.inside_between(a, b, check, TOLERANCE).tolist() == [False]
    assert cut.inside_between(b, a, check, TOLERANCE).tolist() == [False]
    assert free.inside_between(a, b, check, TOLERANCE).tolist() == [True]
    # Not checked: a step no longer than the spacing, and one whose ends lie farther from
    # every limit than a path of stretch x the step could go (both ends 45 mrad under the
    # cut: a path 0.04 x the 1.07 rad step long could not reach it and come back).
    coarse = LimitCheck(spacing_rad=1.5, stretch=2.0)
    assert cut.inside_between(a, b, coarse, TOLERANCE).tolist() == [True]
    short = LimitCheck(spacing_rad=0.01, stretch=0.04)
    assert cut.inside_between(a, b, short, TOLERANCE).tolist() == [True]
    # motion_valid: the landing check alone takes the step, the limit check refuses it.
    error = np.zeros(1)
    assert cut.motion_valid(a, b, error, 10.0, TOLERANCE).tolist() == [True]
    assert cut.motion_valid(a, b, error, 10.0, TOLERANCE, limit_check=check).tolist() == [False]
