"""training.evaluate.references.collision: coal on the URDF's geometry, against closed forms.

Obstacles in MoveIt's dimensions are the shapes they say: a sphere [r] and a box [x, y,
z] (full sizes) at known distances from the arm's l1 sphere, and a capsule [height, r]
whose height is the distance between its cap centres (coal's lz): the distance from a
point beyond a cap is |point - cap centre| - r. The arm's own l1 sphere at q is where
chain_frames puts it; a penetrating primitive pair reports minus the depth; the least
self distance over the pairs not disabled is the least of the pair distances.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from service.manifest import ChainSpec
from service.pipeline.collision.frames import chain_frames
from training.collision.geometry import Body, Shape, read_bodies
from training.evaluate.references.collision import CoalRobot, Obstacle

BALL_M = 0.04  # the l1 sphere's radius (tests/support/collision_arm.py)


def _only_the_ball(arm_urdf: Path, arm_chain: ChainSpec) -> CoalRobot:
    l1 = next(b for b in read_bodies(arm_urdf, arm_chain) if b.link == "l1")
    ball = next(s for s in l1.shapes if s.kind == "sphere")
    return CoalRobot(arm_chain, [Body(link="l1", frame=1, shapes=(ball,))])


@pytest.mark.parametrize(
    ("shape", "dimensions", "offset", "expected"),
    [
        ("sphere", (0.1,), (0.3, 0.0, 0.0), 0.3 - 0.1 - BALL_M),
        ("box", (0.2, 0.4, 0.6), (0.0, 0.5, 0.0), 0.5 - 0.2 - BALL_M),  # y half-size 0.2
        ("capsule", (0.4, 0.05), (0.0, 0.0, 0.5), 0.5 - 0.2 - 0.05 - BALL_M),  # cap at 0.2
        ("cylinder", (0.4, 0.05), (0.0, 0.0, 0.5), 0.5 - 0.2 - BALL_M),  # flat end at 0.2
        ("sphere", (0.1,), (0.1, 0.0, 0.0), 0.1 - 0.1 - BALL_M),  # penetrating: -depth
    ],
)
def test_obstacle_distances_follow_moveits_dimensions(
    arm_urdf: Path, arm_chain: ChainSpec, shape: str, dimensions: tuple, offset: tuple,
    expected: float,
) -> None:  # fmt: skip
    """Distance from the l1 sphere to an obstacle placed `offset` from its centre (turned
    by a rotation about the offset, which leaves these distances alone)."""
    robot = _only_the_ball(arm_urdf, arm_chain)
    q = np.array([[0.7, 0.2, -0.3, 0.4]])
    ball_pose = chain_frames(arm_chain, q)[0, 1] @ robot.bodies[0].shapes[0].pose
    axis = np.asarray(offset) / np.linalg.norm(offset)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    turn = np.eye(3) + np.sin(0.6) * cross + (1 - np.cos(0.6)) * cross @ cross
    obstacle = Obstacle(shape, dimensions, ball_pose[:3, 3] + np.asarray(offset), turn)
    assert robot.obstacle_distance_m(q, [obstacle])[0] == pytest.approx(expected, abs=1e-6)


def test_the_base_does_not_meet_obstacles_and_self_distance_is_the_least_pair(
    arm_urdf: Path, arm_chain: ChainSpec
) -> None:
    """A box around the base touches only frame-0 bodies: no moving body is within it
    (distance > 0); the self distance over a set of pairs is the least pair distance, and
    a body sphere placed inside another reports a negative distance (penetration)."""
    bodies = read_bodies(arm_urdf, arm_chain)
    robot = CoalRobot(arm_chain, bodies)
    q = np.array([[0.0, 0.0, 0.0, 0.0], [1.4, 0.5, -0.5, 1.0]])
    around_base = Obstacle("box", (0.12, 0.12, 0.08), np.array([0, 0, 0.05]), np.eye(3))
    assert np.all(robot.obstacle_distance_m(q, [around_base]) > 0)
    pairs = robot.checked_pairs([])
    least = robot.pair_distances_m(q, pairs).min(axis=1)
    np.testing.assert_array_equal(robot.self_distance_m(q, []), least)
    pose = np.eye(4)
    inside = Body("probe", 0, (Shape("sphere", pose, (0.03,)),))
    other = Body("other", 0, (Shape("sphere", pose @ np.diag([1, 1, 1, 1.0]), (0.05,)),))
    pair = CoalRobot(arm_chain, [inside, other]).self_distance_m(q[:1], [])
    assert pair[0] == pytest.approx(-0.08, abs=1e-9)  # concentric: depth r_a + r_b
