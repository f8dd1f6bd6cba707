"""The exact SMM of a pose target, traced as the kinematic report's ground truth traces it
(training/evaluate/truth.py's references: the iiwa14 closed form, the Panda's EAIK
sweep), each curve taken at the pieces' resolution and cut by coal (pieces.py).

Which curve is a loop: the Panda's reference says so; an iiwa14 component is a loop when
it is the branch's whole circle of arm angles, whose last point is one arm-angle step
from its first (an arc cut by a limit ends at least the cut's width away).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.arrays import FloatArray
from service.pipeline.collision.scene import Obstacle
from training.evaluate.scenes.coal_model import CoalModel
from training.evaluate.scenes.pieces import CutCurve, FreePieces, at_resolution, cut_curve
from training.evaluate.truth import REFERENCES


def _closed(component: object, q_rad: FloatArray) -> bool:
    closed = getattr(component, "closed", None)
    if closed is not None:
        return bool(closed)
    steps = np.linalg.norm(np.diff(q_rad, axis=0), axis=1)
    return bool(np.linalg.norm(q_rad[-1] - q_rad[0]) <= 2 * steps.max(initial=0.0))


def free_pieces_of_pose(
    model: ServedModel,
    coal: CoalModel,
    q_target_rad: FloatArray,
    obstacles: Sequence[Obstacle],
    margin_m: float,
) -> FreePieces:
    """The free pieces of the exact SMM of the pose q_target reaches (a pose model)."""
    fk = model.kinematics(q_target_rad[None])
    exact = REFERENCES[model.manifest.robot].pose_smm(fk.position_m[0], fk.rotation[0])
    curves: list[CutCurve] = []
    for component in exact:
        closed = _closed(component, component.q_rad)
        q = at_resolution(component.q_rad)
        curves.append(cut_curve(q, closed, coal.free(q, obstacles, margin_m)))
    return FreePieces.of(curves, float(sum(c.arc_length_rad for c in exact)))
