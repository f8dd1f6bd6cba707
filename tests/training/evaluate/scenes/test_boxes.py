"""training.evaluate.scenes.boxes: seeded random box scenes around the Panda.

The same (seed, index) gives the same target and scene, another index another; the
target is free of self-collision and each box is clear of it by the margin, both judged
by coal's distances (not the collide-with-margin verdict the generator used); every box
is as the module says (sides 0.05 to 0.4 m, centre within the reach of the base and
above its floor, a unit quaternion); the POST body carries the scene as the API's
obstacles and the target whose FK the model gives.
"""

from __future__ import annotations

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.collision.scene import Obstacle
from training.evaluate.scenes.boxes import request_body, scene_target
from training.evaluate.scenes.coal_model import CoalModel

MARGIN_M = 0.01


def test_scenes_are_seeded_and_clear_the_target_by_coal_distances(
    panda_pose_model: ServedModel, panda_coal: CoalModel
) -> None:
    first = scene_target(panda_pose_model, panda_coal, 3, 0, 6, MARGIN_M)
    again = scene_target(panda_pose_model, panda_coal, 3, 0, 6, MARGIN_M)
    other = scene_target(panda_pose_model, panda_coal, 3, 1, 6, MARGIN_M)
    np.testing.assert_array_equal(first.q_target_rad, again.q_target_rad)
    assert [o.position_m.tolist() for o in first.obstacles] == [
        o.position_m.tolist() for o in again.obstacles
    ]
    assert not np.array_equal(first.q_target_rad, other.q_target_rad)
    for scene in (first, other):
        assert 1 <= scene.boxes_asked <= 6 and 1 <= len(scene.obstacles) <= scene.boxes_asked
        q = scene.q_target_rad[None]
        assert panda_coal.self_clearance_m(q)[0] >= MARGIN_M
        for box in scene.obstacles:
            assert panda_coal.obstacle_clearance_m(q, [box])[0] >= MARGIN_M
            assert all(0.05 <= side <= 0.4 for side in box.dimensions_m)
            assert np.linalg.norm(box.position_m) <= panda_pose_model.manifest.reach_m
            assert box.position_m[2] > 0
            np.testing.assert_allclose(box.rotation @ box.rotation.T, np.eye(3), atol=1e-9)


def test_an_exact_count_and_the_post_body(
    panda_pose_model: ServedModel, panda_coal: CoalModel
) -> None:
    scene = scene_target(panda_pose_model, panda_coal, 5, 2, 3, 0.0, exact_count=10)
    assert scene.boxes_asked == 10 and len(scene.obstacles) == 10
    loose = scene_target(panda_pose_model, panda_coal, 5, 2, 3, 0.0)
    np.testing.assert_array_equal(scene.q_target_rad, loose.q_target_rad)
    body = request_body(panda_pose_model, scene, 0.0)
    assert body["robot"] == "panda" and body["task"] == "pose" and body["seed"] == 2
    assert body["num_samples"] == panda_pose_model.manifest.defaults.num_samples
    assert body["collision"] == {"self": True, "margin_m": 0.0}
    obstacles = body["obstacles"]
    assert isinstance(obstacles, list) and len(obstacles) == 10
    for index, (sent, box) in enumerate(zip(obstacles, scene.obstacles, strict=True)):
        wxyz = tuple(sent["orientation"][k] for k in "wxyz")
        again = Obstacle.of(index, sent["shape"], sent["dimensions"], sent["position"], wxyz)
        np.testing.assert_array_equal(again.rotation, box.rotation)  # a replay is exact
        np.testing.assert_array_equal(again.position_m, box.position_m)
    fk = panda_pose_model.kinematics(scene.q_target_rad[None])
    target = body["target"]
    assert isinstance(target, dict)
    np.testing.assert_allclose(target["position"], fk.position_m[0])
