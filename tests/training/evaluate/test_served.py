"""served: the client's view of a model: candidate defaults, the configurations and stage
times of an answer, and a rotation as the request's {w, x, y, z} quaternion.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from service.models.registry import ServedModel
from service.pipeline.run import run
from service.pipeline.types import Query
from training.evaluate.served import (
    orientation_wxyz,
    returned_configurations,
    stage_times_ms,
    with_defaults,
)


def test_with_defaults_changes_only_the_named_defaults_of_a_copy(planar3r: ServedModel) -> None:
    before = planar3r.manifest.defaults
    candidate = with_defaults(planar3r, correction_steps=17)
    assert candidate.manifest.defaults.correction_steps == 17
    assert candidate.manifest.defaults.model_copy(update={"correction_steps": 0}) == (
        before.model_copy(update={"correction_steps": 0})
    )
    assert planar3r.manifest.defaults == before  # the served model is untouched


def test_returned_configurations_and_stage_times_of_an_answer(planar3r: ServedModel) -> None:
    query = Query.for_model(planar3r.manifest, position_m=[2.0, 0.0], num_samples=200, seed=0)
    result = run(planar3r, query)
    q_rad = returned_configurations(result, 3)
    path_points = sum(len(c.path.q_rad) for c in result.components if c.path is not None)
    assert path_points > 0  # the planar arm is r = 1: every component has its path
    assert q_rad.shape == (result.counts.accepted + path_points, 3)
    samples_only = returned_configurations(result, 3, include_paths=False)
    assert samples_only.shape == (result.counts.accepted, 3)
    times_ms = stage_times_ms(result)
    assert set(times_ms) == {
        "encode", "sample", "correct", "accept", "connect", "summarise", "total"
    }  # fmt: skip
    assert all(isinstance(span, str) and ms >= 0.0 for span, ms in times_ms.items())
    unreachable = Query.for_model(planar3r.manifest, position_m=[9.0, 0.0], num_samples=50, seed=0)
    assert returned_configurations(run(planar3r, unreachable), 3).shape == (0, 3)


def test_orientation_wxyz_puts_the_scalar_first() -> None:
    assert orientation_wxyz(np.eye(3)) == (1.0, 0.0, 0.0, 0.0)
    rotation = Rotation.from_rotvec([0.0, 0.0, np.pi / 2])
    w, x, y, z = orientation_wxyz(rotation.as_matrix())
    np.testing.assert_allclose([w, x, y, z], [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])
