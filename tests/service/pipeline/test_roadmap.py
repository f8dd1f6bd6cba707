"""roadmap (stage 5 for r > 1): on the iiwa14's 4-D position fibre, a null-space random walk
along one component comes back as one component, and the elbow-up and elbow-down
components, nearer each other than the 2.5 rad radius the service used to join samples
with, stay two."""

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.connectivity import planner_settings, roadmap_settings
from service.pipeline.fibre import project
from service.pipeline.roadmap import roadmap_labels
from service.pipeline.run import run
from service.pipeline.types import Query
from tests.service.pipeline.fibre_support import pose_fibre

OLD_RADIUS_RAD = 2.5  # the radius graph's default for this model before stage 5


@pytest.fixture(scope="module")
def iiwa14_position() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-position", threads=1)


def null_space_walk(model: ServedModel, q0: np.ndarray, steps: int, seed: int) -> np.ndarray:
    """(k, 7) configurations along a random walk on the fibre of q0's position: each step
    0.05 rad along the null-space part of a slowly turning random direction, projected
    back; a step that would leave the limits is not taken and the direction is redrawn."""
    fibre = pose_fibre(model, q0)
    lower, upper, _ = model.manifest.joints.arrays()
    rng = np.random.default_rng(seed)
    walk = [q0]
    heading = rng.normal(size=7)
    for _ in range(steps):
        q = walk[-1]
        _, jacobian = fibre.residual(q[None])
        heading = 0.9 * heading + 0.3 * rng.normal(size=7)
        d = heading - np.linalg.pinv(jacobian[0]) @ (jacobian[0] @ heading)  # tangent part
        projected = project(fibre, (q + 0.05 * d / np.linalg.norm(d))[None], 4)
        nxt = projected.q_rad[0]
        if projected.error_norm[0] < 1e-10 and np.all((nxt >= lower) & (nxt <= upper)):
            walk.append(nxt)
        else:
            heading = rng.normal(size=7)
    return np.asarray(walk)


def test_a_random_walk_along_one_component_is_one_component(
    iiwa14_position: ServedModel,
) -> None:
    q0 = np.array([0.3, 0.5, -0.4, -1.3, 0.6, 0.9, 0.2])
    walk = null_space_walk(iiwa14_position, q0, steps=400, seed=0)
    travelled = np.linalg.norm(walk[-1] - walk[0])
    assert len(walk) > 300 and travelled > 1.0
    # It crosses the wrist singular set (q6 = 0), where sparse samples come back split.
    assert walk[:, 5].min() < 0.0 < walk[:, 5].max()
    nodes = walk[::6][np.random.default_rng(1).permutation(len(walk[::6]))]  # ~0.3 rad apart
    spec = iiwa14_position.manifest.defaults.connectivity
    lower, upper, periodic = iiwa14_position.manifest.joints.arrays()
    labels = roadmap_labels(
        pose_fibre(iiwa14_position, q0), nodes, lower, upper, periodic,
        planner_settings(spec), roadmap_settings(spec),
    )  # fmt: skip
    assert set(labels.tolist()) == {0}


def test_elbow_up_and_down_stay_two_though_nearer_than_the_old_radius(
    iiwa14_position: ServedModel,
) -> None:
    # The target is 0.674 m from the shoulder; with the elbow straight (q4 = 0) the end
    # effector is 0.82 +- 0.126 m from it, so q4 never reaches 0 on this fibre: the
    # elbow-up and elbow-down samples lie on different components.
    position = [0.544, 0.136, 0.734]
    query = Query.for_model(iiwa14_position.manifest, position_m=position, num_samples=600, seed=3)
    result = run(iiwa14_position, query)
    components = [c.configurations_rad for c in result.components if c.size >= 20]
    elbow = [np.sign(c[:, 3]) for c in components]
    assert all(len(set(side.tolist())) == 1 for side in elbow)  # no component mixes them
    up = np.concatenate([c for c, s in zip(components, elbow, strict=True) if s[0] > 0])
    down = np.concatenate([c for c, s in zip(components, elbow, strict=True) if s[0] < 0])
    nearest = np.min(np.linalg.norm(up[:, None, :] - down[None, :, :], axis=2))
    assert nearest < OLD_RADIUS_RAD  # a radius graph would have joined them
