"""Fibres of the bundled models for the connect-stage tests, and exact points on them."""

from __future__ import annotations

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.fibre import Fibre
from service.pipeline.targets import Target


def planar_fibre(model: ServedModel, target_m: np.ndarray) -> Fibre:
    manifest = model.manifest
    target = Target(position_m=target_m, rotation=None, condition=np.zeros(1, np.float32))
    return Fibre(target=target, task=manifest.task, kinematics=model.kinematics, damping=1e-3)


def pose_fibre(model: ServedModel, q_target: np.ndarray) -> Fibre:
    """The fibre of the pose (or position) that q_target (n,) reaches."""
    manifest = model.manifest
    fk = model.kinematics(q_target[None])
    rotation = fk.rotation[0] if manifest.task.orientation else None
    target = Target(
        position_m=fk.position_m[0, manifest.task.position_axes],
        rotation=rotation,
        condition=np.zeros(1, np.float32),
    )
    return Fibre(target=target, task=manifest.task, kinematics=model.kinematics, damping=1e-3)
