"""The reference collision checker: coal on the URDF's own geometry, placed by the chain.

coal (the successor of the Flexible Collision Library, which MoveIt checks with) is given
every body's shapes as they are in the URDF: meshes as BVH models (read by coal's assimp
loader), primitives as coal shapes. A body moves with its chain frame T_k(q)
(`service.pipeline.collision.frames.chain_frames`), a shape at T_k(q) @ its pose in that
frame. This is what the sphere model is checked against: the tests (the spheres never
call free what coal calls in collision, never report more clearance than coal) and the
build's free space lost.

Distances: coal.distance's exact distance when two shapes are apart. When they touch
(coal.collide), the distance reported is min(coal's distance, 0): negative, the
penetration depth, for a pair with a primitive (coal's GJK/EPA); 0 between two meshes,
for which coal computes no depth.

Obstacles follow MoveIt's SolidPrimitive dimensions: box [x, y, z] full sizes, sphere
[r], cylinder [height, r], capsule [height, r] with height the distance between the cap
centres: coal.Box(x, y, z), coal.Sphere(r), coal.Cylinder(r, height), coal.Capsule(r,
height) (coal's lz is that same length: its half is `halfLength`).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import coal
import numpy as np

from service.manifest import ChainSpec
from service.pipeline.arrays import FloatArray
from service.pipeline.collision.frames import chain_frames
from training.collision.geometry import Body, Shape

OBSTACLE_SHAPES = ("box", "sphere", "cylinder", "capsule")


@dataclass(frozen=True)
class Obstacle:
    """A solid primitive in the base frame: MoveIt's dimensions (module docstring)."""

    shape: str
    dimensions_m: tuple[float, ...]
    position_m: FloatArray  # (3,)
    rotation: FloatArray  # (3, 3)


def coal_geometry(kind: str, dimensions_m: Sequence[float], mesh: Shape | None = None) -> Any:
    """The coal object of a shape: a primitive from MoveIt's dimensions, or a mesh's BVH."""
    if kind == "mesh" and mesh is not None and mesh.mesh_path is not None:
        return coal.MeshLoader().load(str(mesh.mesh_path), np.asarray(mesh.mesh_scale))
    sizes = {"box": 3, "sphere": 1, "cylinder": 2, "capsule": 2}
    if kind not in sizes:
        raise ValueError(f"shape {kind!r}: choose from {[*sizes, 'mesh']}")
    if len(dimensions_m) != sizes[kind]:
        raise ValueError(f"{kind} dimensions {list(dimensions_m)}: give {sizes[kind]} numbers")
    if kind == "box":
        return coal.Box(*(float(d) for d in dimensions_m))
    if kind == "sphere":
        return coal.Sphere(float(dimensions_m[0]))
    height, radius = (float(d) for d in dimensions_m)
    return (coal.Cylinder if kind == "cylinder" else coal.Capsule)(radius, height)


def _transform(pose: FloatArray) -> Any:
    return coal.Transform3s(np.ascontiguousarray(pose[:3, :3]), np.ascontiguousarray(pose[:3, 3]))


class CoalRobot:
    """The bodies as coal objects, and their distances and collisions at configurations."""

    def __init__(self, chain: ChainSpec, bodies: Sequence[Body]) -> None:
        self.chain = chain
        self.bodies = tuple(bodies)
        self.names = tuple(body.link for body in bodies)
        # per body: (coal geometry, pose in the body's frame) of each shape
        self.shapes = [
            [(coal_geometry(s.kind, s.dimensions_m, s), s.pose) for s in body.shapes]
            for body in bodies
        ]
        self.frames = np.array([body.frame for body in bodies], dtype=np.int64)

    def checked_pairs(self, disabled: Iterable[tuple[str, str]]) -> list[tuple[int, int]]:
        """Index pairs (a < b) of the bodies not disabled."""
        off = {frozenset(pair) for pair in disabled}
        count = len(self.names)
        return [
            (a, b) for a in range(count) for b in range(a + 1, count)
            if frozenset((self.names[a], self.names[b])) not in off
        ]  # fmt: skip

    def _placed(self, frames: FloatArray, body: int) -> list[tuple[Any, Any]]:
        """(geometry, coal transform) of the body's shapes at one configuration's frames."""
        base = frames[self.frames[body]]
        return [(geometry, _transform(base @ pose)) for geometry, pose in self.shapes[body]]

    def pair_collisions(self, q_rad: FloatArray, pairs: Sequence[tuple[int, int]]) -> np.ndarray:
        """(B, P) whether body pair p touches at each configuration (coal.collide)."""
        frames = chain_frames(self.chain, q_rad)
        request = coal.CollisionRequest()
        touching = np.zeros((len(frames), len(pairs)), dtype=bool)
        for i, frame in enumerate(frames):
            placed = [self._placed(frame, body) for body in range(len(self.names))]
            for p, (a, b) in enumerate(pairs):
                touching[i, p] = _any_collision(placed[a], placed[b], request)
        return touching

    def pair_distances_m(
        self, q_rad: FloatArray, pairs: Sequence[tuple[int, int]]
    ) -> FloatArray:  # (B, P)
        """Least distance between body pair p's shapes at each configuration (module
        docstring: exact apart, <= 0 touching)."""
        frames = chain_frames(self.chain, q_rad)
        distances = np.empty((len(frames), len(pairs)))
        for i, frame in enumerate(frames):
            placed = [self._placed(frame, body) for body in range(len(self.names))]
            for p, (a, b) in enumerate(pairs):
                distances[i, p] = _least_distance(placed[a], placed[b])
        return distances

    def self_distance_m(
        self, q_rad: FloatArray, disabled: Iterable[tuple[str, str]]
    ) -> FloatArray:  # (B,)
        """The least distance over the body pairs not disabled; +inf when none is checked."""
        pairs = self.checked_pairs(disabled)
        if not pairs:
            return np.full(len(q_rad), np.inf)
        return self.pair_distances_m(q_rad, pairs).min(axis=1)

    def in_self_collision(
        self, q_rad: FloatArray, disabled: Iterable[tuple[str, str]]
    ) -> np.ndarray:  # (B,)
        """Whether any body pair not disabled touches."""
        pairs = self.checked_pairs(disabled)
        if not pairs:
            return np.zeros(len(q_rad), dtype=bool)
        return np.asarray(self.pair_collisions(q_rad, pairs).any(axis=1))

    def obstacle_distance_m(self, q_rad: FloatArray, obstacles: Sequence[Obstacle]) -> FloatArray:
        """(B,) the least distance of the moving bodies (frame > 0) to the obstacles;
        +inf without obstacles or moving bodies."""
        placed_obstacles = [
            (coal_geometry(o.shape, o.dimensions_m), _transform(_pose(o))) for o in obstacles
        ]
        frames = chain_frames(self.chain, q_rad)
        moving = np.flatnonzero(self.frames > 0)
        least = np.full(len(frames), np.inf)
        for i, frame in enumerate(frames):
            for body in moving:
                d = _least_distance(self._placed(frame, int(body)), placed_obstacles)
                least[i] = min(least[i], d)
        return least

    def within_m(
        self,
        q_rad: FloatArray,
        disabled: Iterable[tuple[str, str]],
        obstacles: Sequence[Obstacle],
        margin_m: float,
    ) -> np.ndarray:  # (B,)
        """Whether any body pair not disabled, or any moving body and obstacle, is closer
        than `margin_m` (touching included): coal.collide with the margin as its security
        margin, far cheaper than the distances when only the verdict is asked."""
        pairs = self.checked_pairs(disabled)
        request = coal.CollisionRequest()
        request.security_margin = float(margin_m)
        placed_obstacles = [
            (coal_geometry(o.shape, o.dimensions_m), _transform(_pose(o))) for o in obstacles
        ]
        moving = np.flatnonzero(self.frames > 0).tolist()
        near = np.zeros(len(q_rad), dtype=bool)
        for i, frame in enumerate(chain_frames(self.chain, q_rad)):
            placed = [self._placed(frame, body) for body in range(len(self.names))]
            near[i] = any(_any_collision(placed[a], placed[b], request) for a, b in pairs) or any(
                _any_collision(placed[body], placed_obstacles, request) for body in moving
            )
        return near


def _pose(obstacle: Obstacle) -> FloatArray:
    if obstacle.shape not in OBSTACLE_SHAPES:
        raise ValueError(f"obstacle shape {obstacle.shape!r}: choose from {list(OBSTACLE_SHAPES)}")
    pose = np.eye(4)
    pose[:3, :3] = obstacle.rotation
    pose[:3, 3] = obstacle.position_m
    return pose


def _any_collision(
    first: list[tuple[Any, Any]], second: list[tuple[Any, Any]], request: Any
) -> bool:
    for g1, t1 in first:
        for g2, t2 in second:
            if coal.collide(g1, t1, g2, t2, request, coal.CollisionResult()):
                return True
    return False


def _least_distance(first: list[tuple[Any, Any]], second: list[tuple[Any, Any]]) -> float:
    """min over the shape pairs of coal's distance, min(distance, 0) when they touch."""
    request, collision = coal.DistanceRequest(), coal.CollisionRequest()
    least = np.inf
    for g1, t1 in first:
        for g2, t2 in second:
            distance = coal.distance(g1, t1, g2, t2, request, coal.DistanceResult())
            if distance <= 0 or coal.collide(g1, t1, g2, t2, collision, coal.CollisionResult()):
                distance = min(distance, 0.0)
            least = min(least, distance)
    return float(least)
