"""Stage 5 for r = 1: trace every curve of the fibre that a corrected sample lies on, whole.

The fibre of a regular target of a 1-D redundant arm is a union of closed curves on the
joint torus (every revolute joint is a circle to the kinematics; the limits come after).
Seeds are spread over the samples that reach the target (inside the limits or not);
from each, two fronts walk the curve in opposite directions by predictor-corrector
continuation: predict h along the unit tangent (the null vector of J), correct with
Newton on [J; t^T] dq = [e; 0]. All fronts advance in lockstep, one batched kinematics
call per corrector iteration. A front stops when it meets a front coming the other way
on the same curve (ends closer than the meeting distance, travelling head-on, the chord
between them along the tangent), so neighbouring seeds share the work and each curve
closes in about (largest gap between its seeds) / 2h steps. Chaining the fronts through
their seeds and meetings orders every curve; curves are then cut by the joint limits
(each end refined onto the limit with the limited joint held there) and densified to
the path spacing: points on the cubic Hermite curve through the traced points and their
tangents, each put on the fibre by Newton and evaluated where it is returned. Every
traced point keeps what the kinematics measured there (error, Jacobian, tangent), so no
point is evaluated twice.

A front that cannot go on (the corrector fails, a step jumps, the step budget runs out)
leaves its curve open there (the connect stage splices such pieces where the fibre joins
them: splicing.py); such a trace, a fibre whose Jacobian comes near rank
deficiency, and two strands of the fibre closer than the fronts' meeting distance
(`closest_strands_rad`: the meeting test cannot always tell them apart; next to a
singular value the fibre can run as twin strands a few hundredths of a radian apart, or
far less, while sigma_min(J) stays moderate, as on the planar 3R within 1e-4 of
|x| = 1) make the result `near_singular`.
"""

from __future__ import annotations

import numpy as np

from service.pipeline.arrays import FloatArray
from service.pipeline.connect.trace.cut import cut_by_limits, refine_near_limits
from service.pipeline.connect.trace.densify import densify
from service.pipeline.connect.trace.points import Evaluated, Trace, TraceSettings
from service.pipeline.connect.trace.seeds import spread_seeds
from service.pipeline.connect.trace.walk import walk_fronts
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import evaluate, min_singular_value, unit_tangent
from service.pipeline.rows import Aside
from service.pipeline.space import FibreSpace


def trace_fibre(
    space: FibreSpace,
    q_on_fibre_rad: FloatArray,  # (M, n) samples within tolerance, inside the limits or not
    settings: TraceSettings,
    deadline: Deadline = NO_DEADLINE,
) -> Trace:
    """Every curve through `q_on_fibre_rad`, cut by the limits, as ordered dense paths."""
    fibre, limits = space.fibre, space.limits
    if len(q_on_fibre_rad) == 0:
        return Trace(
            pieces=[], complete=True, min_singular_value=np.inf, reached_rad=q_on_fibre_rad[:0]
        )
    start = evaluate(fibre, spread_seeds(q_on_fibre_rad, settings.seed_spacing_rad))  # (S,)
    tangent0 = unit_tangent(start.jacobian)  # (S, n)
    seeds = Evaluated.of(start, tangent0).take(np.all(np.isfinite(tangent0), axis=1))
    evaluated, curves, complete = walk_fronts(fibre, seeds, settings, deadline)
    reached_rad = evaluated.q_rad  # (R, n) the whole curves, before the limits cut them
    # sigma_min over the seeds and every point the fronts reached.
    reached_jacobian = np.concatenate([start.jacobian, evaluated.jacobian[len(seeds) :]])
    sigma = Aside(
        lambda: min_singular_value(reached_jacobian), fibre.threads, len(reached_jacobian)
    )
    evaluated, curves = refine_near_limits(fibre, evaluated, curves, limits, settings)
    runs = cut_by_limits(curves, limits)
    dense = densify(fibre, evaluated, runs, limits, settings)
    return Trace(
        pieces=dense, complete=complete, min_singular_value=sigma.result(), reached_rad=reached_rad
    )
