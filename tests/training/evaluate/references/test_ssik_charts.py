"""references.ssik_charts: ssik's closed-form charts as components, checked independently.

ssik's prebuilt iiwa14 and Panda end where the bundled chains' FK says (the Panda through
PANDA_TOOL) at random configurations, to 1e-12. On random full-pose targets of each, the
glued in-limit arcs are the exact reference's components in number (training/evaluate/
truth.py, its own closed form and continuation), and every returned point reaches the
target by the bundled FK within 1e-7 m (the closed form is exact to ~1e-7 at a fold of
its coordinate, ssik says), lies inside the limits, and lies within the path
spacing (times 1.5) of the next along its arc; the generating configuration lies within
that spacing of a point of some component. An arm ssik lacks is not supported.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import load_model
from training.evaluate.references import ssik_charts
from training.evaluate.targets import uniform_configurations
from training.evaluate.truth import ground_truth

MODELS = [("iiwa14-pose", "iiwa14"), ("panda-pose", "panda")]
SPACING_RAD = 0.05


def _pose(position_m: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, position_m
    return pose


@pytest.mark.parametrize(("model_id", "robot"), MODELS)
def test_ssiks_arm_ends_where_the_bundled_chain_does(model_id: str, robot: str) -> None:
    model = load_model(REPO_MODELS_DIR / model_id, threads=1)
    arm = ssik_charts.manipulator(robot)
    tool = ssik_charts.ARMS[robot][1]
    for q in uniform_configurations(model.limits, 10, seed=1):
        fk = model.kinematics(q[None])
        ours = _pose(fk.position_m[0], fk.rotation[0]) @ tool
        np.testing.assert_allclose(np.asarray(arm.fk(q)), ours, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("model_id", "robot"), MODELS)
def test_the_glued_arcs_are_the_exact_components(model_id: str, robot: str) -> None:
    model = load_model(REPO_MODELS_DIR / model_id, threads=1)
    limits = model.limits
    for i, q in enumerate(uniform_configurations(limits, 6, seed=2)):
        fk = model.kinematics(q[None])
        pose = _pose(fk.position_m[0], fk.rotation[0])
        charted = ssik_charts.chart_components(
            robot, pose, limits.lower_rad, limits.upper_rad, SPACING_RAD
        )
        truth = ground_truth(model, q, seed=i)
        assert int(charted.component.max(initial=-1)) + 1 == truth.count
        reached = model.kinematics(charted.q_rad)
        assert np.linalg.norm(reached.position_m - fk.position_m[0], axis=1).max() < 1e-7
        assert limits.contains(charted.q_rad).all()
        assert np.linalg.norm(charted.q_rad - q, axis=1).min() < SPACING_RAD
        # Along each arc (rows of one component in order, arcs concatenated) the steps are
        # at the spacing, but for the jumps from one arc to the next.
        steps = np.linalg.norm(np.diff(charted.q_rad, axis=0), axis=1)
        same = charted.component[1:] == charted.component[:-1]
        assert (steps[same] <= 1.5 * SPACING_RAD).mean() > 0.99


def test_an_arm_ssik_lacks_is_not_supported() -> None:
    assert not ssik_charts.supported("planar3r")
    assert ssik_charts.supported("iiwa14")
