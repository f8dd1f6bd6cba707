"""Stage 3, second half (r > 1): move samples that reach the target outside the joint
limits onto the fibre inside them.

A corrected sample within tolerance but outside the limits lies on the fibre, next to
the part of it inside the limits more often than not: at the edge of a small
component, whose inside the flow barely samples. Rejecting it can lose the component:
on the iiwa14 position report target 81, a component of 1.5 % of the fibre drew 0 to
10 accepted samples out of 1000 over 30 seeds (none on one seed, the report's miss),
and 1 to 10 samples within tolerance just outside the limits; pulled in, it draws 2
to 12 and none is lost. On the Panda position target 98 (a 1.5 % component behind the
Panda's tight limits) the seeds without an accepted sample in it fell from 11 of 30 to 3.

The pull is locked-joint damped least squares: a joint outside its limits is set onto
the limit it crossed and held there (its Jacobian column zeroed), and DLS steps on the
remaining joints bring the task error back down; a free joint that crosses a limit on
the way is locked at the next step. With r > 1 the free joints keep the task reachable
unless most are locked. A pulled sample replaces the original only where it ends within
tolerance and inside the limits: every returned configuration stays exact, and the
others stay rejected for the limits, as they were.

For r = 1 the tracing stage already walks from such samples along their curves into the
limits (connect/trace/), so this runs for r > 1 only.
"""

from __future__ import annotations

import numpy as np

from service.pipeline.correction import dls_step, error_norms
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.space import FibreSpace
from service.pipeline.types import Correction

# Locked-joint DLS steps. A locked joint can move a sample by a radian or more, which
# undoes the task by up to the arm's reach; on the iiwa14 and Panda position targets 6
# steps bring 96 to 100 % of the pulled samples within 1e-6 m (4 steps: 90 %).
PULL_STEPS = 6


def pull_into_limits(
    correction: Correction,
    space: FibreSpace,
    steps: int = PULL_STEPS,
    deadline: Deadline = NO_DEADLINE,
) -> Correction:
    """`correction` with its samples that are within tolerance but outside the limits
    replaced by locked-joint DLS pulls of them that end valid (`FibreSpace.accept`);
    every other row as it was."""
    fibre, limits = space.fibre, space.limits
    before = space.accept(correction)
    rows = np.flatnonzero(before.within_tolerance & ~before.within_limits)  # (P,)
    if not len(rows):
        return correction
    q = correction.q_rad[rows]  # (P, n)
    locked = np.zeros(q.shape, dtype=bool)  # (P, n)
    for _ in range(steps):
        deadline.check("correct")
        locked |= limits.outside(q)
        q = limits.clip(q)
        error, jacobian = fibre.residual(q)  # (P, m), (P, m, n)
        free_jacobian = np.where(locked[:, None, :], 0.0, jacobian)  # (P, m, n)
        q = q + dls_step(free_jacobian, error, fibre.damping)
    error, jacobian = fibre.residual(q)
    pulled = Correction(q, *error_norms(error, fibre.task), jacobian)  # (P,) rows
    kept = space.accept(pulled).accepted  # (P,)
    if not kept.any():
        return correction
    into = rows[kept]
    q_out, jacobian_out = correction.q_rad.copy(), correction.jacobian.copy()
    position_out = correction.position_error_m.copy()
    orientation_out = correction.orientation_error_rad.copy()
    q_out[into], jacobian_out[into] = q[kept], jacobian[kept]
    position_out[into] = pulled.position_error_m[kept]
    orientation_out[into] = pulled.orientation_error_rad[kept]
    return Correction(q_out, position_out, orientation_out, jacobian_out)
