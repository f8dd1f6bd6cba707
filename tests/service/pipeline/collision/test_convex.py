"""convex: GJK's separation is a lower bound of the distance between convex sets, and it
certifies every pair clear of the margin by twice its resolution; checked against coal
(an independent GJK on its own shapes) on random polytopes, polytopes with parallel faces
a hair apart (where Frank-Wolfe steps zigzag), and each obstacle primitive, placed and
turned; sets that meet are never certified."""

from __future__ import annotations

from functools import partial

import coal
import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial import ConvexHull

from service.pipeline.collision.convex import (
    RESOLUTION_M,
    Support,
    hull_support,
    nearest_in_hull,
    separation_deepest_first_m,
    separation_m,
)
from service.pipeline.collision.scene import Obstacle
from service.pipeline.rotations import quaternion_to_matrix
from training.evaluate.references.collision import coal_geometry

RNG = np.random.default_rng(3)


def _coal_convex(vertices: np.ndarray) -> coal.BVHModelOBBRSS:
    """The points' convex hull (qhull's triangles) as a coal mesh: for sets apart, the
    distance between two hulls' surfaces is the distance between the hulls."""
    hull = ConvexHull(vertices)
    model = coal.BVHModelOBBRSS()
    model.beginModel(len(hull.simplices), len(vertices))
    model.addVertices(np.asarray(vertices, dtype=np.float64))
    model.addTriangles(np.asarray(hull.simplices, dtype=np.int64))
    model.endModel()
    return model


def _coal_distance(a: object, pose_a: np.ndarray, b: object, pose_b: np.ndarray) -> float:
    ta, tb = coal.Transform3s(), coal.Transform3s()
    ta.setRotation(pose_a[:3, :3]), ta.setTranslation(pose_a[:3, 3])
    tb.setRotation(pose_b[:3, :3]), tb.setTranslation(pose_b[:3, 3])
    request, result = coal.DistanceRequest(), coal.DistanceResult()
    return float(coal.distance(a, ta, b, tb, request, result))


def _random_rotation() -> np.ndarray:
    q = RNG.normal(size=4)
    return quaternion_to_matrix(*(q / np.linalg.norm(q)))


def _polytope_pairs(count: int) -> tuple[np.ndarray, np.ndarray]:
    """(count, 24, 3) pairs of point clouds; every other pair has a square face of A over
    a square face of B (both level, overlapping), 0.2 to 2 mm apart."""
    a = RNG.normal(size=(count, 24, 3)) * RNG.uniform(0.02, 0.1, (count, 1, 3))
    b = RNG.normal(size=(count, 24, 3)) * RNG.uniform(0.02, 0.1, (count, 1, 3))
    b += RNG.normal(size=(count, 1, 3)) * 0.2
    flat = np.flatnonzero(np.arange(count) % 2 == 1)
    square = 0.03 * np.array([[1, 1, 0], [1, -1, 0], [-1, 1, 0], [-1, -1, 0]])
    gap = RNG.uniform(2e-4, 2e-3, (len(flat), 1))
    a[flat, :, 2] = np.abs(a[flat, :, 2]) + 1e-3
    a[flat, :4] = square
    b[flat] = RNG.normal(size=(len(flat), 24, 3)) * 0.05
    b[flat, :, 2] = -np.abs(b[flat, :, 2]) - 1e-3
    b[flat, :4] = square + np.array([0.01, 0.02, 0.0])
    b[flat, :, 2] -= gap
    return a, b


def start(support_a: Support, support_b: Support, direction: np.ndarray) -> np.ndarray:
    """A point of A - B at each row: A's farthest against `direction`, B's along it."""
    rows = np.arange(len(direction))
    return support_a(-direction, rows) - support_b(direction, rows)


def _placed(points: np.ndarray, turn: np.ndarray, shift: np.ndarray) -> Support:
    """hull_support of row i's own point cloud (N, V, 3), turned and shifted."""
    count = len(points)
    return hull_support(
        points[:, None],
        np.full((count, 1), points.shape[1]),
        np.arange(count),
        np.zeros(count, dtype=np.int64),
        turn,
        shift,
    )


def _supports(a: np.ndarray, b: np.ndarray) -> tuple[Support, Support, np.ndarray, np.ndarray]:
    count = len(a)
    turn = np.stack([_random_rotation() for _ in range(count)])
    shift = RNG.normal(size=(count, 3))
    return (
        _placed(a, turn, shift),
        _placed(b, turn, shift),
        turn,
        shift,
    )


def test_the_separation_is_coals_distance_from_below_and_certifies_clear_pairs() -> None:
    """Random placed polytopes: bound <= coal's distance always; every pair at least 2
    resolutions clearer than the margin asked is certified, to within 2 resolutions of
    coal's distance when asked at it."""
    a, b = _polytope_pairs(60)
    support_a, support_b, turn, shift = _supports(a, b)
    pose = [
        np.block([[t, s[:, None]], [np.zeros((1, 3)), 1]]) for t, s in zip(turn, shift, strict=True)
    ]
    exact = np.array([
        _coal_distance(_coal_convex(a[i]), pose[i], _coal_convex(b[i]), pose[i])
        for i in range(len(a))
    ])  # fmt: skip
    apart = np.flatnonzero(exact > 3 * RESOLUTION_M)
    assert len(apart) >= 40 and (exact[1::2] < 0.01).sum() > 10  # parallel faces, near
    x0 = start(support_a, support_b, np.ones((len(a), 3)))
    for i in apart:
        margin = exact[i] - 2 * RESOLUTION_M
        one = np.array([i])
        bound = separation_m(support_a, support_b, x0, np.zeros(len(a)), margin, one)[i]
        assert bound <= exact[i] + 1e-9
        assert bound >= margin, (i, exact[i], bound)
    # Asked at an unreachable margin, the bound still never passes the distance.
    loose = separation_m(support_a, support_b, x0, np.zeros(len(a)), 10.0)
    assert (loose <= exact + 1e-9).all()


def test_pads_shift_the_bound_and_sets_that_meet_are_never_certified() -> None:
    """Grown by pads, the bound drops by their sum; overlapping polytopes bound <= 0."""
    a, b = _polytope_pairs(20)
    support_a, support_b, _, _ = _supports(a, b)
    x0 = start(support_a, support_b, np.ones((len(a), 3)))
    bare = separation_m(support_a, support_b, x0, np.zeros(len(a)), 0.0)
    padded = separation_m(support_a, support_b, x0, np.full(len(a), 0.01), -1.0)
    assert (padded <= bare - 0.01 + 1e-12).all()
    eye, zero = np.eye(3)[None].repeat(len(a), 0), np.zeros((len(a), 3))
    support_c = _placed(a, eye, zero)
    support_d = _placed(a + 0.3 * (a[:, :1] - a.mean(axis=1, keepdims=True)), eye, zero)
    x0 = start(support_c, support_d, np.ones((len(a), 3)))
    assert (separation_m(support_c, support_d, x0, np.zeros(len(a)), 0.0) <= 0).all()


@pytest.mark.parametrize(
    ("shape", "dimensions"),
    [("box", (0.3, 0.1, 0.2)), ("sphere", (0.08,)), ("cylinder", (0.3, 0.05)),
     ("capsule", (0.2, 0.04))],
)  # fmt: skip
def test_each_obstacle_is_measured_as_coal_measures_it(
    shape: str, dimensions: tuple[float, ...]
) -> None:
    """A polytope against a placed, turned primitive: certified within 2 resolutions of
    coal's distance, never above it."""
    count = 30
    a = RNG.normal(size=(count, 20, 3)) * 0.05
    centre = RNG.normal(size=(count, 1, 3))
    centre *= 0.25 / np.linalg.norm(centre, axis=2, keepdims=True)
    a += centre
    eye = np.eye(3)[None].repeat(count, 0)
    support_a = _placed(a, eye, np.zeros((count, 3)))
    q = RNG.normal(size=4)
    wxyz = tuple(float(v) for v in q / np.linalg.norm(q))
    obstacle = Obstacle.of(0, shape, dimensions, [0.01, -0.02, 0.03], wxyz)  # type: ignore[arg-type]
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = obstacle.rotation, obstacle.position_m
    geometry = coal_geometry(shape, dimensions)
    exact = np.array([
        _coal_distance(_coal_convex(a[i]), np.eye(4), geometry, pose) for i in range(count)
    ])  # fmt: skip
    x0 = start(support_a, obstacle.support_m, a.mean(axis=1) - obstacle.position_m)
    pad = np.full(count, obstacle.pad_m)
    for i in np.flatnonzero(exact > 3 * RESOLUTION_M):
        margin = exact[i] - 2 * RESOLUTION_M
        bound = separation_m(support_a, obstacle.support_m, x0, pad, margin, np.array([i]))[i]
        assert margin <= bound <= exact[i] + 1e-9, (i, exact[i], bound)


def _nearest_by_qp(points: np.ndarray) -> np.ndarray:
    """The point of the hull of (k, 3) points nearest the origin, by SLSQP on the weights."""
    k = len(points)
    found = minimize(
        lambda w: float(np.sum((w @ points) ** 2)),
        np.full(k, 1.0 / k),
        bounds=[(0.0, 1.0)] * k,
        constraints=[{"type": "eq", "fun": lambda w: w.sum() - 1.0}],
        method="SLSQP",
        options={"ftol": 1e-16, "maxiter": 500},
    )
    return np.asarray(found.x @ points)


def _least_norm_m(points: np.ndarray) -> float:
    return float(np.linalg.norm(_nearest_by_qp(points)))


def test_the_nearest_point_of_a_simplex_is_the_least_squares_one() -> None:
    """As GJK calls it: W of 0 to 3 points, a new point z nearer along W's nearest point x
    than x; nearest_in_hull of z and W against a quadratic programme's least norm over
    their hull; the face kept holds z and the point."""
    for old_count in (0, 1, 2, 3):
        points = np.zeros((30, 4, 3))
        used = np.zeros((30, 4), dtype=bool)
        used[:, : old_count + 1] = True
        for row in range(30):
            while True:
                old = RNG.normal(size=(old_count, 3)) + 0.5
                z = RNG.normal(size=3)
                if old_count == 0:
                    break
                x = _nearest_by_qp(old)
                if z @ x < x @ x - 1e-6:
                    break
            points[row, 0], points[row, 1 : old_count + 1] = z, old
        nearest, keep = nearest_in_hull(points, used)
        reference = [_least_norm_m(p[: old_count + 1]) for p in points]
        np.testing.assert_allclose(np.linalg.norm(nearest, axis=1), reference, atol=1e-6)
        assert keep[:, 0].all() and not (keep & ~used).any()
        for row in range(30):  # the point is in the kept face's affine hull
            face = points[row, keep[row]]
            offsets = face[1:] - face[0]
            residual = nearest[row] - face[0]
            if len(offsets):
                solution = np.linalg.lstsq(offsets.T, residual, rcond=None)[0]
                residual = residual - offsets.T @ solution
            assert np.linalg.norm(residual) < 1e-9


def test_a_configurations_deepest_pair_decides_first() -> None:
    """A configuration whose deepest pair meets keeps its other pairs' sphere gaps; the
    others get their separations, never below the gap given."""
    a, b = _polytope_pairs(6)
    support_a, support_b, _, _ = _supports(a, b)
    x0 = start(support_a, support_b, np.ones((6, 3)))
    full = separation_m(support_a, support_b, x0, np.zeros(6), 0.0)
    group = np.array([0, 0, 0, 1, 1, 1])
    gap = np.array([-1.0, -2.0, -0.5, -0.1, -0.3, -0.2])
    separation = partial(separation_m, support_a, support_b, x0, np.zeros(6), 0.0)
    bound = separation_deepest_first_m(separation, 0.0, group, gap)
    assert (bound >= gap).all()
    for g in (0, 1):
        rows = np.flatnonzero(group == g)
        deepest = rows[np.argmin(gap[rows])]
        assert bound[deepest] == max(gap[deepest], full[deepest])
        if full[deepest] < 0:
            others = rows[rows != deepest]
            assert (bound[others] == gap[others]).all()
