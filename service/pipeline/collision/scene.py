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
from functools import partial
from typing import Literal, get_args

import numpy as np

from service.errors import RequestFieldError
from service.pipeline.arrays import FloatArray, IntArray
from service.pipeline.collision.convex import separation_deepest_first_m, separation_m
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
        the configuration's least distance so far are measured sphere by sphere.
        """
        clearance = within.copy()
        moving = np.flatnonzero(robot.moving)  # (M,)
        if not self.obstacles or not len(moving):
            return clearance
        bounds = placed.bound_centres_m[:, moving]  # (B, M, 3)
        body_radius = robot.bound_radius_m[moving]  # (M,)
        centres = np.stack([o.position_m for o in self.obstacles])  # (K, 3)
        reach = np.array([o.reach_m for o in self.obstacles])  # (K,)
        apart = bounds[:, :, None, :] - centres  # (B, M, K, 3)
        coarse = np.sqrt(np.einsum("bmki,bmki->bmk", apart, apart))
        coarse -= body_radius[:, None] + reach  # (B, M, K) lower bounds
        # An attained distance per configuration: the first sphere of its nearest pair.
        nearest = coarse.reshape(len(coarse), -1).argmin(axis=1)  # (B,)
        body_of, obstacle_of = np.divmod(nearest, len(self.obstacles))
        for k in np.unique(obstacle_of):
            rows = np.flatnonzero(obstacle_of == k)
            body = moving[body_of[rows]]
            first = placed.first_centres_m[rows, body]  # (R, 3)
            upper = self.obstacles[k].signed_distance_m(first) - robot.radius_m[body, 0]
            np.minimum.at(clearance, rows, upper)
        for k, obstacle in enumerate(self.obstacles):
            rows, bodies = np.nonzero(coarse[:, :, k] < clearance[:, None])  # (N,), (N,)
            if not len(rows):
                continue
            lower = obstacle.signed_distance_m(bounds[rows, bodies]) - body_radius[bodies]
            near = lower < clearance[rows]
            rows, body = rows[near], moving[bodies[near]]
            if not len(rows):
                continue
            gap = obstacle.signed_distance_m(placed.spheres(rows, body))  # (N, S)
            gap -= robot.radius_m[body]
            np.minimum.at(clearance, rows, gap.min(axis=1))
        return clearance

    def refined_clearance_m(
        self, placed: PlacedBodies, robot: RobotSpheres, rows: IntArray, margin_m: float
    ) -> FloatArray:  # rows (R,) -> (R,)
        """A lower bound of the moving bodies' least distance to the obstacles at
        configurations `rows`, at least `clearance_m`'s: a (body, obstacle) pair clear by
        the margin on the bounds counts with that bound, a sphere clear by it with its
        distance, and every other sphere with its hull's separation from the obstacle
        (robot.py, convex.py)."""
        clearance = np.full(len(rows), np.inf)
        moving = np.flatnonzero(robot.moving)  # (M,)
        if not self.obstacles or not len(moving):
            return clearance
        bounds = placed.bound_centres_m[rows][:, moving]  # (R, M, 3)
        body_radius = robot.bound_radius_m[moving]  # (M,)
        for obstacle in self.obstacles:
            lower = obstacle.signed_distance_m(bounds) - body_radius  # (R, M)
            np.minimum.at(clearance, np.arange(len(rows)), np.where(
                lower >= margin_m, lower, np.inf).min(axis=1))  # fmt: skip
            # A configuration already not free is not measured again.
            near, bodies = np.nonzero((lower < margin_m) & (clearance >= margin_m)[:, None])
            if not len(near):
                continue
            row, body = rows[near], moving[bodies]
            centres = placed.spheres(row, body)  # (N, S, 3)
            gap = obstacle.signed_distance_m(centres) - robot.radius_m[body]  # (N, S)
            own = np.arange(gap.shape[1])[None] < robot.own_spheres[body][:, None]
            gap = np.where(own, gap, np.inf)
            n, s = np.nonzero(gap < margin_m)  # the spheres whose hulls decide
            if len(n):
                hull = placed.hulls(row[n], body[n], s)
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
