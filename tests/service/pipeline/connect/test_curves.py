"""curves: which samples lie on the curves traced so far, and tracing those that do not.

`off_the_reached` measures in the joint metric (a periodic joint wraps): a sample within
the distance of a reached point is on, one beyond it off, every sample off an empty set.
`extend_curves` on the planar 3R (two loops at 0.5 m, by the closed form of
training/evaluate/references/planar3r.py): samples on the traced loop add nothing and
count no stray; a sample of the other loop is traced, its loop added once, and the
reached points grow.
"""

from __future__ import annotations

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.connect import extend_curves, trace_curves
from service.pipeline.connect.curves import off_the_reached
from service.pipeline.deadline import NO_DEADLINE
from service.pipeline.joint_space import JointLimits
from service.pipeline.run import collision_of, encode, space_of
from service.pipeline.types import Query
from training.evaluate.references.planar3r import closed_form_smm


def test_off_the_reached_uses_the_joint_metric() -> None:
    limits = JointLimits(
        lower_rad=np.array([-np.pi, -1.0]), upper_rad=np.array([np.pi, 1.0]),
        periodic=np.array([True, False]),
    )  # fmt: skip
    reached = np.array([[3.1, 0.0], [0.0, 0.5]])
    q = np.array([[-3.1, 0.05], [0.0, 0.72], [0.0, 0.68], [1.5, 0.0]])
    # (-3.1, 0.05) is 0.083 + from (3.1, 0) across the wrap; 0.22 and 0.18 from (0, 0.5).
    assert off_the_reached(q, reached, limits, 0.2).tolist() == [False, True, False, True]
    assert off_the_reached(q, reached[:0], limits, 0.2).all()


def test_extend_traces_only_samples_on_no_traced_curve(planar3r: ServedModel) -> None:
    query = Query.for_model(planar3r.manifest, position_m=[0.5, 0.0], seed=0)
    target = encode(planar3r, query)
    space = space_of(planar3r, target, query.tolerance, collision_of(planar3r, query))
    spec = planar3r.manifest.defaults.connectivity
    up, down = closed_form_smm(np.array([0.5, 0.0]), phi_step_rad=0.37)
    curves = trace_curves(space, up[:2], up[:2], spec, NO_DEADLINE).curves
    assert len(curves.paths) == 1 and len(curves.reached_rad) > 10
    same = extend_curves(curves, space, up[5:9], spec, NO_DEADLINE)
    assert same.curves is curves and same.strays == 0 and same.owner.tolist() == [0] * 4
    q_mixed = np.concatenate([up[3:4], down[2:3]])
    more = extend_curves(curves, space, q_mixed, spec, NO_DEADLINE)
    assert more.strays == 1 and len(more.curves.paths) == 2
    assert more.owner[0] == 0 and more.owner[1] == 1  # the new path is the down loop's
    assert len(more.curves.reached_rad) > len(curves.reached_rad)
    again = extend_curves(more.curves, space, down[4:6], spec, NO_DEADLINE)
    assert again.curves is more.curves and again.strays == 0 and again.owner.tolist() == [1, 1]
