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
from service.pipeline.native import AxisTarget, OrientationTarget
from service.pipeline.rotations import (
    axis_frame,
    matrix_to_quaternion,
    quaternion_to_matrix,
    rotation_6d,
)

AXIS_NAMES = ("x", "y", "z")
# A quaternion whose norm is within this of 1 is normalised; anything else is refused,
# because a far-from-unit quaternion usually means a unit or ordering mistake upstream.
QUATERNION_NORM_TOLERANCE = 1e-2
# The same for the axis task's target axis.
AXIS_NORM_TOLERANCE = 1e-2


@dataclass(frozen=True)
class Target:
    """A validated target in the robot's base frame and its encoded condition."""

    position_m: FloatArray  # (m_p,) the constrained position axes only
    rotation: FloatArray | None  # (3, 3) for the pose task, else None
    condition: Float32Array  # (c,) normalised, as the flow expects
    axis: FloatArray | None = None  # (3,) unit, the tool axis's direction: axis task only


@dataclass(frozen=True)
class TargetFields:
    """A target as a client sends it: the task's position axes, and the orientation (pose
    task) or the tool axis's direction (axis task)."""

    position_m: list[float]
    orientation_wxyz: tuple[float, float, float, float] | None = None
    axis: tuple[float, float, float] | None = None

    def wire(self) -> dict[str, object]:
        """The request's `target` object."""
        fields: dict[str, object] = {"position": self.position_m}
        if self.orientation_wxyz is not None:
            fields["orientation"] = dict(zip("wxyz", self.orientation_wxyz, strict=True))
        if self.axis is not None:
            fields["axis"] = list(self.axis)
        return fields


def fields_reached(
    task: TaskSpec,
    position_m: FloatArray,  # (3,) an end-effector position, base frame
    rotation: FloatArray,  # (3, 3) its rotation
) -> TargetFields:
    """The target of `task` that an end-effector pose reaches (a configuration's FK)."""
    axis = None
    if task.tool_axis is not None:
        x, y, z = (float(v) for v in rotation @ np.asarray(task.tool_axis))
        axis = (x, y, z)
    return TargetFields(
        position_m=[float(position_m[a]) for a in task.position_axes],
        orientation_wxyz=matrix_to_quaternion(rotation) if task.orientation else None,
        axis=axis,
    )


def target_reached(
    task: TaskSpec,
    position_m: FloatArray,  # (3,)
    rotation: FloatArray,  # (3, 3)
) -> Target:
    """The Target (no condition) that an end-effector pose reaches: for the fibre through a
    known configuration, as the evaluation and the tests build it."""
    return Target(
        position_m=np.asarray(position_m, np.float64)[task.position_axes],
        rotation=rotation if task.orientation else None,
        condition=np.zeros(0, np.float32),
        axis=None if task.tool_axis is None else rotation @ np.asarray(task.tool_axis),
    )


def kernel_orientation(task: TaskSpec, target: Target) -> OrientationTarget:
    """The target's orientation part as the compiled kernels take it (`native.task_residual`):
    R* for the pose task, the axis frame for the axis task, None for a position task."""
    if task.orientation:
        return target.rotation
    if task.tool_axis is not None and target.axis is not None:
        return AxisTarget(axis_frame(target.axis, np.asarray(task.tool_axis)))
    return None


def condition_names(task: TaskSpec) -> list[str]:
    """Names of the condition vector's entries: constrained position axes, then the 6-D
    rotation (pose) or the tool axis's direction (axis)."""
    names = [f"p_{AXIS_NAMES[a]}" for a in task.position_axes]
    if task.orientation:
        names += [f"r_{row}{col}" for col in (0, 1) for row in range(3)]
    if task.tool_axis is not None:
        names += [f"a_{AXIS_NAMES[a]}" for a in range(3)]
    return names


def condition_features(
    task: TaskSpec,
    position_m: FloatArray,  # (B, m_p)
    rotation: FloatArray | None,  # (B, 3, 3) end-effector rotations
    axis: FloatArray | None = None,  # (B, 3) axis task: the tool axes' directions
) -> FloatArray:  # (B, c)
    """Raw (un-normalised) condition from positions and rotations (pose), or positions and
    tool-axis directions (axis: given, or the rotations' images of the tool axis)."""
    if task.tool_axis is not None:
        if axis is None and rotation is not None:
            axis = rotation @ np.asarray(task.tool_axis)
        if axis is None:
            raise ValueError("an axis task needs axes or rotations")
        return np.concatenate([position_m, axis], axis=-1)
    if not task.orientation:
        return position_m
    if rotation is None:
        raise ValueError("a pose task needs rotations")
    return np.concatenate([position_m, rotation_6d(rotation)], axis=-1)


def validate_target(
    task: TaskSpec,
    position_m: list[float],
    orientation_wxyz: tuple[float, float, float, float] | None,
    axis: tuple[float, float, float] | None = None,
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
        _require_unit(
            "orientation", "a unit quaternion", orientation_wxyz, QUATERNION_NORM_TOLERANCE
        )
    elif orientation_wxyz is not None:
        raise RequestFieldError(
            ("body", "target", "orientation"),
            f"target.orientation is not allowed for the {task.name} task; use task 'pose' "
            "to constrain the whole orientation",
        )
    if task.tool_axis is not None:
        if axis is None:
            raise RequestFieldError(
                ("body", "target", "axis"),
                "target.axis (a unit vector [x, y, z], base frame) is required for the axis task",
            )
        _require_unit("axis", "a unit vector", axis, AXIS_NORM_TOLERANCE)
    elif axis is not None:
        raise RequestFieldError(
            ("body", "target", "axis"),
            f"target.axis is not allowed for the {task.name} task; use task 'axis' to "
            "constrain the tool axis alone",
        )


def _require_unit(field: str, kind: str, value: tuple[float, ...], tolerance: float) -> None:
    """RequestFieldError naming target.<field> unless its norm is within `tolerance` of 1."""
    with np.errstate(over="ignore"):  # a norm past float range is inf: refused below
        norm = float(np.linalg.norm(value))
    if not abs(norm - 1.0) <= tolerance:
        raise RequestFieldError(
            ("body", "target", field),
            f"target.{field} must be {kind} (norm within {tolerance} of 1, normalised then), "
            f"got norm {norm:.6g}",
        )


def encode_target(
    task: TaskSpec,
    condition: ConditionSpec,
    position_m: list[float],
    orientation_wxyz: tuple[float, float, float, float] | None,
    axis: tuple[float, float, float] | None = None,
) -> Target:
    """The target (already checked by `validate_target`) and its normalised condition."""
    rotation = None if orientation_wxyz is None else quaternion_to_matrix(*orientation_wxyz)
    unit_axis = None if axis is None else np.asarray(axis, np.float64) / np.linalg.norm(axis)
    position = np.asarray(position_m, dtype=np.float64)
    features = condition_features(
        task,
        position[None],
        None if rotation is None else rotation[None],
        None if unit_axis is None else unit_axis[None],
    )
    with np.errstate(over="ignore"):  # an absurdly far target overflows to inf: no_solution
        normalised = condition.normalisation.normalise(features)[0].astype(np.float32)
    return Target(position_m=position, rotation=rotation, condition=normalised, axis=unit_axis)
