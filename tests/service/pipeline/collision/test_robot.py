"""robot and check: spheres placed by the chain frames where the planar 3R's closed-form
FK puts them, self-clearance the least gap over the pairs not disabled, obstacles checked
against the moving bodies only, and the margin deciding what is free."""

import numpy as np
import pytest

from service.manifest import ChainSpec, CollisionBody, CollisionSpec, DisabledPair
from service.models.registry import ServedModel
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.collision.frames import chain_frames
from service.pipeline.collision.robot import RobotSpheres
from service.pipeline.collision.scene import Obstacle, Scene
from tests.support.app import PLANAR3R_DIR

RADIUS_M = 0.1


def planar_spec(disabled: list[DisabledPair] | None = None) -> CollisionSpec:
    """A post at the base and one sphere at the middle of each unit link of the planar 3R."""
    return CollisionSpec(
        bodies=[
            CollisionBody(link="base", frame=0, centres_m=[[0.0, 0.0, 0.0]], radii_m=[RADIUS_M]),
            *(
                CollisionBody(
                    link=f"link{k}", frame=k, centres_m=[[0.5, 0.0, 0.0]], radii_m=[RADIUS_M]
                )
                for k in (1, 2, 3)
            ),
        ],
        disabled_pairs=disabled or [],
    )


def link_middles(q: np.ndarray) -> np.ndarray:  # (B, 3) -> (B, 3, 2): closed-form planar FK
    theta = np.cumsum(q, axis=1)
    joint = np.concatenate(
        [np.zeros((len(q), 1, 2)), np.cumsum(np.stack([np.cos(theta), np.sin(theta)], 2), 1)],
        axis=1,
    )
    return joint[:, :3] + 0.5 * np.stack([np.cos(theta), np.sin(theta)], axis=2)


def test_frames_end_where_the_chain_kernel_puts_the_end_effector(planar3r: ServedModel) -> None:
    chain = planar_chain()
    q = np.random.default_rng(0).uniform(-3, 3, (50, 3))
    tip = chain_frames(chain, q)[:, -1] @ np.asarray(chain.tip)
    np.testing.assert_allclose(tip[:, :3, 3], planar3r.kinematics(q).position_m, atol=1e-14)


def planar_chain() -> ChainSpec:
    return ChainSpec.model_validate_json((PLANAR3R_DIR / "chain.json").read_bytes())


def test_spheres_sit_where_the_closed_form_puts_the_links(planar3r: ServedModel) -> None:
    robot = RobotSpheres.of(planar_chain(), planar_spec())
    q = np.random.default_rng(1).uniform(-3, 3, (40, 3))
    centres = robot.place(q).first_centres_m  # (B, 4, 3)
    np.testing.assert_allclose(centres[:, 1:, :2], link_middles(q), atol=1e-14)
    np.testing.assert_allclose(centres[:, 0], 0.0, atol=0)


def test_self_clearance_is_the_least_gap_over_pairs_not_disabled(planar3r: ServedModel) -> None:
    adjacent = [
        DisabledPair(links=("base", "link1"), reason="adjacent"),
        DisabledPair(links=("link1", "link2"), reason="adjacent"),
        DisabledPair(links=("link2", "link3"), reason="adjacent"),
    ]
    robot = RobotSpheres.of(planar_chain(), planar_spec(adjacent))
    q = np.random.default_rng(2).uniform(-3, 3, (200, 3))
    middles = np.concatenate([np.zeros((len(q), 1, 2)), link_middles(q)], axis=1)  # (B, 4, 2)
    checked = [(0, 2), (0, 3), (1, 3)]
    brute = np.min(
        [np.linalg.norm(middles[:, a] - middles[:, b], axis=1) for a, b in checked], axis=0
    )
    got = robot.self_clearance_m(robot.place(q))
    np.testing.assert_allclose(got, brute - 2 * RADIUS_M, atol=1e-12)


def test_obstacles_are_checked_against_moving_bodies_and_the_margin_decides(
    planar3r: ServedModel,
) -> None:
    robot = RobotSpheres.of(planar_chain(), planar_spec())
    # A sphere on the base body's own centre: the base stands there; only link 1 (middle
    # at 0.5 m along x at q = 0) is near it.
    scene = Scene((Obstacle.of(0, "sphere", [0.2], [0.0, 0.0, 0.0], None),))
    q = np.zeros((1, 3))
    check = CollisionCheck(robot=robot, scene=scene, check_self=False, margin_m=0.0)
    assert check.clearance_m(q)[0] == pytest.approx(0.5 - 0.2 - RADIUS_M)
    assert check.free(q)[0]
    tight = CollisionCheck(robot=robot, scene=scene, check_self=False, margin_m=0.25)
    assert not tight.free(q)[0]
    assert not CollisionCheck.none().active
    assert np.isinf(CollisionCheck.none().clearance_m(q)).all()


def test_the_two_pass_clearance_is_the_brute_force_minimum() -> None:
    """Bodies of several spheres each, some pairs disabled, a scene of every shape: the
    pruned least distance equals the minimum over every sphere pair and every obstacle."""
    rng = np.random.default_rng(7)
    bodies = []
    for k in range(4):
        count = int(rng.integers(1, 6))
        bodies.append(
            CollisionBody(
                link=f"b{k}",
                frame=k,
                centres_m=(rng.uniform(-0.2, 1.2, (count, 3)) * [1, 0.3, 0.3]).tolist(),
                radii_m=rng.uniform(0.02, 0.15, count).tolist(),
            )
        )
    spec = CollisionSpec(
        bodies=bodies, disabled_pairs=[DisabledPair(links=("b1", "b2"), reason="adjacent")]
    )
    robot = RobotSpheres.of(planar_chain(), spec)
    scene = Scene(
        (
            Obstacle.of(0, "box", [0.3, 0.2, 0.5], [1.0, 1.0, 0.0], (0.9, 0.1, 0.3, 0.3)),
            Obstacle.of(1, "sphere", [0.2], [-1.0, 0.5, 0.1], None),
            Obstacle.of(2, "cylinder", [0.6, 0.1], [0.5, -1.2, 0.0], (0.7, 0.7, 0.0, 0.14)),
            Obstacle.of(3, "capsule", [0.4, 0.1], [-0.5, -0.8, 0.0], None),
        )
    )
    q = rng.uniform(-3, 3, (300, 3))
    check = CollisionCheck(robot=robot, scene=scene, check_self=True, margin_m=0.0)
    got = check.clearance_m(q)

    frames = chain_frames(planar_chain(), q)  # (B, 4, 4, 4)
    placed = []
    for body in bodies:
        local = np.asarray(body.centres_m)
        f = frames[:, body.frame]
        placed.append((np.einsum("bij,sj->bsi", f[:, :3, :3], local) + f[:, None, :3, 3], body))
    brute = np.full(len(q), np.inf)
    for i, (ci, bi) in enumerate(placed):
        for j, (cj, bj) in enumerate(placed):
            if j <= i or {bi.link, bj.link} == {"b1", "b2"}:
                continue
            gap = np.linalg.norm(ci[:, :, None] - cj[:, None], axis=3)
            gap -= np.add.outer(bi.radii_m, bj.radii_m)
            brute = np.minimum(brute, gap.min(axis=(1, 2)))
        if bi.frame > 0:
            for obstacle in scene.obstacles:
                gap = obstacle.signed_distance_m(ci) - np.asarray(bi.radii_m)
                brute = np.minimum(brute, gap.min(axis=1))
    np.testing.assert_allclose(got, brute, atol=1e-12)
