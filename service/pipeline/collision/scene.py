"""The request's obstacles: solid primitives in the model's base frame, as MoveIt's
planning scene gives them (shape_msgs/SolidPrimitive), and the signed distance of the
robot's spheres to them.

    box       dimensions [x, y, z]      full side lengths, centred on its position
    sphere    dimensions [radius]
    cylinder  dimensions [height, radius]  along its z axis, centred
    capsule   dimensions [height, radius]  the segment between the cap centres along z
              (height), centred, swept by the radius: total length height + 2 radius

The orientation is the same named-field unit quaternion as a pose target's (identity
when left out). Each kernel gives the signed distance from a point to the solid (negative
inside) in the obstacle's own frame; a sphere of radius r is clear of it by that minus r.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Literal, get_args

import numpy as np

from service.errors import RequestFieldError
from service.pipeline import native
from service.pipeline.arrays import FloatArray, IntArray
from service.pipeline.collision.robot import PlacedBodies, RobotSpheres
from service.pipeline.rotations import quaternion_to_matrix
from service.pipeline.targets import QUATERNION_NORM_TOLERANCE

ShapeName = Literal["box", "sphere", "cylinder", "capsule"]
SHAPES: tuple[ShapeName, ...] = get_args(ShapeName)
DIMENSION_NAMES: dict[ShapeName, tuple[str, ...]] = {
    "box": ("x", "y", "z"),
    "sphere": ("radius",),
    "cylinder": ("height", "radius"),
    "capsule": ("height", "radius"),
}
# Past this size (m) a dimension is a unit mistake (millimetres), not a scene.
MAX_DIMENSION_M = 100.0


@dataclass(frozen=True)
class Obstacle:
    shape: ShapeName
    dimensions_m: tuple[float, ...]  # as DIMENSION_NAMES
    position_m: FloatArray  # (3,) base frame
    rotation: FloatArray  # (3, 3) obstacle frame -> base frame

    @classmethod
    def of(
        cls,
        index: int,
        shape: str,
        dimensions_m: Sequence[float],
        position_m: Sequence[float],
        orientation_wxyz: tuple[float, float, float, float] | None,
    ) -> Obstacle:
        """One obstacle of a request, checked; RequestFieldError names obstacles[index]'s
        field and says what is valid."""
        where, field = ("body", "obstacles", index), f"obstacles[{index}]"
        if shape not in SHAPES:
            raise RequestFieldError(
                (*where, "shape"), f"{field}.shape must be one of {list(SHAPES)}, got {shape!r}"
            )
        names = DIMENSION_NAMES[shape]
        if len(dimensions_m) != len(names) or not all(
            0.0 < d <= MAX_DIMENSION_M for d in dimensions_m
        ):
            raise RequestFieldError(
                (*where, "dimensions"),
                f"{field}.dimensions of a {shape} are [{', '.join(names)}]: {len(names)} values "
                f"in metres, each above 0 and at most {MAX_DIMENSION_M:g}, got "
                f"{list(dimensions_m)}",
            )
        if len(position_m) != 3:
            raise RequestFieldError(
                (*where, "position"),
                f"{field}.position must have 3 values (x, y, z), got {len(position_m)}",
            )
        rotation = np.eye(3)
        if orientation_wxyz is not None:
            with np.errstate(over="ignore"):
                norm = float(np.linalg.norm(orientation_wxyz))
            if not abs(norm - 1.0) <= QUATERNION_NORM_TOLERANCE:
                raise RequestFieldError(
                    (*where, "orientation"),
                    f"{field}.orientation must be a unit quaternion (norm within "
                    f"{QUATERNION_NORM_TOLERANCE} of 1, normalised then), got norm {norm:.6g}",
                )
            rotation = quaternion_to_matrix(*orientation_wxyz)
        return cls(
            shape=shape,
            dimensions_m=tuple(float(d) for d in dimensions_m),
            position_m=np.asarray(position_m, dtype=np.float64),
            rotation=rotation,
        )

    @property
    def reach_m(self) -> float:
        """The radius of the smallest sphere about its position that holds it."""
        d = self.dimensions_m
        if self.shape == "box":
            return 0.5 * math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        if self.shape == "sphere":
            return d[0]
        if self.shape == "cylinder":
            return math.hypot(0.5 * d[0], d[1])
        return 0.5 * d[0] + d[1]  # capsule

    @property
    def pad_m(self) -> float:
        """The radius its core (`support_m`) is grown by: a sphere's and a capsule's."""
        radius = {"sphere": 0, "capsule": 1}.get(self.shape)
        return 0.0 if radius is None else self.dimensions_m[radius]

    def support_m(self, u: FloatArray, rows: IntArray | None = None) -> FloatArray:  # (M, 3)
        """The point of its core farthest along each direction, base frame: a box's corner,
        a cylinder's rim point, a capsule's cap centre, a sphere's centre (convex.py)."""
        local = u @ self.rotation  # R^T u, (M, 3)
        half = 0.5 * np.asarray(self.dimensions_m)
        point = np.zeros_like(local)
        if self.shape == "box":
            point = np.sign(local) * half
        elif self.shape in ("cylinder", "capsule"):
            point[:, 2] = np.sign(local[:, 2]) * half[0]
        if self.shape == "cylinder":
            radial = np.linalg.norm(local[:, :2], axis=1, keepdims=True)  # (M, 1)
            point[:, :2] = local[:, :2] * (self.dimensions_m[1] / np.where(radial > 0, radial, 1))
        return point @ self.rotation.T + self.position_m

    def signed_distance_m(self, points_m: FloatArray) -> FloatArray:  # (..., 3) -> (...)
        """Signed distance of base-frame points to the solid (negative inside)."""
        local = (points_m - self.position_m) @ self.rotation  # R^T (p - t), row vectors
        return _SIGNED_DISTANCE[self.shape](local, self.dimensions_m)


@dataclass(frozen=True)
class Scene:
    """The obstacles of one request (one scene for every target of a batch)."""

    obstacles: tuple[Obstacle, ...] = ()

    @cached_property
    def compiled(self) -> native.ObstacleSet:
        """The obstacles as the compiled obstacle passes take them."""
        count = len(self.obstacles)
        dims = np.zeros((count, 3))
        for k, obstacle in enumerate(self.obstacles):
            dims[k, : len(obstacle.dimensions_m)] = obstacle.dimensions_m
        return native.ObstacleSet(
            shape=np.array([native.OBSTACLE_SHAPES.index(o.shape) for o in self.obstacles],
                           dtype=np.int64),
            dims_m=dims,
            rotation=np.array([o.rotation for o in self.obstacles]).reshape(count, 3, 3),
            position_m=np.array([o.position_m for o in self.obstacles]).reshape(count, 3),
            reach_m=np.array([o.reach_m for o in self.obstacles]),
            pad_m=np.array([o.pad_m for o in self.obstacles]),
        )  # fmt: skip

    def clearance_m(
        self,
        placed: PlacedBodies,  # the bodies at B configurations
        robot: RobotSpheres,
        within: FloatArray,  # (B,) the least clearance found so far (+inf: none)
    ) -> FloatArray:  # (B,)
        """The least of `within` and the signed distance (negative: penetrating) of the
        moving bodies' spheres to any obstacle.

        Exact, with bounds that spare most of the work, as in robot.py: a body's bounding
        sphere against an obstacle's bounds their distance from below, first against the
        obstacle's bounding sphere (every pair at once), then against the obstacle itself;
        one sphere of the pair nearest by that bound gives each configuration an attained
        distance. Only (configuration, body, obstacle) triples whose lower bound is under
        the configuration's least distance so far are measured sphere by sphere. Compiled,
        row by row (`native.obstacle_clearance_m`).
        """
        if not self.obstacles or not robot.moving.any():
            return within.copy()
        return native.obstacle_clearance_m(
            robot.moving_bodies, self.compiled, placed.rotation, placed.origin_m, within
        )

    def refined_clearance_m(
        self, placed: PlacedBodies, robot: RobotSpheres, rows: IntArray, margin_m: float
    ) -> FloatArray:  # rows (R,) -> (R,)
        """A lower bound of the moving bodies' least distance to the obstacles at
        configurations `rows`, at least `clearance_m`'s: a (body, obstacle) pair clear by
        the margin on the bounds counts with that bound, a sphere clear by it with its
        distance, and every other sphere with its hull's separation from the obstacle
        (robot.py, convex.py), each configuration's deepest first
        (`convex.separation_deepest_first_m`). Compiled, row by row
        (`native.refined_obstacle_clearance_m`)."""
        if not self.obstacles or not robot.moving.any():
            return np.full(len(rows), np.inf)
        return native.refined_obstacle_clearance_m(
            robot.moving_bodies, self.compiled, placed.rotation[rows], placed.origin_m[rows],
            margin_m,
        )  # fmt: skip


def _box(p: FloatArray, dimensions: tuple[float, ...]) -> FloatArray:  # (..., 3) -> (...)
    excess = np.abs(p) - 0.5 * np.asarray(dimensions)  # (..., 3)
    outside = np.linalg.norm(np.maximum(excess, 0.0), axis=-1)
    return outside + np.minimum(excess.max(axis=-1), 0.0)


def _sphere(p: FloatArray, dimensions: tuple[float, ...]) -> FloatArray:
    return np.linalg.norm(p, axis=-1) - dimensions[0]


def _cylinder(p: FloatArray, dimensions: tuple[float, ...]) -> FloatArray:
    height, radius = dimensions
    radial = np.hypot(p[..., 0], p[..., 1]) - radius  # (...)
    axial = np.abs(p[..., 2]) - 0.5 * height
    outside = np.hypot(np.maximum(radial, 0.0), np.maximum(axial, 0.0))
    return outside + np.minimum(np.maximum(radial, axial), 0.0)


def _capsule(p: FloatArray, dimensions: tuple[float, ...]) -> FloatArray:
    height, radius = dimensions
    nearest_z = np.clip(p[..., 2], -0.5 * height, 0.5 * height)
    return np.sqrt(p[..., 0] ** 2 + p[..., 1] ** 2 + (p[..., 2] - nearest_z) ** 2) - radius


_SIGNED_DISTANCE = {"box": _box, "sphere": _sphere, "cylinder": _cylinder, "capsule": _capsule}
