"""collision.json from a URDF: the bodies' sphere covers, the pairs never checked, and what
the spheres cost in free space.

`build_collision_model` reads the bodies (`geometry`), covers each with spheres
(`spheres`), decides the disabled pairs (`pairs`: adjacent, and default/always/never
from the sampled configurations, or the SRDF's), and measures on the same configurations, uniform
in the joint limits, the free space the spheres lose: of the configurations coal finds
free of self-collision on the URDF's geometry (over the pairs not disabled), the
fraction the service's check calls in collision (`CollisionCheck`: the spheres, and the
hulls inside them where the spheres touch). Both are conservative, so the check never
calls free what coal calls in collision; this is the price of that, which the service
pays as configurations it refuses.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from service.manifest import ChainSpec, CollisionSpec, DisabledPair, JointSpec
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.collision.robot import RobotSpheres
from service.pipeline.collision.scene import Scene
from service.pipeline.joint_space import JointLimits
from training.collision.geometry import read_bodies
from training.collision.pairs import (
    DEFAULT_CONFIGURATIONS,
    adjacent_pairs,
    default_configuration,
    sampled_pairs,
    srdf_pairs,
    tagged,
)
from training.collision.spheres import DEFAULT_SPHERES_PER_BODY, cover_body


@dataclass(frozen=True)
class BuiltCollision:
    """collision.json and the figures its manifest record holds."""

    spec: CollisionSpec
    sphere_count: int
    configurations_sampled: int
    free_space_lost_fraction: float
    wall_time_s: float
    sampling_time_s: float  # coal's collisions on the sampled configurations


def build_collision_model(
    urdf_path: Path,
    chain: ChainSpec,
    joints: JointSpec,
    srdf_path: Path | None = None,
    spheres_per_body: int = DEFAULT_SPHERES_PER_BODY,
    configurations: int = DEFAULT_CONFIGURATIONS,
    seed: int = 0,
    package_dir: Path | None = None,
) -> BuiltCollision | None:
    """The collision model of the URDF's chain (module docstring); None when no link on
    the chain or attached to it has collision geometry."""
    if configurations < 1:
        raise ValueError(f"configurations: {configurations}; give at least 1")
    started = time.perf_counter()
    bodies = read_bodies(urdf_path, chain, package_dir)
    if not bodies:
        return None
    covered = [cover_body(body, spheres_per_body, seed) for body in bodies]
    # coal is imported here, not with the module: `smm-train train` imports this module
    # through the export, and a machine that only trains (a GPU lent for the epochs)
    # need not have coal's 300 MB of libraries until a collision model is built.
    from training.evaluate.references.collision import CoalRobot

    robot = CoalRobot(chain, bodies)
    limits = JointLimits.of(joints)
    q = np.random.default_rng(seed).uniform(
        limits.lower_rad, limits.upper_rad, size=(configurations, joints.count)
    )
    disabled = tagged(adjacent_pairs(urdf_path, bodies), "adjacent")
    if srdf_path is not None:
        adjacent = {pair.links for pair in disabled}
        disabled += tagged([p for p in srdf_pairs(srdf_path, bodies) if p not in adjacent], "srdf")
    candidates = robot.checked_pairs(pair.links for pair in disabled)
    sampling_started = time.perf_counter()
    touching = robot.pair_collisions(q, candidates)  # (B, P)
    sampling_time_s = time.perf_counter() - sampling_started
    if srdf_path is None:
        at_default = robot.pair_collisions(default_configuration(joints), candidates)[0]
        disabled += sampled_pairs(robot.names, candidates, touching, at_default)
    disabled = sorted(disabled, key=lambda pair: pair.links)
    spec = CollisionSpec(bodies=covered, disabled_pairs=disabled)
    checked = _checked_columns(robot.names, candidates, disabled)
    coal_free = ~touching[:, checked].any(axis=1)
    spheres = RobotSpheres.of(chain, spec)
    spheres_collide = ~CollisionCheck(spheres, Scene(), True, 0.0).free(q)
    free = int(coal_free.sum())
    lost = float((spheres_collide & coal_free).sum() / free) if free else 0.0
    return BuiltCollision(
        spec=spec,
        sphere_count=spheres.sphere_count,
        configurations_sampled=configurations,
        free_space_lost_fraction=lost,
        wall_time_s=time.perf_counter() - started,
        sampling_time_s=sampling_time_s,
    )


def _checked_columns(
    names: tuple[str, ...], pairs: list[tuple[int, int]], disabled: list[DisabledPair]
) -> np.ndarray:
    """(P,) which of `pairs` are checked (not disabled)."""
    off = {frozenset(pair.links) for pair in disabled}
    return np.array([frozenset((names[a], names[b])) not in off for a, b in pairs], dtype=bool)
