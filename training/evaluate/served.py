"""Asking the served model as a client would: queries for a target, candidate defaults,
and the configurations an answer returned."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from service.manifest import Defaults
from service.models.registry import ServedModel
from service.pipeline.arrays import FloatArray
from service.pipeline.rotations import matrix_to_quaternion
from service.pipeline.types import SmmResult


def serving(model: ServedModel, defaults: Defaults) -> ServedModel:
    """The same model serving `defaults` (for measuring candidates)."""
    return replace(model, manifest=model.manifest.model_copy(update={"defaults": defaults}))


def with_defaults(model: ServedModel, **changes: object) -> ServedModel:
    """The same model with some serving defaults changed (for measuring candidates)."""
    return serving(model, model.manifest.defaults.model_copy(update=changes))


def returned_configurations(
    result: SmmResult, num_joints: int, include_paths: bool = True
) -> FloatArray:
    """(K, n) every configuration a pipeline answer returned, all components together: the
    listed samples and (r = 1, unless include_paths is False) every point of each path."""
    listed = [c.configurations_rad for c in result.components]
    if include_paths:
        listed += [c.path.q_rad for c in result.components if c.path is not None]
    return np.concatenate(listed) if listed else np.zeros((0, num_joints))


def stage_times_ms(result: SmmResult) -> dict[str, float]:
    """Wall time of each timed span of an answer (`StageTimings.as_dict()`), in ms."""
    return {str(span): ms for span, ms in result.timings.as_dict().items()}


def orientation_wxyz(rotation: FloatArray) -> tuple[float, float, float, float]:
    """The unit quaternion {w, x, y, z} of a rotation matrix (3, 3), as a request sends it."""
    return matrix_to_quaternion(rotation)
