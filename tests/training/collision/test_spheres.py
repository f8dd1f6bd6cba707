"""training.collision.spheres: every point of a body's geometry lies inside its spheres.

Conservativeness, checked against points the test samples itself: dense points on the
surface of every primitive of the small arm (box faces, cylinder side and caps, capsule
side and caps, sphere) and of its mesh (the STL's box, scaled and placed), and on every
triangle of the Panda's collision meshes (read from the STL files with numpy), all lie in
the union of the body's spheres, for several budgets, and in the union of the hulls
inside them (grown by their pads), each hull inside its sphere; a sphere alone is covered
by itself. And on the Panda at random configurations, for every body pair, the spheres'
distance (RobotSpheres, what the service computes) is at most coal's distance on the
meshes where coal finds them apart, and negative where coal finds them touching.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import ConvexHull, QhullError

from service.manifest import (
    REPO_MODELS_DIR,
    ChainSpec,
    CollisionBody,
    CollisionSpec,
    JointSpec,
    Manifest,
)
from service.pipeline.collision.robot import RobotSpheres
from service.pipeline.joint_space import JointLimits
from tests.support.collision_arm import MESH_BOX_M, MESH_SCALE
from training.collision.geometry import Body, Shape, read_bodies
from training.collision.spheres import RADIUS_MARGIN_M, cover_body
from training.evaluate.references.collision import CoalRobot

PANDA = REPO_MODELS_DIR / "panda-pose"
RNG = np.random.default_rng(11)


def _unit(count: int) -> np.ndarray:
    v = RNG.normal(size=(count, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _box_surface(size: np.ndarray, count: int = 4000) -> np.ndarray:
    """Points on the faces of the box of full sizes `size` centred at 0, corners included."""
    points = RNG.uniform(-0.5, 0.5, size=(count, 3))
    face = RNG.integers(0, 3, count)
    points[np.arange(count), face] = RNG.choice([-0.5, 0.5], count)
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    return np.vstack([points, corners]) * size


def _round_surface(kind: str, length: float, radius: float, count: int = 4000) -> np.ndarray:
    """Points on a cylinder (side, rims, caps) or a capsule (side, hemispheres) along z."""
    angle = RNG.uniform(0, 2 * np.pi, count)
    ring = radius * np.c_[np.cos(angle), np.sin(angle)]
    side = np.c_[ring, RNG.uniform(-length / 2, length / 2, count)]
    if kind == "cylinder":
        disc = np.sqrt(RNG.uniform(0, 1, count))[:, None] * ring
        caps = np.c_[disc, RNG.choice([-length / 2, length / 2], count)]
        rims = np.c_[ring, RNG.choice([-length / 2, length / 2], count)]
        return np.vstack([side, caps, rims])
    direction = _unit(count) * radius
    return np.vstack([side, direction + np.c_[0, 0, length / 2] * np.sign(direction[:, 2:])])


def _placed(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    return points @ pose[:3, :3].T + pose[:3, 3]


def surface_points(shape: Shape) -> np.ndarray:
    """Points on the shape's surface in its body frame, sampled from its definition."""
    if shape.kind == "box":
        local = _box_surface(np.asarray(shape.dimensions_m))
    elif shape.kind == "sphere":
        local = _unit(2000) * shape.dimensions_m[0]
    elif shape.kind in ("cylinder", "capsule"):
        local = _round_surface(shape.kind, shape.dimensions_m[0], shape.dimensions_m[1])
    else:  # the arm's mesh: the STL's box, scaled
        low, high = (np.asarray(c) * MESH_SCALE for c in MESH_BOX_M)
        local = _box_surface(high - low) + (low + high) / 2
    return _placed(local, shape.pose)


def stl_surface_points(path: Path, pose: np.ndarray, per_triangle: int = 6) -> np.ndarray:
    """Points on every triangle of a binary STL (read with numpy), corners included."""
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    data = path.read_bytes()
    count = int(np.frombuffer(data, "<u4", 1, 80)[0])
    triangles = np.frombuffer(data, record, count, 84)["corners"].astype(np.float64)
    weights = RNG.dirichlet(np.ones(3), size=(count, per_triangle))  # (T, k, 3)
    inside = np.einsum("tkc,tcx->tkx", weights, triangles).reshape(-1, 3)
    return _placed(np.vstack([inside, triangles.reshape(-1, 3)]), pose)


def uncovered_m(body: Body, points: np.ndarray, budget: int) -> float:
    """How far the farthest point lies outside every sphere of the body's cover (<= 0:
    all inside)."""
    cover = cover_body(body, budget)
    centres, radii = np.asarray(cover.centres_m), np.asarray(cover.radii_m)
    assert len(radii) <= budget
    gaps = np.linalg.norm(points[:, None] - centres[None], axis=2) - radii[None]
    return float(gaps.min(axis=1).max())


def outside_hulls_m(cover: CollisionBody, points: np.ndarray) -> float:
    """How far the farthest point lies outside every hull of the cover (<= 0: all inside),
    by qhull's facet planes (joggled for a flat hull) less the hull's pad: a point is
    inside a hull grown by r when no facet plane has it more than r above."""
    above = np.full(len(points), np.inf)
    for hull, pad in zip(cover.hulls_m, cover.hull_pads_m, strict=True):
        vertices = np.asarray(hull)
        if len(vertices) < 4:  # a point, a segment, a triangle: made a sliver 1e-10 thick
            vertices = np.vstack([vertices + 1e-10 * step for step in np.eye(3)] + [vertices])
        try:
            planes = ConvexHull(vertices).equations
        except QhullError:
            planes = ConvexHull(vertices, qhull_options="QJ").equations
        height = (points @ planes[:, :3].T + planes[:, 3]).max(axis=1)
        above = np.minimum(above, height - pad)
    return float(above.max())


def test_each_hull_lies_in_its_sphere_and_the_hulls_cover_the_arm(
    arm_urdf: Path, arm_chain: ChainSpec
) -> None:
    """Every body of the small arm (box, sphere, cylinder, capsule, mesh): its hulls are
    within their spheres (the schema checks it too) and hold every surface sample."""
    for body in read_bodies(arm_urdf, arm_chain):
        cover = cover_body(body, 4)
        for centre, radius, hull, pad in zip(
            cover.centres_m, cover.radii_m, cover.hulls_m, cover.hull_pads_m, strict=True
        ):
            reach = np.linalg.norm(np.asarray(hull) - centre, axis=1).max() + pad
            assert reach <= radius, body.link
        points = np.vstack([surface_points(shape) for shape in body.shapes])
        assert outside_hulls_m(cover, points) <= 1e-9, body.link


@pytest.mark.parametrize("budget", [1, 3, 8])
def test_every_surface_point_of_the_arm_lies_in_a_sphere(
    arm_urdf: Path, arm_chain: ChainSpec, budget: int
) -> None:
    """Dense samples of each primitive and the mesh are inside the body's spheres."""
    for body in read_bodies(arm_urdf, arm_chain):
        points = np.vstack([surface_points(shape) for shape in body.shapes])
        assert uncovered_m(body, points, budget) <= 0, body.link


def test_a_sphere_alone_is_covered_by_itself() -> None:
    """One sphere shape gives one sphere: its placed centre, its radius."""
    pose = np.eye(4)
    pose[:3, 3] = [0.1, -0.2, 0.3]
    body = Body(link="ball", frame=2, shapes=(Shape("sphere", pose, (0.07,)),))
    cover = cover_body(body, 8)
    np.testing.assert_allclose(cover.centres_m, [[0.1, -0.2, 0.3]], atol=1e-15)
    np.testing.assert_allclose(cover.radii_m, [0.07], atol=RADIUS_MARGIN_M)
    assert cover.hulls_m == [[[0.1, -0.2, 0.3]]]  # its hull is its centre, padded
    assert cover.hull_pads_m[0] == pytest.approx(0.07, abs=1e-6)
    assert cover.frame == 2


@pytest.fixture(scope="module")
def panda() -> tuple[ChainSpec, JointSpec, list[Body], CollisionSpec]:
    chain = ChainSpec.model_validate_json((PANDA / "chain.json").read_bytes())
    joints = Manifest.model_validate_json((PANDA / "manifest.json").read_bytes()).joints
    bodies = read_bodies(REPO_MODELS_DIR / "robots" / "panda.urdf", chain)
    spec = CollisionSpec(bodies=[cover_body(body) for body in bodies], disabled_pairs=[])
    return chain, joints, bodies, spec


def test_every_point_of_the_panda_meshes_lies_in_a_sphere(
    panda: tuple[ChainSpec, JointSpec, list[Body], CollisionSpec],
) -> None:
    """Samples on every triangle of each Panda STL, placed in the body's frame, are inside
    the spheres of the default budget and inside their hulls."""
    _, _, bodies, spec = panda
    for body, cover in zip(bodies, spec.bodies, strict=True):
        points = np.vstack([
            stl_surface_points(s.mesh_path, s.pose) if s.mesh_path is not None
            else surface_points(s)
            for s in body.shapes
        ])  # fmt: skip
        gaps = np.linalg.norm(points[:, None] - np.asarray(cover.centres_m)[None], axis=2)
        assert (gaps - np.asarray(cover.radii_m)).min(axis=1).max() <= 0, body.link
        assert outside_hulls_m(cover, points) <= 1e-9, body.link


def test_the_panda_spheres_never_report_more_clearance_than_coal(
    panda: tuple[ChainSpec, JointSpec, list[Body], CollisionSpec],
) -> None:
    """Per body pair, at random configurations: sphere distance <= coal's distance where
    coal says apart; sphere distance < 0 where coal says touching."""
    chain, joints, bodies, spec = panda
    limits = JointLimits.of(joints)
    q = np.random.default_rng(5).uniform(limits.lower_rad, limits.upper_rad, size=(24, 7))
    coal_robot = CoalRobot(chain, bodies)
    pairs = coal_robot.checked_pairs([])
    coal_m = coal_robot.pair_distances_m(q, pairs)  # (B, P)
    touching = coal_robot.pair_collisions(q, pairs)
    for p, (a, b) in enumerate(pairs):
        both = CollisionSpec(bodies=[spec.bodies[a], spec.bodies[b]], disabled_pairs=[])
        spheres = RobotSpheres.of(chain, both)
        sphere_m = spheres.self_clearance_m(spheres.place(q))
        apart = ~touching[:, p]
        assert np.all(sphere_m[apart] <= coal_m[apart, p] + 1e-9), (bodies[a].link, bodies[b].link)
        assert np.all(sphere_m[~apart] < 0), (bodies[a].link, bodies[b].link)
    assert touching.any() and (~touching).any()  # both cases were checked
