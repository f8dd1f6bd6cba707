"""reference_fk: the iiwa14 pose model's answers, re-checked by the paper's DH table (no
code shared with the URDF or the ONNX export), reach their targets within the served
tolerances; an answer moved off its target by a joint offset is caught; a robot without a
reference FK gets no check.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from service.models.registry import ServedModel
from training.evaluate.methods import served_target
from training.evaluate.reference_fk import reference_fk_check
from training.evaluate.targets import uniform_configurations


def test_iiwa14_pose_answers_are_exact_by_the_dh_table(iiwa14_pose_model: ServedModel) -> None:
    limits = iiwa14_pose_model.limits
    q_targets = uniform_configurations(limits, 2, seed=3)
    answers = [served_target(iiwa14_pose_model, q, 300, seed=i) for i, q in enumerate(q_targets)]
    checked = reference_fk_check(iiwa14_pose_model, q_targets, answers)
    assert checked is not None and checked.configurations > 0
    assert checked.within_tolerance
    assert checked.max_position_error_m <= 1e-6
    assert checked.max_orientation_error_rad is not None
    assert checked.max_orientation_error_rad <= 1e-6

    moved = [replace(answers[0], returned=answers[0].returned + np.array([0.01] + [0.0] * 6))]
    off = reference_fk_check(iiwa14_pose_model, q_targets[:1], moved)
    assert off is not None and not off.within_tolerance
    assert off.max_position_error_m > 1e-4


def test_a_robot_without_a_reference_fk_is_not_checked(iiwa14_pose_model: ServedModel) -> None:
    manifest = iiwa14_pose_model.manifest.model_copy(update={"robot": "my_arm"})
    unknown = replace(iiwa14_pose_model, manifest=manifest)
    assert reference_fk_check(unknown, np.zeros((0, 7)), []) is None
