"""Stage 1: validate a target against the model's task and encode it as the flow's condition.

The condition encoding is shared with training (`training.data` labels its data with
`condition_features`), so the service and the flow can never disagree on the layout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.errors import RequestFieldError
from service.manifest import ConditionSpec, TaskSpec
from service.pipeline.arrays import Float32Array, FloatArray
from service.pipeline.rotations import quaternion_to_matrix, rotation_6d

AXIS_NAMES = ("x", "y", "z")
# A quaternion whose norm is within this of 1 is normalised; anything else is refused,
# because a far-from-unit quaternion usually means a unit or ordering mistake upstream.
QUATERNION_NORM_TOLERANCE = 1e-2


@dataclass(frozen=True)
class Target:
    """A validated target in the robot's base frame and its encoded condition."""

    position_m: FloatArray  # (m_p,) the constrained position axes only
    rotation: FloatArray | None  # (3, 3), None for a position task
    condition: Float32Array  # (c,) normalised, as the flow expects


def condition_names(task: TaskSpec) -> list[str]:
    """Names of the condition vector's entries: constrained position axes, then the 6-D rotation."""
    names = [f"p_{AXIS_NAMES[a]}" for a in task.position_axes]
    if task.orientation:
        names += [f"r_{row}{col}" for col in (0, 1) for row in range(3)]
    return names


def condition_features(
    task: TaskSpec, position_m: FloatArray, rotation: FloatArray | None
) -> FloatArray:
    """Raw (un-normalised) condition (B, c) from positions (B, m_p) and rotations (B, 3, 3)."""
    if not task.orientation:
        return position_m
    if rotation is None:
        raise ValueError("a pose task needs rotations")
    return np.concatenate([position_m, rotation_6d(rotation)], axis=-1)


def validate_target(
    task: TaskSpec,
    position_m: list[float],
    orientation_wxyz: tuple[float, float, float, float] | None,
) -> None:
    """Check the target's shape against the task; RequestFieldError names the field.

    `Query.for_model` calls it, so every query the stages see has passed it.
    """
    expected = len(task.position_axes)
    if len(position_m) != expected:
        axes = ", ".join(AXIS_NAMES[a] for a in task.position_axes)
        raise RequestFieldError(
            ("body", "target", "position"),
            f"target.position must have {expected} values ({axes}) for the {task.name} task "
            f"of this robot, got {len(position_m)}",
        )
    if task.orientation:
        if orientation_wxyz is None:
            raise RequestFieldError(
                ("body", "target", "orientation"),
                "target.orientation (a unit quaternion {w, x, y, z}) is required for the pose task",
            )
        with np.errstate(over="ignore"):  # a norm past float range is inf: refused below
            norm = float(np.linalg.norm(orientation_wxyz))
        if not abs(norm - 1.0) <= QUATERNION_NORM_TOLERANCE:
            raise RequestFieldError(
                ("body", "target", "orientation"),
                f"target.orientation must be a unit quaternion (norm within "
                f"{QUATERNION_NORM_TOLERANCE} of 1, normalised then), got norm {norm:.6g}",
            )
    elif orientation_wxyz is not None:
        raise RequestFieldError(
            ("body", "target", "orientation"),
            "target.orientation is not allowed for the position task; use task 'pose' "
            "to constrain orientation",
        )


def encode_target(
    task: TaskSpec,
    condition: ConditionSpec,
    position_m: list[float],
    orientation_wxyz: tuple[float, float, float, float] | None,
) -> Target:
    """The target (already checked by `validate_target`) and its normalised condition."""
    rotation = None if orientation_wxyz is None else quaternion_to_matrix(*orientation_wxyz)
    position = np.asarray(position_m, dtype=np.float64)
    features = condition_features(
        task, position[None], None if rotation is None else rotation[None]
    )
    with np.errstate(over="ignore"):  # an absurdly far target overflows to inf: no_solution
        normalised = condition.normalisation.normalise(features)[0].astype(np.float32)
    return Target(position_m=position, rotation=rotation, condition=normalised)
