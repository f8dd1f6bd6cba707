"""targets: the target's shape is checked against the task (position, pose or tool axis) and
encoded as the manifest says."""

import numpy as np
import pytest

from service.errors import RequestFieldError
from service.manifest import AffineNormalisation, ConditionSpec, TaskSpec
from service.pipeline.targets import condition_names, encode_target, validate_target

PLANAR = TaskSpec(name="position", position_axes=[0, 1], orientation=False)
POSE = TaskSpec(name="pose", position_axes=[0, 1, 2], orientation=True)
AXIS = TaskSpec(name="axis", position_axes=[0, 1, 2], orientation=False, tool_axis=[0, 0, 1])


def spec(task: TaskSpec, offset: float = 0.0, scale: float = 1.0) -> ConditionSpec:
    size = len(condition_names(task))
    return ConditionSpec(
        names=condition_names(task),
        normalisation=AffineNormalisation(offset=[offset] * size, scale=[scale] * size),
    )


def test_position_condition_is_normalised_position() -> None:
    target = encode_target(PLANAR, spec(PLANAR, offset=1.0, scale=2.0), [0.5, -1.0], None)
    np.testing.assert_allclose(target.condition, [(0.5 - 1) / 2, (-1 - 1) / 2])
    assert target.rotation is None
    assert condition_names(PLANAR) == ["p_x", "p_y"]


def test_wrong_position_length_names_the_field_and_the_expected_length() -> None:
    with pytest.raises(RequestFieldError) as error:
        validate_target(PLANAR, [0.5, 0.0, 0.1], None)
    assert error.value.location == ("body", "target", "position")
    assert "must have 2 values (x, y)" in error.value.message


def test_orientation_refused_for_position_and_required_for_pose() -> None:
    with pytest.raises(RequestFieldError, match="not allowed for the position task"):
        validate_target(PLANAR, [0.5, 0.0], (1.0, 0.0, 0.0, 0.0))
    with pytest.raises(RequestFieldError, match="required for the pose task"):
        validate_target(POSE, [0.5, 0.0, 0.3], None)


def test_pose_condition_appends_the_6d_rotation_and_refuses_far_from_unit_quaternions() -> None:
    target = encode_target(POSE, spec(POSE), [0.1, 0.2, 0.3], (0.0, 1.0, 0.0, 0.0))
    # 180 deg about x: columns (1, 0, 0) and (0, -1, 0).
    np.testing.assert_allclose(target.condition, [0.1, 0.2, 0.3, 1, 0, 0, 0, -1, 0], atol=1e-7)
    validate_target(POSE, [0.1, 0.2, 0.3], (0.0, 1.005, 0.0, 0.0))  # near enough: normalised
    nearly_unit = encode_target(POSE, spec(POSE), [0.1, 0.2, 0.3], (0.0, 1.005, 0.0, 0.0))
    assert nearly_unit.rotation is not None and target.rotation is not None
    np.testing.assert_allclose(nearly_unit.rotation, target.rotation, atol=1e-12)
    for bad in [(0.0, 0.0, 0.0, 0.0), (0.0, 2.0, 0.0, 0.0)]:
        with pytest.raises(RequestFieldError, match="unit quaternion"):
            validate_target(POSE, [0.1, 0.2, 0.3], bad)


def test_axis_target_is_position_and_unit_axis_and_names_its_field() -> None:
    """The axis task's condition is the position and the unit axis (a near-unit axis is
    normalised); the axis is required there, refused elsewhere, and must be unit; the
    orientation is refused for it."""
    assert condition_names(AXIS) == ["p_x", "p_y", "p_z", "a_x", "a_y", "a_z"]
    target = encode_target(AXIS, spec(AXIS), [0.1, 0.2, 0.3], None, (0.0, 0.6, 0.805))
    assert target.axis is not None
    np.testing.assert_allclose(np.linalg.norm(target.axis), 1.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(target.condition[:3], [0.1, 0.2, 0.3], rtol=1e-7)
    np.testing.assert_allclose(target.condition[3:], target.axis, rtol=1e-7)
    assert target.rotation is None
    for task, axis, orientation, message in (
        (AXIS, None, None, "target.axis (a unit vector [x, y, z], base frame) is required"),
        (AXIS, (0.0, 0.0, 2.0), None, "must be a unit vector (norm within 0.01 of 1"),
        (AXIS, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0), "not allowed for the axis task"),
        (POSE, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0), "target.axis is not allowed for the pose"),
    ):
        with pytest.raises(RequestFieldError) as error:
            validate_target(task, [0.1, 0.2, 0.3], orientation, axis)
        assert message in error.value.message
        assert error.value.location[:2] == ("body", "target")


def test_an_axis_task_names_one_unit_tool_axis() -> None:
    """TaskSpec: the axis task has a unit tool axis and 5 coordinates; a tool axis on
    another task, a missing or non-unit one, or one beside the full orientation is refused."""
    assert AXIS.dimension == 5 and AXIS.orientation_rows == 2
    assert POSE.dimension == 6 and PLANAR.dimension == 2
    for fields in (
        {"name": "axis", "orientation": False},
        {"name": "axis", "orientation": False, "tool_axis": [0.0, 0.0, 2.0]},
        {"name": "position", "orientation": False, "tool_axis": [0.0, 0.0, 1.0]},
        {"name": "axis", "orientation": True, "tool_axis": [0.0, 0.0, 1.0]},
    ):
        with pytest.raises(ValueError, match="tool_axis"):
            TaskSpec(position_axes=[0, 1, 2], **fields)
