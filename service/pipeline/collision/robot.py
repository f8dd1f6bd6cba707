"""The robot's own bodies as spheres (collision.json), placed at a configuration, and the
least distance between the body pairs that are checked: self-collision.

Each body's spheres cover its URDF collision geometry (training.collision fits them so
that every point of the geometry is inside one), so the distance between two bodies'
spheres, |c_a - c_b| - r_a - r_b minimised over their sphere pairs, is at most the
distance between the geometry itself: a configuration these spheres call free is free.

The least distance is found in two passes, exactly: each body also has a bounding
sphere, whose distance to another's bounds their sphere pairs' from below, and one
sphere pair per body pair bounds it from above; only the body pairs whose lower bound is
under the least upper bound of the configuration can hold its least distance, and only
their sphere pairs are measured. Bodies are padded to the same sphere count with copies
of their first sphere, which changes no minimum.

Where the spheres leave a configuration less clear than the margin, the refined pass
measures the hulls inside the spheres instead (`refined_self_clearance_m`): every sphere
pair under the margin is replaced by a lower bound of its hulls' distance (convex.py),
which is never less than the spheres' and is the hulls' distance itself when certified.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, partial

import numpy as np

from service.manifest import ChainSpec, CollisionSpec
from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.collision.convex import (
    Separation,
    separation_deepest_first_m,
)
from service.pipeline.collision.frames import frames_of, joint_transforms


@dataclass(frozen=True)
class PlacedBodies:
    """The bodies at B configurations, base frame: each body's frame; its bounding
    sphere's and first sphere's centres when first asked for (the refined self pass; the
    compiled self-clearance and obstacle passes place their own from the frames); the
    other spheres on demand (`spheres`), only for the (configuration, body) pairs a
    distance needs."""

    rotation: FloatArray  # (B, K, 3, 3) each body's frame
    origin_m: FloatArray  # (B, K, 3)
    bound_local_m: FloatArray  # (K, 3) the robot's bounding spheres' centres, body frames
    centre_local_m: FloatArray  # (K, S, 3) the robot's, in each body's frame
    hull_local_m: FloatArray  # (K, S, V, 3) the robot's
    hull_count: IntArray  # (K, S)

    @cached_property
    def _centres_m(self) -> FloatArray:  # (B, K, 3, 2) bounding, then first sphere centres
        points = np.stack([self.bound_local_m, self.centre_local_m[:, 0]], axis=2)  # (K, 3, 2)
        return np.matmul(self.rotation, points) + self.origin_m[..., None]

    @property
    def bound_centres_m(self) -> FloatArray:  # (B, K, 3)
        return self._centres_m[..., 0]

    @property
    def first_centres_m(self) -> FloatArray:  # (B, K, 3) each body's first sphere
        return self._centres_m[..., 1]

    def hull_separation(
        self,
        rows: IntArray,  # (N,) the configuration of each pair
        body_a: IntArray,  # (N,) and sphere_a (N,): the first hull
        sphere_a: IntArray,
        body_b: IntArray,  # (N,) and sphere_b (N,): the second hull
        sphere_b: IntArray,
        pad_m: FloatArray,  # (N,) pad_A + pad_B
        margin_m: float,
    ) -> Separation:
        """`convex.separation_m` between the placed hull pairs, in compiled code
        (`native.hull_separation_m`, the same GJK), from their first vertices' difference."""
        spheres = self.hull_local_m.shape[1]
        x0 = self.hull_points(rows, body_a, sphere_a) - self.hull_points(rows, body_b, sphere_b)
        return partial(
            native.hull_separation_m,
            self.hull_local_m.reshape(-1, *self.hull_local_m.shape[2:]),
            self.hull_count.ravel(),
            body_a * spheres + sphere_a,
            self.rotation[rows, body_a],
            self.origin_m[rows, body_a],
            body_b * spheres + sphere_b,
            self.rotation[rows, body_b],
            self.origin_m[rows, body_b],
            x0,
            pad_m,
            margin_m,
        )

    def hull_points(self, rows: IntArray, bodies: IntArray, spheres: IntArray) -> FloatArray:
        """(N, 3) a point of each hull (its first vertex), placed: to start GJK from."""
        local = self.hull_local_m[bodies, spheres, 0]  # (N, 3)
        turned = np.einsum("nij,nj->ni", self.rotation[rows, bodies], local)
        return turned + self.origin_m[rows, bodies]

    def spheres(self, rows: IntArray, bodies: IntArray) -> FloatArray:  # (N,), (N,) -> (N, S, 3)
        """The padded sphere centres of body bodies[i] at configuration rows[i]."""
        local = self.centre_local_m[bodies]  # (N, S, 3)
        turned = np.matmul(local, self.rotation[rows, bodies].transpose(0, 2, 1))
        return turned + self.origin_m[rows, bodies][:, None, :]


@dataclass(frozen=True)
class RobotSpheres:
    """Every body's spheres in the frame it moves with, padded to S per body, its bounding
    sphere, and the body pairs self-collision checks (those not disabled)."""

    chain: ChainSpec
    body_names: tuple[str, ...]
    frame: IntArray  # (K,) chain frame each body moves with (0: the base)
    centre_local_m: FloatArray  # (K, S, 3) in that frame
    radius_m: FloatArray  # (K, S)
    bound_local_m: FloatArray  # (K, 3) bounding sphere's centre, in that frame
    bound_radius_m: FloatArray  # (K,) it holds every sphere of the body
    pair_a: IntArray  # (P,) body indices of the checked pairs
    pair_b: IntArray  # (P,)
    sphere_count: int  # the spheres of collision.json, padding aside
    own_spheres: IntArray  # (K,) each body's, padding aside
    hull_local_m: FloatArray  # (K, S, V, 3) each sphere's hull, padded with its first vertex
    hull_pad_m: FloatArray  # (K, S)
    hull_count: IntArray  # (K, S) each hull's own vertices, padding aside

    @classmethod
    def of(cls, chain: ChainSpec, spec: CollisionSpec) -> RobotSpheres:
        frames = np.array([body.frame for body in spec.bodies], dtype=np.int64)
        if frames.size and frames.max() > len(chain.joints):
            raise ValueError(
                f"collision body in frame {int(frames.max())}; the chain has frames 0 to "
                f"{len(chain.joints)}"
            )
        count = max((len(body.radii_m) for body in spec.bodies), default=1)
        centres = np.zeros((len(spec.bodies), count, 3))
        radii = np.zeros((len(spec.bodies), count))
        for k, body in enumerate(spec.bodies):
            own = len(body.radii_m)
            centres[k, :own], radii[k, :own] = body.centres_m, body.radii_m
            centres[k, own:], radii[k, own:] = body.centres_m[0], body.radii_m[0]
        vertices = max((len(hull) for body in spec.bodies for hull in body.hulls_m), default=1)
        hulls = np.repeat(centres[:, :, None, :], vertices, axis=2)  # (K, S, V, 3)
        pads = radii.copy()  # without hulls, each sphere is its own: its centre, padded
        vertex_count = np.ones(radii.shape, dtype=np.int64)
        for k, body in enumerate(spec.bodies):
            for s, (hull, pad) in enumerate(zip(body.hulls_m, body.hull_pads_m, strict=True)):
                hulls[k, s, : len(hull)], hulls[k, s, len(hull) :] = hull, hull[0]
                pads[k, s], vertex_count[k, s] = pad, len(hull)
            own = len(body.radii_m)
            hulls[k, own:], pads[k, own:] = hulls[k, 0], pads[k, 0]
            vertex_count[k, own:] = vertex_count[k, 0]
        bound = centres.mean(axis=1)  # (K, 3)
        bound_radius = (np.linalg.norm(centres - bound[:, None], axis=2) + radii).max(axis=1)
        names = tuple(body.link for body in spec.bodies)
        disabled = {frozenset(pair.links) for pair in spec.disabled_pairs}
        pairs = [
            (i, j)
            for i in range(len(names))
            for j in range(i + 1, len(names))
            if frozenset((names[i], names[j])) not in disabled
        ]
        return cls(
            chain=chain,
            body_names=names,
            frame=frames,
            centre_local_m=centres,
            radius_m=radii,
            bound_local_m=bound,
            bound_radius_m=bound_radius,
            pair_a=np.array([a for a, _ in pairs], dtype=np.int64),
            pair_b=np.array([b for _, b in pairs], dtype=np.int64),
            sphere_count=sum(len(body.radii_m) for body in spec.bodies),
            own_spheres=np.array([len(body.radii_m) for body in spec.bodies], dtype=np.int64),
            hull_local_m=hulls,
            hull_pad_m=pads,
            hull_count=vertex_count,
        )

    @property
    def moving(self) -> BoolArray:
        """(K,) the bodies that move (frame > 0): what obstacles are checked against. A
        body fixed to the base is where the robot stands: its scene places it."""
        return self.frame > 0

    @cached_property
    def moving_bodies(self) -> native.MovingBodies:
        """These bodies as the compiled obstacle passes take them."""
        return native.MovingBodies(
            centre_local_m=self.centre_local_m, radius_m=self.radius_m,
            own_spheres=self.own_spheres, bound_local_m=self.bound_local_m,
            bound_radius_m=self.bound_radius_m,
            moving=np.flatnonzero(self.moving).astype(np.int64),
            hull_local_m=self.hull_local_m, hull_count=self.hull_count,
            hull_pad_m=self.hull_pad_m,
        )  # fmt: skip

    @cached_property
    def joint_transforms(self) -> tuple[FloatArray, FloatArray]:
        """The chain's joint transforms as arrays, made once, not at every placement."""
        return joint_transforms(self.chain)

    def place(self, q_rad: FloatArray) -> PlacedBodies:  # q (B, n)
        frames = frames_of(*self.joint_transforms, q_rad)[:, self.frame]  # (B, K, 4, 4)
        return PlacedBodies(
            rotation=frames[:, :, :3, :3],
            origin_m=frames[:, :, :3, 3],
            bound_local_m=self.bound_local_m,
            centre_local_m=self.centre_local_m,
            hull_local_m=self.hull_local_m,
            hull_count=self.hull_count,
        )

    def self_clearance_m(self, placed: PlacedBodies) -> FloatArray:  # -> (B,)
        """The least |c_a - c_b| - r_a - r_b over the sphere pairs of the checked body
        pairs (negative: overlapping); +inf when no pair is checked. Compiled
        (`native.self_clearance_m`), with the module docstring's bounds row by row."""
        return native.self_clearance_m(
            placed.rotation, placed.origin_m, self.centre_local_m, self.radius_m,
            self.own_spheres, self.bound_local_m, self.bound_radius_m, self.pair_a, self.pair_b,
        )  # fmt: skip

    def self_clearance_at_m(
        self, q_rad: FloatArray, threads: int = 1
    ) -> FloatArray:  # (B, n) -> (B,)
        """`self_clearance_m` of the bodies placed at q_rad, row by row in compiled code
        (`native.self_clearance_at_m`, on `threads`): the same numbers, no placed frames
        stored."""
        origin, axis = self.joint_transforms
        return native.self_clearance_at_m(
            origin, axis, q_rad, self.frame, self.centre_local_m, self.radius_m,
            self.own_spheres, self.bound_local_m, self.bound_radius_m, self.pair_a, self.pair_b,
            threads,
        )  # fmt: skip

    def self_bodies(self, margin_m: float) -> native.SelfBodies:
        """These bodies as the compiled self-collision kernels take them."""
        origin, axis = self.joint_transforms
        return native.SelfBodies(
            origin, axis, self.frame, self.centre_local_m, self.radius_m, self.own_spheres,
            self.bound_local_m, self.bound_radius_m, self.pair_a, self.pair_b,
            self.hull_local_m, self.hull_count, self.hull_pad_m, margin_m,
        )  # fmt: skip

    def refined_self_clearance_at_m(
        self, q_rad: FloatArray, margin_m: float
    ) -> FloatArray:  # (R, n) -> (R,)
        """`refined_self_clearance_m` of the bodies placed at q_rad, row by row in compiled
        code (`native.refined_self_clearance_at_m`): the same numbers, without its
        (pairs, S, S, 3) temporaries."""
        return native.refined_self_clearance_at_m(self.self_bodies(margin_m), q_rad)

    def refined_self_clearance_m(
        self, placed: PlacedBodies, rows: IntArray, margin_m: float
    ) -> FloatArray:  # rows (R,) -> (R,)
        """A lower bound of the least distance over the checked body pairs at configurations
        `rows`, at least `self_clearance_m`'s: a body pair whose bounding spheres are
        clear by the margin counts with that bound, a sphere pair clear by it with its
        distance, and every other sphere pair with its hulls' separation (module
        docstring)."""
        if not len(self.pair_a):
            return np.full(len(rows), np.inf)
        a, b = self.pair_a, self.pair_b
        bounds = placed.bound_centres_m[rows]  # (R, K, 3)
        lower = np.linalg.norm(bounds[:, a] - bounds[:, b], axis=2)  # (R, P)
        lower -= self.bound_radius_m[a] + self.bound_radius_m[b]
        clearance = np.where(lower >= margin_m, lower, np.inf).min(axis=1)  # (R,)
        near, pairs = np.nonzero(lower < margin_m)  # (N,), (N,)
        if not len(near):
            return clearance
        body_a, body_b, row = a[pairs], b[pairs], rows[near]
        ca = placed.spheres(row, body_a)  # (N, S, 3)
        cb = placed.spheres(row, body_b)
        gap = np.linalg.norm(ca[:, :, None] - cb[:, None], axis=3)  # (N, S, S)
        gap -= self.radius_m[body_a][:, :, None] + self.radius_m[body_b][:, None]
        spheres = np.arange(gap.shape[1])
        own = (spheres[None, :, None] < self.own_spheres[body_a][:, None, None]) & (
            spheres[None, None, :] < self.own_spheres[body_b][:, None, None]
        )
        gap = np.where(own, gap, np.inf)
        n, sa, sb = np.nonzero(gap < margin_m)  # the sphere pairs the hulls decide
        if len(n):
            pad = self.hull_pad_m[body_a[n], sa] + self.hull_pad_m[body_b[n], sb]
            separation = placed.hull_separation(row[n], body_a[n], sa, body_b[n], sb, pad, margin_m)
            gap[n, sa, sb] = separation_deepest_first_m(
                separation, margin_m, near[n], gap[n, sa, sb]
            )
        np.minimum.at(clearance, near, gap.min(axis=(1, 2)))
        return clearance
