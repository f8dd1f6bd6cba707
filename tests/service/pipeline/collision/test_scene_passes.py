"""scene.py's obstacle passes, compiled (native.obstacle_clearance_m and
native.refined_obstacle_clearance_m), against the numpy passes they replace, written out
here step for step, on every shape, turned, from clear to penetrating, at margins that
certify some configurations and give up on others: the spheres' pass agrees to 1e-12;
the refined pass gives every configuration the same verdict against the margin and the
same bound to 1e-12 but on a few rows in a thousand, where GJK's stopping tests flip on
the last bit of a support point (numpy's matrix product rounds otherwise than the
compiled sums) and either bound is valid. Every refined figure is at least the spheres'
distance (or the margin, where a body clear on its bounds counts with them), and one
certified free is at most a witness of the true distance: the obstacles' signed
distance at the hulls' vertices, less their pads."""

from functools import partial

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from service.pipeline import native
from service.pipeline.arrays import FloatArray, IntArray
from service.pipeline.collision.convex import (
    hull_support,
    separation_deepest_first_m,
    separation_m,
)
from service.pipeline.collision.robot import PlacedBodies, RobotSpheres
from service.pipeline.collision.scene import Obstacle, Scene
from tests.service.pipeline.test_native import COLLISION_MODELS, robot_spheres


def numpy_clearance_m(
    scene: Scene, placed: PlacedBodies, robot: RobotSpheres, within: FloatArray
) -> FloatArray:
    """The spheres' pass as numpy computed it before it was compiled."""
    clearance = within.copy()
    moving = np.flatnonzero(robot.moving)
    if not scene.obstacles or not len(moving):
        return clearance
    bounds = placed.bound_centres_m[:, moving]  # (B, M, 3)
    body_radius = robot.bound_radius_m[moving]
    centres = np.stack([o.position_m for o in scene.obstacles])
    reach = np.array([o.reach_m for o in scene.obstacles])
    apart = bounds[:, :, None, :] - centres
    coarse = np.sqrt(np.einsum("bmki,bmki->bmk", apart, apart))
    coarse -= body_radius[:, None] + reach
    nearest = coarse.reshape(len(coarse), -1).argmin(axis=1)
    body_of, obstacle_of = np.divmod(nearest, len(scene.obstacles))
    for k in np.unique(obstacle_of):
        rows = np.flatnonzero(obstacle_of == k)
        body = moving[body_of[rows]]
        first = placed.first_centres_m[rows, body]
        upper = scene.obstacles[k].signed_distance_m(first) - robot.radius_m[body, 0]
        np.minimum.at(clearance, rows, upper)
    for k, obstacle in enumerate(scene.obstacles):
        rows, bodies = np.nonzero(coarse[:, :, k] < clearance[:, None])
        if not len(rows):
            continue
        lower = obstacle.signed_distance_m(bounds[rows, bodies]) - body_radius[bodies]
        near = lower < clearance[rows]
        rows, body = rows[near], moving[bodies[near]]
        if not len(rows):
            continue
        gap = obstacle.signed_distance_m(placed.spheres(rows, body)) - robot.radius_m[body]
        np.minimum.at(clearance, rows, gap.min(axis=1))
    return clearance


def numpy_refined_clearance_m(
    scene: Scene, placed: PlacedBodies, robot: RobotSpheres, rows: IntArray, margin_m: float
) -> FloatArray:
    """The refined pass as numpy computed it before it was compiled."""
    clearance = np.full(len(rows), np.inf)
    moving = np.flatnonzero(robot.moving)
    if not scene.obstacles or not len(moving):
        return clearance
    bounds = placed.bound_centres_m[rows][:, moving]
    body_radius = robot.bound_radius_m[moving]
    for obstacle in scene.obstacles:
        lower = obstacle.signed_distance_m(bounds) - body_radius
        np.minimum.at(clearance, np.arange(len(rows)), np.where(
            lower >= margin_m, lower, np.inf).min(axis=1))  # fmt: skip
        near, bodies = np.nonzero((lower < margin_m) & (clearance >= margin_m)[:, None])
        if not len(near):
            continue
        row, body = rows[near], moving[bodies]
        gap = obstacle.signed_distance_m(placed.spheres(row, body)) - robot.radius_m[body]
        own = np.arange(gap.shape[1])[None] < robot.own_spheres[body][:, None]
        gap = np.where(own, gap, np.inf)
        n, s = np.nonzero(gap < margin_m)
        if len(n):
            hull = hull_support(
                placed.hull_local_m, placed.hull_count, body[n], s,
                placed.rotation[row[n], body[n]], placed.origin_m[row[n], body[n]],
            )  # fmt: skip
            x0 = placed.hull_points(row[n], body[n], s) - obstacle.position_m
            pad = robot.hull_pad_m[body[n], s] + obstacle.pad_m
            gap[n, s] = separation_deepest_first_m(
                partial(separation_m, hull, obstacle.support_m, x0, pad, margin_m),
                margin_m,
                near[n],
                gap[n, s],
            )
        np.minimum.at(clearance, near, gap.min(axis=1))
    return clearance


def random_scene(rng: np.random.Generator, count: int, reach_m: float) -> Scene:
    """Obstacles of every shape, turned at random, centred within the robot's reach."""
    obstacles = []
    for index in range(count):
        shape = ("box", "sphere", "cylinder", "capsule")[index % 4]
        dimensions = {"box": 3, "sphere": 1, "cylinder": 2, "capsule": 2}[shape]
        sides = rng.uniform(0.05, 0.4, dimensions).tolist()
        w, x, y, z = Rotation.random(random_state=rng).as_quat(scalar_first=True)
        centre = rng.uniform(-reach_m, reach_m, 3) * [1.0, 1.0, 0.5] + [0.0, 0.0, 0.5 * reach_m]
        obstacles.append(Obstacle.of(index, shape, sides, centre.tolist(), (w, x, y, z)))
    return Scene(tuple(obstacles))


def witness_m(
    scene: Scene, placed: PlacedBodies, robot: RobotSpheres, rows: IntArray
) -> FloatArray:
    """(R,) at least the true distance of the moving bodies' hulls (grown by their pads)
    to the obstacles where they are apart: the least signed distance of any hull vertex
    to any obstacle, less the hull's pad."""
    moving = np.flatnonzero(robot.moving)
    least = np.full(len(rows), np.inf)
    for body in moving:
        for sphere in range(int(robot.own_spheres[body])):
            count = int(robot.hull_count[body, sphere])
            local = robot.hull_local_m[body, sphere, :count]  # (V, 3)
            vertices = np.einsum("rij,vj->rvi", placed.rotation[rows, body], local)
            vertices += placed.origin_m[rows, body][:, None]
            for obstacle in scene.obstacles:
                gap = obstacle.signed_distance_m(vertices).min(axis=1)
                least = np.minimum(least, gap - robot.hull_pad_m[body, sphere])
    return least


@pytest.mark.parametrize("model", COLLISION_MODELS)
def test_the_compiled_passes_take_the_numpy_steps(model: str) -> None:
    robot = robot_spheres(model)
    rng = np.random.default_rng(11)
    q = rng.uniform(-np.pi, np.pi, (600, len(robot.chain.joints)))
    placed = robot.place(q)
    certified = given_up = rows_refined = rows_apart = 0
    for trial in range(8):
        scene = random_scene(rng, 1 + 2 * trial, 0.8)
        within = np.where(rng.random(len(q)) < 0.2, rng.uniform(-0.05, 0.3, len(q)), np.inf)
        expected = numpy_clearance_m(scene, placed, robot, within)
        compiled = scene.clearance_m(placed, robot, within)
        np.testing.assert_allclose(compiled, expected, rtol=0, atol=1e-12)
        spheres = numpy_clearance_m(scene, placed, robot, np.full(len(q), np.inf))
        for margin in (0.0, 0.02):
            rows = np.flatnonzero(expected < margin)
            expected_refined = numpy_refined_clearance_m(scene, placed, robot, rows, margin)
            refined = scene.refined_clearance_m(placed, robot, rows, margin)
            np.testing.assert_array_equal(refined >= margin, expected_refined >= margin)
            rows_refined += len(rows)
            rows_apart += int((np.abs(refined - expected_refined) > 1e-12).sum())
            # never below the spheres' (a body clear on its bounds counts with that bound)
            assert (refined >= np.minimum(spheres[rows], margin) - 1e-12).all()
            # certified free: never above the true distance (a configuration not free by
            # one obstacle is not measured against the next, so only its verdict holds)
            free = refined >= margin
            witness = np.maximum(witness_m(scene, placed, robot, rows[free]), 0.0)
            assert (refined[free] <= witness + 1e-12).all()
            certified += int((refined >= margin).sum())
            given_up += int((refined < margin).sum())
    assert rows_apart <= 0.002 * rows_refined
    assert certified > 0 and given_up > 0  # the hulls certify some, not all


def test_no_obstacle_or_no_moving_body_leaves_the_clearance_as_it_was() -> None:
    robot = robot_spheres("panda-pose")
    q = np.zeros((3, len(robot.chain.joints)))
    placed = robot.place(q)
    within = np.array([0.1, np.inf, -0.2])
    np.testing.assert_array_equal(Scene().clearance_m(placed, robot, within), within)
    refined = Scene().refined_clearance_m(placed, robot, np.arange(3), 0.0)
    assert np.isposinf(refined).all()


def test_a_frame_not_finite_gives_nan() -> None:
    robot = robot_spheres("panda-pose")
    q = np.zeros((2, len(robot.chain.joints)))
    q[1, 0] = np.nan
    placed = robot.place(q)
    scene = random_scene(np.random.default_rng(3), 4, 0.8)
    expected = numpy_clearance_m(scene, placed, robot, np.full(2, np.inf))
    compiled = scene.clearance_m(placed, robot, np.full(2, np.inf))
    assert np.isfinite(compiled[0]) and np.isnan(compiled[1]) and np.isnan(expected[1])


def test_bad_obstacle_arrays_are_refused() -> None:
    robot = robot_spheres("panda-pose")
    placed = robot.place(np.zeros((1, len(robot.chain.joints))))
    scene = random_scene(np.random.default_rng(3), 2, 0.8)
    bad = native.ObstacleSet(**{**vars(scene.compiled), "shape": np.array([0, 7])})
    with pytest.raises(ValueError, match=r"obstacle shapes must index \['box', 'sphere'"):
        native.obstacle_clearance_m(
            robot.moving_bodies, bad, placed.rotation, placed.origin_m, np.full(1, np.inf)
        )
