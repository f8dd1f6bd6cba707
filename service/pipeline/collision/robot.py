"""The robot's own bodies as spheres (collision.json), placed at a configuration, and the
least distance between the pairs that are checked: self-collision.

Each body's spheres cover its URDF collision geometry (training.collision fits them so
that every point of the geometry is inside one), so the distance between two bodies'
spheres, |c_a - c_b| - r_a - r_b minimised over their sphere pairs, is at most the
distance between the geometry itself: a configuration these spheres call free is free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.manifest import ChainSpec, CollisionSpec
from service.pipeline.arrays import FloatArray, IntArray
from service.pipeline.collision.frames import chain_frames


@dataclass(frozen=True)
class RobotSpheres:
    """The spheres of every body, in the frames they move with, and the sphere pairs that
    self-collision checks (those of body pairs not disabled, never a body with itself)."""

    chain: ChainSpec
    body_names: tuple[str, ...]
    frame: IntArray  # (S,) chain frame each sphere moves with (0: the base)
    centre_local_m: FloatArray  # (S, 3) in that frame
    radius_m: FloatArray  # (S,)
    body: IntArray  # (S,) index into body_names
    pair_a: IntArray  # (P,) sphere indices of the checked pairs
    pair_b: IntArray  # (P,)

    @classmethod
    def of(cls, chain: ChainSpec, spec: CollisionSpec) -> RobotSpheres:
        names = tuple(body.link for body in spec.bodies)
        disabled = {frozenset(pair.links) for pair in spec.disabled_pairs}
        counts = [len(body.radii_m) for body in spec.bodies]
        body = np.repeat(np.arange(len(names)), counts)  # (S,)
        frame = np.repeat([b.frame for b in spec.bodies], counts).astype(np.int64)
        if frame.size and frame.max() > len(chain.joints):
            raise ValueError(
                f"collision body in frame {int(frame.max())}; the chain has frames 0 to "
                f"{len(chain.joints)}"
            )
        centres = np.asarray([c for b in spec.bodies for c in b.centres_m], dtype=np.float64)
        radii = np.asarray([r for b in spec.bodies for r in b.radii_m], dtype=np.float64)
        pair_a, pair_b = [], []
        for i in range(len(names)):
            for j in range(i + 1, len(names)):
                if frozenset((names[i], names[j])) in disabled:
                    continue
                a, b = np.meshgrid(np.flatnonzero(body == i), np.flatnonzero(body == j))
                pair_a.append(a.ravel())
                pair_b.append(b.ravel())
        return cls(
            chain=chain,
            body_names=names,
            frame=frame,
            centre_local_m=centres.reshape(-1, 3),
            radius_m=radii,
            body=body.astype(np.int64),
            pair_a=np.concatenate(pair_a).astype(np.int64) if pair_a else np.zeros(0, np.int64),
            pair_b=np.concatenate(pair_b).astype(np.int64) if pair_b else np.zeros(0, np.int64),
        )

    @property
    def sphere_count(self) -> int:
        return len(self.radius_m)

    @property
    def moving(self) -> IntArray:
        """(M,) the spheres of bodies that move (frame > 0): what obstacles are checked
        against. A body fixed to the base is where the robot stands: its scene places it."""
        return np.flatnonzero(self.frame > 0)

    def centres_m(self, q_rad: FloatArray) -> FloatArray:  # q (B, n) -> (B, S, 3), base frame
        frames = chain_frames(self.chain, q_rad)[:, self.frame]  # (B, S, 4, 4)
        return (
            np.einsum("bsij,sj->bsi", frames[:, :, :3, :3], self.centre_local_m)
            + frames[:, :, :3, 3]
        )

    def self_clearance_m(self, centres_m: FloatArray) -> FloatArray:  # (B, S, 3) -> (B,)
        """The least |c_a - c_b| - r_a - r_b over the checked pairs (negative: overlapping);
        +inf when no pair is checked."""
        if not len(self.pair_a):
            return np.full(len(centres_m), np.inf)
        gap = np.linalg.norm(centres_m[:, self.pair_a] - centres_m[:, self.pair_b], axis=2)
        gap -= self.radius_m[self.pair_a] + self.radius_m[self.pair_b]  # (B, P)
        return gap.min(axis=1)
