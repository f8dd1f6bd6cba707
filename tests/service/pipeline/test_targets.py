"""targets: the target's shape is checked against the task and encoded as the manifest says."""

import numpy as np
import pytest

from service.errors import RequestFieldError
from service.manifest import AffineNormalisation, ConditionSpec, TaskSpec
from service.pipeline.targets import condition_names, encode_target, validate_target

PLANAR = TaskSpec(name="position", position_axes=[0, 1], orientation=False)
POSE = TaskSpec(name="pose", position_axes=[0, 1, 2], orientation=True)


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
