"""Lower bounds of the distance between convex sets, each given by its support point, by
the GJK algorithm (Gilbert, Johnson and Keerthi: the point of their difference nearest
the origin, over a simplex of support points).

For convex sets A and B and any direction x, every a in A and b in B satisfy

    |a - b| >= x.(a - b) / |x| >= (min_a x.a - max_b x.b) / |x|

so the right-hand side, the separation of A and B along x, is a lower bound of their
distance whatever x is: a configuration certified free by it is free. GJK moves x to the
point of D = A - B nearest the origin, where that bound equals the distance (convex
duality), with one support point of each set per step:

    z = s_A(-x) - s_B(x)                    the point of D least along x
    bound = x.z / |x| - pad_A - pad_B       the separation along x, sets grown by pads
    W <- the face of conv(W + {z}) holding its point nearest the origin; x <- that point

(`nearest_in_hull`: every face of the at most 4 points that holds z, each one's affine
projection of the origin kept when it lies in the face; the nearest of those). For
polytopes it ends in a few steps, where Frank-Wolfe steps alone zigzag between parallel
faces. GJK starts from any point of D (a hull's first vertex less the other's, or the
obstacle's centre). x stays in
D, so |x| - pads is an upper bound of the distance: once it is under the margin plus
`RESOLUTION_M` (or W is a tetrahedron holding the origin: the sets meet), the pair is
given up. Every pair stops when certified, given up, when z adds nothing or after
`ITERATIONS` steps; its best bound is returned, so an uncertified pair counts as not
free: conservative.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from service.pipeline.arrays import BoolArray, FloatArray, IntArray

# Support point of a set at the rows asked: (directions (M, 3), rows (M,)) -> (M, 3),
# a point of each row's set that is farthest along its direction.
Support = Callable[[FloatArray, IntArray], FloatArray]
# Separations of the pairs asked: rows (M,) -> (N,), each row's lower bound at those rows
# (`separation_m` with its sets and margin, or its compiled form for two placed hulls).
Separation = Callable[[IntArray], FloatArray]

ITERATIONS = 32
# Vertex counts the support groups hulls by (past the last: the widest asked).
HULL_WIDTHS = (16, 32, 64)
# A pair whose distance is within this of the margin may be given up: the clearance the
# check certifies is resolved to it.
RESOLUTION_M = 1e-4
# A face whose Gram determinant is this small relative to its edges' is degenerate (its
# lower faces decide).
DEGENERATE = 1e-10
# x is the nearest point when no support point is nearer along it by this fraction of |x|^2.
STALLED = 1e-12


def nearest_in_hull(
    points: FloatArray,  # (M, 4, 3) the newest support point first, then W's
    used: BoolArray,  # (M, 4) which are points (the first always)
) -> tuple[FloatArray, BoolArray]:  # (M, 3), (M, 4)
    """The point of each row's hull nearest the origin and the points of the face that
    holds it, over the faces that hold the first point (Johnson's sub-algorithm: the
    rest's nearest point is x, and the first is nearer along x, so the hull's nearest
    point has weight on it). Each face's affine projection of the origin is solved in
    closed form and kept when it lies in the face; the nearest of those."""
    p0 = points[:, 0]  # (M, 3)
    edges = points[:, 1:] - p0[:, None]  # (M, 3, 3) e_i = p_i - p_0
    gram = np.einsum("mki,mli->mkl", edges, edges)  # (M, 3, 3)
    toward = -np.einsum("mki,mi->mk", edges, p0)  # (M, 3) -p_0 . e_i
    rows = np.arange(len(points))
    best, nearest = np.linalg.norm(p0, axis=1), p0.copy()  # the face {0}
    keep = np.zeros((len(points), 4), dtype=bool)
    keep[:, 0] = True

    def offer(candidate: FloatArray, inside: BoolArray, face: tuple[int, ...]) -> None:
        norm = np.linalg.norm(candidate, axis=1)
        better = inside & (norm < best)
        best[better], nearest[better] = norm[better], candidate[better]
        keep[better] = False
        keep[np.ix_(rows[better], np.array(face))] = True

    for i in range(3):  # edges {0, i}
        length = gram[:, i, i]
        t = toward[:, i] / np.where(length > 0, length, 1.0)
        inside = used[:, i + 1] & (length > 0) & (t >= 0) & (t <= 1)
        offer(p0 + t[:, None] * edges[:, i], inside, (0, i + 1))
    for i, j in ((0, 1), (0, 2), (1, 2)):  # triangles {0, i, j}
        a, b, c = gram[:, i, i], gram[:, i, j], gram[:, j, j]
        det = a * c - b * b
        solvable = used[:, i + 1] & used[:, j + 1] & (det > DEGENERATE * a * c)
        det = np.where(solvable, det, 1.0)
        s = (c * toward[:, i] - b * toward[:, j]) / det
        t = (a * toward[:, j] - b * toward[:, i]) / det
        inside = solvable & (s >= 0) & (t >= 0) & (s + t <= 1)
        offer(p0 + s[:, None] * edges[:, i] + t[:, None] * edges[:, j], inside, (0, i + 1, j + 1))
    # The tetrahedron: p_0 + E mu = 0 by Cramer's rule, E's columns the edges.
    e1, e2, e3 = edges[:, 0], edges[:, 1], edges[:, 2]
    cross = np.stack([np.cross(e2, e3), np.cross(e3, e1), np.cross(e1, e2)], axis=1)  # (M, 3, 3)
    det = np.einsum("mi,mi->m", e1, cross[:, 0])
    scale = np.sqrt(gram[:, 0, 0] * gram[:, 1, 1] * gram[:, 2, 2])
    solvable = used.all(axis=1) & (np.abs(det) > DEGENERATE * scale)
    mu = -np.einsum("mki,mi->mk", cross, p0) / np.where(solvable, det, 1.0)[:, None]
    inside = solvable & (mu >= 0).all(axis=1) & (mu.sum(axis=1) <= 1)
    offer(np.zeros_like(p0), inside, (0, 1, 2, 3))
    return nearest, keep


def separation_m(
    support_a: Support,
    support_b: Support,
    x0: FloatArray,  # (N, 3) a point of A - B at each row
    pad_m: FloatArray,  # (N,) pad_A + pad_B
    margin_m: float,
    measure: IntArray | None = None,  # (M,) the rows to measure (None: all)
) -> FloatArray:  # (N,)
    """The best lower bound of the distance between A + ball(pad_A) and B + ball(pad_B)
    found at each row measured (module docstring); -inf at the others."""
    x = np.array(x0, dtype=np.float64)
    simplex = np.zeros((len(x), 4, 3))  # W: the support points x is nearest in
    simplex[:, 0] = x
    used = np.zeros((len(x), 4), dtype=bool)
    used[:, 0] = True
    best = np.full(len(x), -np.inf)
    active = np.arange(len(x)) if measure is None else measure
    for _ in range(ITERATIONS):
        if not len(active):
            break
        xa = x[active]  # (M, 3)
        squared = np.einsum("mi,mi->m", xa, xa)  # (M,)
        z = support_a(-xa, active) - support_b(xa, active)  # (M, 3) least along x
        along = np.einsum("mi,mi->m", xa, z)
        norm = np.sqrt(squared)
        bound = np.where(norm > 0, along / np.where(norm > 0, norm, 1.0), -np.inf)
        best[active] = np.maximum(best[active], bound - pad_m[active])
        stalled = squared - along <= STALLED * squared  # z is no nearer: x is the nearest
        # z first, then W's points (at most 3 here: 4 would hold the origin).
        order = np.argsort(~used[active], axis=1, kind="stable")[:, :3]  # (M, 3)
        points = np.concatenate(
            [z[:, None], np.take_along_axis(simplex[active], order[..., None], axis=1)], axis=1
        )  # (M, 4, 3)
        kept = np.concatenate(
            [np.ones((len(active), 1), bool), np.take_along_axis(used[active], order, axis=1)],
            axis=1,
        )
        x[active], used[active] = nearest_in_hull(points, kept)
        simplex[active] = points
        upper = np.linalg.norm(x[active], axis=1) - pad_m[active]
        met = used[active].all(axis=1)  # a tetrahedron holding the origin: the sets meet
        given_up = (upper < margin_m + RESOLUTION_M) | met
        active = active[~((best[active] >= margin_m) | given_up | stalled)]
    return best


def hull_support(
    hulls_local: FloatArray,  # (K, S, V, 3) every hull, padded with its first vertex
    counts: IntArray,  # (K, S) each hull's own vertex count
    body: IntArray,  # (N,) each row's hull: hulls_local[body, sphere]
    sphere: IntArray,  # (N,)
    rotation: FloatArray,  # (N, 3, 3) body frame -> base frame
    origin_m: FloatArray,  # (N, 3)
) -> Support:
    """The support of placed hulls: the vertex farthest along the direction. Rows are
    taken in groups by vertex count, each over its widest hull's vertices only (padding
    repeats the first vertex, so a narrower slice of a padded hull is the same hull)."""

    def support(u: FloatArray, rows: IntArray) -> FloatArray:
        turned = np.einsum("mji,mj->mi", rotation[rows], u)  # R^T u, (M, 3)
        local = np.empty_like(turned)
        count = counts[body[rows], sphere[rows]]  # (M,)
        low = 0
        for width in (*HULL_WIDTHS, int(count.max(initial=1))):
            group = np.flatnonzero((count > low) & (count <= width))
            low = max(low, width)
            if not len(group):
                continue
            vertices = hulls_local[body[rows[group]], sphere[rows[group]], :width]  # (G, w, 3)
            reach = np.einsum("gvi,gi->gv", vertices, turned[group])
            local[group] = vertices[np.arange(len(group)), np.argmax(reach, axis=1)]
        return np.einsum("mij,mj->mi", rotation[rows], local) + origin_m[rows]

    return support


def separation_deepest_first_m(
    separation: Separation,
    margin_m: float,
    group: IntArray,  # (N,) the configuration each pair belongs to
    gap_m: FloatArray,  # (N,) the pair's distance on the spheres: a lower bound already
) -> FloatArray:  # (N,)
    """A lower bound of each pair's distance, at least `gap_m`: each configuration's
    deepest pair by the spheres is measured first (`separation` of those rows), and a
    configuration it leaves less clear than the margin is not free whatever its other
    pairs are, which keep their gap; the other configurations' pairs are all measured."""
    order = np.lexsort((gap_m, group))  # by configuration, deepest first
    first = order[np.r_[True, group[order][1:] != group[order][:-1]]]  # (G,)
    bound = np.array(gap_m, dtype=np.float64)
    bound[first] = np.maximum(bound[first], separation(first)[first])
    failed = group[first][bound[first] < margin_m]
    rest = np.setdiff1d(np.flatnonzero(~np.isin(group, failed)), first)
    if len(rest):
        bound[rest] = np.maximum(bound[rest], separation(rest)[rest])
    return bound
