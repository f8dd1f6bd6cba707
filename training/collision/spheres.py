"""A conservative sphere cover of each body: every point of its geometry lies in a sphere.

The service checks collisions on spheres alone (`service.pipeline.collision.robot`), so
the cover must contain the geometry: then a configuration the spheres call free is free.
Each shape is cut into convex pieces, each the convex hull of a few points grown by a
pad (a ball of radius pad around every point of the hull):

    mesh      its triangles (3 corners, pad 0), split at the edge midpoints until no
              edge is longer than h;
    box       a grid of cells no longer than h on a side (8 corners, pad 0);
    cylinder  slices no longer than h, each inside the prism over the regular 16-gon
              circumscribing its disc (32 corners, pad 0);
    capsule   slices of its axis no longer than h (2 points, pad r);
    sphere    its centre (1 point, pad r): exact.

with h the body's extent / (2 x budget). A ball is convex, so a ball with centre c and
radius max over the piece's points of |c - p| + pad contains the piece. The pieces are
grouped into at most `budget` clusters (k-means on their centroids, the best of a few
seeds by total sphere volume), then each cluster's centre is moved towards the centre of
the smallest ball holding its pieces (Badoiu-Clarkson iterations) and pieces move to the
sphere they grow least, a few rounds; the radius is always recomputed from the pieces, so
the cover stays conservative whatever the refinement does.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.spatial import ConvexHull, QhullError

from service.manifest import CollisionBody
from service.pipeline.arrays import FloatArray, IntArray
from training.collision.geometry import Body, Shape, mesh_triangles_m

# Spheres per body. Measured on the Panda (11 bodies; 3,000 configurations uniform in the
# limits; free space lost as `build` measures it, with the pairs sampled / the SRDF's):
#   spheres per body   2      3      4     6     8     12    16
#   free space lost %  8.3    5.2    4.3   3.1   3.1   3.4   4.5   (pairs sampled)
#                      16.6   13.7   8.1   5.8   4.7   7.6   8.4   (the SRDF's pairs)
# 8 loses the least; past it the cover, chosen by total sphere volume (a proxy for the
# space it adds), stops improving, so more spheres would only add sphere pairs to the
# service's check. A sphere around a section of a round link is never narrower than the
# link: the links' thickness, not the count, sets most of what is left.
DEFAULT_SPHERES_PER_BODY = 8
POLYGON_SIDES = 16  # of the prism circumscribing a cylinder's slice: 1.9 % wider than r
PIECE_SCALE = 1  # h = extent / (PIECE_SCALE x budget): pieces no larger than a sphere
KMEANS_SEEDS = 3
REFINE_ROUNDS = 4
CENTRE_ITERATIONS = 100
# Added to every radius: the test points of a piece are computed with rounding too, and
# its hull is stored rounded (it holds the hull grown by HULL_DECIMALS' rounding).
RADIUS_MARGIN_M = 1e-6
# Hull vertices are stored to 0.1 um and their pads grown by that: the rounded hull so
# grown holds the exact one (a vertex moves at most 0.087 um).
HULL_DECIMALS = 7
HULL_ROUNDING_PAD_M = 1e-7


@dataclass(frozen=True)
class Pieces:
    """Convex pieces of a body: piece e is the hull of points_m[point_piece == e] grown by
    pad_m[point_piece == e] (one pad per piece, repeated per point)."""

    points_m: FloatArray  # (M, 3)
    pad_m: FloatArray  # (M,)
    point_piece: IntArray  # (M,) piece of each point
    count: int

    def centroids_m(self) -> FloatArray:  # (E, 3)
        sums = np.zeros((self.count, 3))
        np.add.at(sums, self.point_piece, self.points_m)
        return sums / np.bincount(self.point_piece, minlength=self.count)[:, None]


def body_pieces(body: Body, budget: int) -> Pieces:
    """The body's shapes cut into pieces of size at most h (module docstring)."""
    coarse = [_shape_pieces(shape, math.inf) for shape in body.shapes]
    points = np.concatenate([p for piece in coarse for p, _ in piece])
    pads = np.array([pad for piece in coarse for _, pad in piece])
    extent_m = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) + 2 * pads.max()
    h = extent_m / (PIECE_SCALE * budget)
    pieces = [piece for shape in body.shapes for piece in _shape_pieces(shape, h)]
    sizes = [len(p) for p, _ in pieces]
    return Pieces(
        points_m=np.concatenate([p for p, _ in pieces]),
        pad_m=np.repeat([pad for _, pad in pieces], sizes),
        point_piece=np.repeat(np.arange(len(pieces)), sizes),
        count=len(pieces),
    )


def _shape_pieces(shape: Shape, h: float) -> list[tuple[FloatArray, float]]:
    """(points (P, 3) in the body frame, pad) of each piece of `shape`, no piece longer
    than `h` (inf: whole)."""
    rotation, origin = shape.pose[:3, :3], shape.pose[:3, 3]
    if shape.kind == "mesh":
        triangles = _subdivided(mesh_triangles_m(shape), h)
        return [(t, 0.0) for t in triangles]
    if shape.kind == "sphere":
        return [(origin[None].copy(), shape.dimensions_m[0])]
    if shape.kind == "box":
        local = _box_cells(np.asarray(shape.dimensions_m), h)  # (C, 8, 3)
    else:
        length, radius = shape.dimensions_m
        cuts = np.linspace(-length / 2, length / 2, _count(length, h) + 1)
        if shape.kind == "capsule":
            local = np.stack(
                [np.zeros((len(cuts) - 1, 2)), np.zeros((len(cuts) - 1, 2)),
                 np.stack([cuts[:-1], cuts[1:]], 1)], axis=2,
            )  # fmt: skip
            return [(p @ rotation.T + origin, radius) for p in local]
        local = _prism_slices(radius, cuts)
    return [(p @ rotation.T + origin, 0.0) for p in local]


def _count(length: float, h: float) -> int:
    return max(1, math.ceil(length / h)) if math.isfinite(h) else 1


def _box_cells(size: FloatArray, h: float) -> FloatArray:  # (C, 8, 3)
    """The corners of a grid of cells filling the box of full sizes `size`, centred at 0."""
    edges = [np.linspace(-s / 2, s / 2, _count(float(s), h) + 1) for s in size]
    lows = np.stack(np.meshgrid(*(e[:-1] for e in edges), indexing="ij"), -1).reshape(-1, 3)
    highs = np.stack(np.meshgrid(*(e[1:] for e in edges), indexing="ij"), -1).reshape(-1, 3)
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])  # (8, 3)
    return np.where(corners[None] == 0, lows[:, None], highs[:, None])


def _prism_slices(radius: float, cuts: FloatArray) -> FloatArray:  # (C, 2 x sides, 3)
    """Corners of the prisms over the regular polygon circumscribing the disc of `radius`
    (z axis), one per slice between consecutive `cuts`."""
    angles = 2 * math.pi * np.arange(POLYGON_SIDES) / POLYGON_SIDES
    circumradius = radius / math.cos(math.pi / POLYGON_SIDES)
    ring = circumradius * np.stack([np.cos(angles), np.sin(angles)], 1)  # (sides, 2)
    slices = [
        np.concatenate(
            [np.c_[ring, np.full(len(ring), low)], np.c_[ring, np.full(len(ring), high)]]
        )
        for low, high in itertools.pairwise(cuts)
    ]
    return np.stack(slices)


def _subdivided(triangles: FloatArray, h: float) -> FloatArray:  # (T, 3, 3) -> (T', 3, 3)
    """Triangles split into four at their edge midpoints until every edge is at most h:
    the pieces cover the same surface."""
    while math.isfinite(h):
        edges = np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2).max(axis=1)
        long = edges > h
        if not long.any():
            break
        a, b, c = (triangles[long, i] for i in range(3))
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        split = np.stack(
            [np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))], 1
        ).reshape(-1, 3, 3)
        triangles = np.concatenate([triangles[~long], split])
    return triangles


def piece_radii_m(pieces: Pieces, centres_m: FloatArray) -> FloatArray:  # (E, K)
    """max over piece e's points of |c_k - p| + pad: the radius sphere k needs to hold e."""
    reach = np.linalg.norm(pieces.points_m[:, None] - centres_m[None], axis=2)  # (M, K)
    reach += pieces.pad_m[:, None]
    needed = np.full((pieces.count, len(centres_m)), -np.inf)
    np.maximum.at(needed, pieces.point_piece, reach)
    return needed


def _minimax_centre(points_m: FloatArray, pad_m: FloatArray) -> FloatArray:
    """A centre near the one of the smallest ball holding the balls (points, pads):
    Badoiu-Clarkson steps towards the farthest, the best centre seen."""
    rows = np.unique(np.c_[points_m, pad_m], axis=0)  # subdivided meshes share corners
    points_m, pad_m = rows[:, :3], rows[:, 3]
    centre = (points_m.max(axis=0) + points_m.min(axis=0)) / 2
    best, best_radius = centre, np.inf
    for step in range(1, CENTRE_ITERATIONS + 1):
        reach = np.linalg.norm(points_m - centre, axis=1) + pad_m
        far = int(np.argmax(reach))
        if reach[far] < best_radius:
            best, best_radius = centre, float(reach[far])
        centre = centre + (points_m[far] - centre) / (step + 1)
    return best


def _cover(pieces: Pieces, label: IntArray, clusters: int) -> tuple[FloatArray, FloatArray]:
    """Minimax centres of the non-empty clusters, then the radii from the pieces."""
    point_label = label[pieces.point_piece]
    centres = np.array([
        _minimax_centre(pieces.points_m[point_label == k], pieces.pad_m[point_label == k])
        for k in range(clusters) if np.any(label == k)
    ])  # fmt: skip
    kept = np.unique(label)
    relabel = np.searchsorted(kept, label)
    needed = piece_radii_m(pieces, centres)  # (E, K)
    radii = np.full(len(centres), -np.inf)
    np.maximum.at(radii, relabel, needed[np.arange(pieces.count), relabel])
    return centres, radii


def _ball(pieces: Pieces, members: IntArray) -> tuple[FloatArray, float]:
    """Minimax centre of the pieces `members` and the radius that holds them."""
    points = np.isin(pieces.point_piece, members)
    centre = _minimax_centre(pieces.points_m[points], pieces.pad_m[points])
    reach = np.linalg.norm(pieces.points_m[points] - centre, axis=1) + pieces.pad_m[points]
    return centre, float(reach.max())


def _split_cover(pieces: Pieces, clusters: int, seed: int) -> IntArray:
    """Labels of a cover grown by splitting: the largest sphere's pieces cut in two by
    2-means (the best of KMEANS_SEEDS cuts by the two radii cubed), until `clusters`."""
    centroids = pieces.centroids_m()
    label = np.zeros(pieces.count, dtype=np.int64)
    radii = [_ball(pieces, np.arange(pieces.count))[1]]
    for new in range(1, clusters):
        order = np.argsort(radii)[::-1]
        for worst in order:
            members = np.flatnonzero(label == worst)
            if len(members) >= 2:
                break
        else:
            break
        best: tuple[float, IntArray, float, float] | None = None
        for attempt in range(KMEANS_SEEDS):
            _, half = kmeans2(centroids[members], 2, minit="++", seed=seed + attempt)
            if half.min() == half.max():
                continue
            r_stay = _ball(pieces, members[half == 0])[1]
            r_move = _ball(pieces, members[half == 1])[1]
            if best is None or r_stay**3 + r_move**3 < best[0]:
                best = (r_stay**3 + r_move**3, half, r_stay, r_move)
        if best is None:
            break
        label[members[best[1] == 1]] = new
        radii[int(worst)] = best[2]
        radii.append(best[3])
    return label


def _refined(pieces: Pieces, label: IntArray) -> tuple[FloatArray, FloatArray]:
    """The cover of `label`, then REFINE_ROUNDS of moving each piece to the sphere it grows
    least (volume) and re-centring; the smaller of before and after by volume."""
    centres, radii = _cover(pieces, label, int(label.max()) + 1)
    best = (centres, radii)
    for _ in range(REFINE_ROUNDS):
        grown = np.maximum(piece_radii_m(pieces, centres), radii[None]) ** 3 - radii**3
        label = np.argmin(grown, axis=1)
        centres, radii = _cover(pieces, label, len(centres))
        if np.sum(radii**3) < np.sum(best[1] ** 3):
            best = (centres, radii)
    return best


def cover_body(body: Body, budget: int = DEFAULT_SPHERES_PER_BODY, seed: int = 0) -> CollisionBody:
    """At most `budget` spheres holding every point of the body's geometry (module
    docstring), in its chain frame: the smallest by total volume of a cover grown by
    splitting and KMEANS_SEEDS k-means covers, each refined."""
    if budget < 1:
        raise ValueError(f"spheres per body: {budget}; give at least 1")
    pieces = body_pieces(body, budget)
    clusters = min(budget, pieces.count)
    labels = [_split_cover(pieces, clusters, seed)]
    if clusters > 1:
        centroids = pieces.centroids_m()
        labels += [
            kmeans2(centroids, clusters, minit="++", seed=seed + attempt)[1]
            for attempt in range(KMEANS_SEEDS)
        ]
    covers = [_refined(pieces, label) for label in labels]
    centres, radii = min(covers, key=lambda cover: float(np.sum(cover[1] ** 3)))
    hulls, pads = sphere_hulls(pieces, centres, radii)
    return CollisionBody(
        link=body.link,
        frame=body.frame,
        centres_m=centres.tolist(),
        radii_m=(radii + RADIUS_MARGIN_M).tolist(),
        hulls_m=[np.round(hull, HULL_DECIMALS).tolist() for hull in hulls],
        hull_pads_m=[pad + HULL_ROUNDING_PAD_M for pad in pads],
    )


def sphere_hulls(
    pieces: Pieces, centres_m: FloatArray, radii_m: FloatArray
) -> tuple[list[FloatArray], list[float]]:
    """Each sphere's hull: every piece goes to the sphere holding it whose centre is
    nearest its centroid (some sphere holds each: the radii came from the pieces), and a
    sphere's hull is the convex hull of its pieces' points grown by their largest pad. A
    piece is the hull of its points grown by its pad, so it lies in its sphere's hull; a
    ball holding every point and pad holds the hull. A sphere no piece went to, or
    whose pieces' pads differ so that the hull grown by the largest leaves it, keeps its
    centre grown by its radius (the sphere itself)."""
    needed = piece_radii_m(pieces, centres_m)  # (E, K)
    holds = needed <= radii_m[None] + RADIUS_MARGIN_M
    apart = np.linalg.norm(pieces.centroids_m()[:, None] - centres_m[None], axis=2)  # (E, K)
    owner = np.argmin(np.where(holds, apart, np.inf), axis=1)  # (E,)
    if not holds[np.arange(pieces.count), owner].all():
        raise AssertionError("a piece lies in no sphere: the cover is not conservative")
    hulls, pads = [], []
    for k in range(len(centres_m)):
        points = np.isin(pieces.point_piece, np.flatnonzero(owner == k))
        if not points.any():
            hulls.append(centres_m[k][None])
            pads.append(float(radii_m[k]))
            continue
        hull, pad = _hull_vertices(pieces.points_m[points]), float(pieces.pad_m[points].max())
        if np.linalg.norm(hull - centres_m[k], axis=1).max() + pad > radii_m[k]:
            hull, pad = centres_m[k][None], float(radii_m[k])  # mixed pads: the sphere
        hulls.append(hull)
        pads.append(pad)
    return hulls, pads


def _hull_vertices(points_m: FloatArray) -> FloatArray:  # (P, 3) -> (V, 3)
    """The vertices of the points' convex hull; the points themselves (deduplicated) when
    they span less than 3-D (a flat piece, a segment, a point), whose hull they are too."""
    unique = np.unique(points_m, axis=0)
    if len(unique) < 5:
        return unique
    try:
        return np.asarray(unique[ConvexHull(unique).vertices])
    except QhullError:
        return unique
