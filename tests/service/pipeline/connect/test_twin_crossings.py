"""local_planner: an edge shorter than the planner's step is still checked across a coaxial
set, so samples on either side of a singular set that the fibre never reaches stay apart.

On the iiwa14's axis task with the flange's axis, the wrist centre is fixed, so |q4| is
fixed by the shoulder-wrist distance (DH geometry, not the service's): the elbow twins
(q4 > 0 and q4 < 0) meet only where q4 = 0, which such a fibre with |q4| > 0 never
reaches. Near the elbow's singular set (|q4| under 0.1 rad) the twins pass within the
roadmap's 0.3 rad step of each other, and at |q4| = 0.014 holding q4 = 0 leaves an error
of 2e-5 m, under the walks' 1e-4 (a set is reached only to 1e-6); every returned
component and roadmap node keeps one sign of q4.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.run import run
from service.pipeline.targets import fields_reached
from service.pipeline.types import Query
from training.evaluate.references.iiwa14 import dh_pose


@pytest.fixture(scope="module")
def iiwa14_axis() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-axis", threads=1)


def test_elbow_twins_near_the_elbow_set_are_never_one_component(iiwa14_axis: ServedModel) -> None:
    rng = np.random.default_rng(40)
    for q4 in (0.014, 0.049, 0.079, -0.06):
        q = np.array([*rng.uniform(-1.5, 1.5, 3), q4, *rng.uniform(-1.5, 1.5, 3)])
        pose = dh_pose(q[None])[0]
        fields = fields_reached(iiwa14_axis.manifest.task, pose[:3, 3], pose[:3, :3])
        query = Query.for_model(
            iiwa14_axis.manifest, position_m=fields.position_m, axis=fields.axis,
            num_samples=1000, check_self=False, include_roadmap=True,
        )  # fmt: skip
        result = run(iiwa14_axis, query)
        assert result.components
        for component in result.components:
            assert component.roadmap is not None
            signs = np.unique(np.sign(component.roadmap.q_rad[:, 3]))
            # |SW| moves by 0.42 * 0.40 sin|q4| / 0.82 m per rad of q4: the 1e-6 m (and
            # 1e-6 rad x 0.126 m) tolerance leaves q4 this much room.
            room = 2e-6 / (0.42 * 0.40 * np.sin(abs(q4)) / 0.82)
            np.testing.assert_allclose(np.abs(component.roadmap.q_rad[:, 3]), abs(q4), atol=room)
            assert len(signs) == 1, f"q4 = {q4}: a component holds both elbow twins"
