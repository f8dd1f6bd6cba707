"""check on the Panda as it ships (collision.json's spheres and hulls), against coal on the
example-robot-data meshes: at random configurations, each in a box placed against one of
its links, the check's clearance is never above coal's (self and obstacles), so whatever
it calls free is free; it is never below the spheres' alone; and it refuses fewer of the
configurations coal finds free than the spheres alone do. Its verdicts (`judged`, which
`free` asks) are its clearance against the margin; with nothing to check,
every configuration is free at an infinite clearance. With obstacles, the robot's own
clearance is the one it has without them, to the bit: an obstacle out of reach changes no
clearance, where the hulls decide too (the UR5, whose spheres overlap often)."""

from __future__ import annotations

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.collision.frames import chain_frames
from service.pipeline.collision.robot import RobotSpheres
from service.pipeline.collision.scene import Obstacle, Scene
from training.evaluate.scenes.coal_model import CoalModel

CONFIGURATIONS = 48


@pytest.fixture(scope="module")
def panda() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "panda-pose", threads=1)


def _box_against_a_link(model: ServedModel, q: np.ndarray, rng: np.random.Generator) -> Obstacle:
    """A box 8 cm on a side, its centre 10 to 20 cm from the origin of a random link's
    frame: near the link, in it about half the time."""
    assert model.robot_spheres is not None
    frames = chain_frames(model.robot_spheres.chain, q[None])[0]  # (n + 1, 4, 4)
    link = int(rng.integers(2, len(frames)))
    direction = rng.normal(size=3)
    centre = frames[link, :3, 3] + rng.uniform(0.1, 0.2) * direction / np.linalg.norm(direction)
    return Obstacle.of(0, "box", [0.08, 0.08, 0.08], centre.tolist(), None)


def test_the_check_is_between_the_spheres_and_coal(panda: ServedModel) -> None:
    rng = np.random.default_rng(21)
    limits = panda.limits
    coal = CoalModel.of(panda)
    robot = panda.robot_spheres
    assert robot is not None
    spheres_only = RobotSpheres(  # each sphere its own hull: its centre grown by its radius
        **{**robot.__dict__, "hull_local_m": robot.centre_local_m[:, :, None, :],
           "hull_pad_m": robot.radius_m,
           "hull_count": np.ones(robot.radius_m.shape, dtype=np.int64)},
    )  # fmt: skip
    checked = spheres_lost = check_lost = 0
    for _ in range(CONFIGURATIONS):
        q = rng.uniform(limits.lower_rad, limits.upper_rad)
        scene = Scene((_box_against_a_link(panda, q, rng),))
        check = CollisionCheck(robot, scene, True, 0.0).clearance_m(q[None])[0]
        spheres = CollisionCheck(spheres_only, scene, True, 0.0).clearance_m(q[None])[0]
        coal_m = coal.clearance_m(q[None], scene.obstacles)[0]
        coal_free = bool(coal.free(q[None], scene.obstacles, 0.0)[0])
        assert spheres <= check + 1e-12
        if coal_free:
            assert check <= coal_m + 1e-9
        else:
            assert check < 0.0
        checked += 1
        spheres_lost += coal_free and spheres < 0
        check_lost += coal_free and check < 0
    assert checked == CONFIGURATIONS and spheres_lost >= 3 and spheres_lost > check_lost


def test_the_verdicts_are_the_clearance_against_the_margin(panda: ServedModel) -> None:
    rng = np.random.default_rng(5)
    limits = panda.limits
    q = rng.uniform(limits.lower_rad, limits.upper_rad, size=(40, limits.count))
    robot = panda.robot_spheres
    assert robot is not None
    obstacle = _box_against_a_link(panda, q[0], rng)
    check = CollisionCheck(robot, Scene((obstacle,)), True, 0.01)
    clearance, free = check.judged(q)
    np.testing.assert_array_equal(clearance, check.clearance_m(q))
    np.testing.assert_array_equal(free, clearance >= 0.01)
    np.testing.assert_array_equal(check.free(q), free)
    assert 0 < free.sum() < len(q)  # the box and the arm take some
    nothing = CollisionCheck(None, Scene(()), False, 0.01)
    assert not nothing.active
    clearance, free = nothing.judged(q)
    assert np.isinf(clearance).all() and free.all()


@pytest.mark.parametrize("model_id", ["panda-pose", "ur5-axis"])
def test_an_obstacle_out_of_reach_changes_no_clearance(model_id: str) -> None:
    model = load_model(REPO_MODELS_DIR / model_id, threads=1)
    robot = model.robot_spheres
    assert robot is not None
    q = np.random.default_rng(5).uniform(
        model.limits.lower_rad, model.limits.upper_rad, (400, len(model.limits.lower_rad))
    )
    far = Scene((Obstacle.of(0, "box", [0.1, 0.1, 0.1], [50.0, 0.0, 0.0], None),))
    for margin_m in (0.0, 0.02):
        alone = CollisionCheck(robot, Scene(), True, margin_m).clearance_m(q)
        beside = CollisionCheck(robot, far, True, margin_m).clearance_m(q)
        assert np.array_equal(beside, alone)
        # Some of these configurations are decided by the hulls (spheres within the margin).
        assert (robot.self_clearance_at_m(q) < margin_m).any()
