"""Coaxial joints: the singular sets where a fibre passes between twin branches.

When the joint j between joints i = j - 1 and k = j + 1 of a serial chain turns the
axis of joint k onto the line of joint i, the two joints share one axis: turning i by a
and k by -a (or +a when the axes point opposite ways) leaves every link beyond k where
it was. So on that set the fibre of every target holds whole straight lines
q + a s, s = e_i - sign e_k, exactly: a finite self-motion along which, for example, the
iiwa's shoulder (q2 = 0: q1 + q3 fixed), elbow (q4 = 0) and wrist (q6 = 0) branches meet
their twins. A straight-line local planner between samples on the two sides rarely
finds that passage (the twins are pi apart in q_i and q_k), so the roadmap places nodes
on it (roadmap.py).

The sets also catch a walk that jumps between twins. A path on a fibre from one side of
a set to the other (q_j - angle changing sign) passes through a point of the fibre on
the set, so a step of a walk that crosses a set where the fibre does not reach it has
jumped onto a nearby twin (`FibreSpace.crossings_on_fibre`, part of whether a motion is
valid): near a set the twins can be a few hundredths of a radian apart, much less than
a step.

Whether axes i and k coincide depends only on q_j (the chain between them), so the sets
are found once per model from the kinematics alone: the twist columns J_i and J_k of
the geometric Jacobian are equal (same line, same direction) or opposite exactly when
the axes are one line. Sets of two joints aligned through more than one joint between
them (a curve in two angles) are not searched.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from service.pipeline.arrays import FloatArray
from service.pipeline.joint_space import TWO_PI, JointLimits, wrap_to_pi
from service.pipeline.types import CoaxialSet, Kinematics

SCAN_POINTS = 720  # angles of q_j scanned per joint (0.5 degree apart) before refinement
COAXIAL_TOLERANCE = 1e-9  # |J_i -+ J_k| at the refined angle (m and rad, twist units)


def find_coaxial_sets(kinematics: Kinematics, limits: JointLimits) -> list[CoaxialSet]:
    """Every angle of a joint j, inside its limits, at which joints j - 1 and j + 1 are coaxial."""
    n = limits.count
    lower_rad, upper_rad, periodic = limits.lower_rad, limits.upper_rad, limits.periodic
    found: list[CoaxialSet] = []
    theta = np.linspace(-np.pi, np.pi, SCAN_POINTS, endpoint=False)  # (T,)
    for j in range(1, n - 1):
        i, k = j - 1, j + 1

        def mismatch(angles: FloatArray, i: int = i, j: int = j, k: int = k) -> FloatArray:
            q = np.zeros((len(angles), n))
            q[:, j] = angles
            jacobian = kinematics(q).jacobian  # (T, 6, n)
            same = np.linalg.norm(jacobian[:, :, i] - jacobian[:, :, k], axis=1)
            opposite = np.linalg.norm(jacobian[:, :, i] + jacobian[:, :, k], axis=1)
            return np.minimum(same, opposite)  # (T,)

        scan = mismatch(theta)
        # Local minima of the scan (on the circle), refined by a bounded scalar search.
        minima = np.flatnonzero((scan <= np.roll(scan, 1)) & (scan <= np.roll(scan, -1)))
        step = TWO_PI / SCAN_POINTS
        for m in minima:
            if scan[m] > 0.05:
                continue
            best = minimize_scalar(
                lambda a: float(mismatch(np.array([a]))[0]),
                bounds=(theta[m] - step, theta[m] + step),
                method="bounded",
                options={"xatol": 1e-13},
            )
            angle = float(wrap_to_pi(np.array(best.x)))
            if not best.fun <= COAXIAL_TOLERANCE:
                continue
            if not periodic[j] and not lower_rad[j] <= angle <= upper_rad[j]:
                continue
            q = np.zeros((1, n))
            q[0, j] = angle
            jacobian = kinematics(q).jacobian[0]  # (6, n)
            sign = (
                1.0
                if np.linalg.norm(jacobian[:, i] - jacobian[:, k]) <= COAXIAL_TOLERANCE
                else -1.0
            )
            slide = np.zeros(n)
            slide[i], slide[k] = 1.0, -sign
            if not any(s.joint == j and abs(s.angle_rad - angle) < 1e-6 for s in found):
                found.append(CoaxialSet(joint=j, angle_rad=angle, slide=slide))
    return found


def slide_range(
    coaxial: CoaxialSet,
    q_rad: FloatArray,  # (B, n) on the set
    limits: JointLimits,
) -> tuple[FloatArray, FloatArray]:  # (B,), (B,) smallest and largest a inside the limits
    """The interval of a for which q + a slide stays inside the limits (periodic: +-pi)."""
    lower_rad, upper_rad, periodic = limits.lower_rad, limits.upper_rad, limits.periodic
    low = np.full(len(q_rad), -np.pi)
    high = np.full(len(q_rad), np.pi)
    for joint in coaxial.moving:
        direction = coaxial.slide[joint]
        if periodic[joint]:
            continue
        room_up = (upper_rad[joint] - q_rad[:, joint]) / direction
        room_down = (lower_rad[joint] - q_rad[:, joint]) / direction
        low = np.maximum(low, np.minimum(room_up, room_down))
        high = np.minimum(high, np.maximum(room_up, room_down))
    return low, high
