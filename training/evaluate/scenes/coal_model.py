"""A model's robot as coal sees it: the URDF's original geometry (meshes and primitives)
placed by the model's chain, the self pairs its collision.json does not disable, and the
request's obstacles; its clearance is the reference the service's check is judged by.

Clearance at a configuration: the least coal distance over the body pairs checked and
from the moving bodies to every obstacle (`references.collision.CoalRobot`: exact when
apart, <= 0 when touching). A configuration is free by a margin when its clearance is
at least the margin and above 0 (touching is never free).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from service.manifest import (
    CHAIN_FILE,
    COLLISION_FILE,
    MANIFEST_FILE,
    REPO_MODELS_DIR,
    ChainSpec,
    CollisionSpec,
    Manifest,
)
from service.models.registry import ServedModel
from service.pipeline.arrays import BoolArray, FloatArray
from service.pipeline.collision.scene import Obstacle as ServiceObstacle
from training.collision.geometry import read_bodies
from training.evaluate.references.collision import CoalRobot, Obstacle


@dataclass(frozen=True)
class CoalModel:
    """The coal robot of a model and the body pairs its collision.json disables."""

    robot: CoalRobot
    disabled: tuple[tuple[str, str], ...]

    @classmethod
    def of(cls, model: ServedModel) -> CoalModel:
        """A bundled model's (`of_directory` of models/<model-id>/)."""
        return cls.of_directory(REPO_MODELS_DIR / model.manifest.model_id)

    @classmethod
    def of_directory(cls, model_dir: Path) -> CoalModel:
        """From a model directory: the URDF its manifest names (relative to the models
        directory), chain.json and collision.json; ValueError for a model without
        collision geometry."""
        if not (model_dir / COLLISION_FILE).is_file():
            raise ValueError(f"{model_dir.name} has no {COLLISION_FILE}")
        manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
        chain = ChainSpec.model_validate_json((model_dir / CHAIN_FILE).read_bytes())
        spec = CollisionSpec.model_validate_json((model_dir / COLLISION_FILE).read_bytes())
        bodies = read_bodies(model_dir.parent / manifest.urdf.path, chain)
        disabled = tuple(tuple(pair.links) for pair in spec.disabled_pairs)
        return cls(CoalRobot(chain, bodies), disabled)  # type: ignore[arg-type]

    def self_clearance_m(self, q_rad: FloatArray) -> FloatArray:  # (B, n) -> (B,)
        """Least distance over the body pairs not disabled (+inf when none)."""
        if not len(q_rad):
            return np.zeros(0)
        return self.robot.self_distance_m(q_rad, self.disabled)

    def obstacle_clearance_m(
        self, q_rad: FloatArray, obstacles: Sequence[ServiceObstacle]
    ) -> FloatArray:  # (B,)
        """Least distance of the moving bodies to the obstacles (+inf without any)."""
        if not len(q_rad) or not obstacles:
            return np.full(len(q_rad), np.inf)
        return self.robot.obstacle_distance_m(q_rad, [coal_obstacle(o) for o in obstacles])

    def clearance_m(
        self, q_rad: FloatArray, obstacles: Sequence[ServiceObstacle]
    ) -> FloatArray:  # (B,)
        """The least of the self and the obstacle clearance (module docstring)."""
        return np.minimum(self.self_clearance_m(q_rad), self.obstacle_clearance_m(q_rad, obstacles))

    def free(
        self, q_rad: FloatArray, obstacles: Sequence[ServiceObstacle], margin_m: float
    ) -> BoolArray:  # (B,)
        """Which configurations are free by the margin (module docstring), by coal's
        collide with the margin as its security margin: `free_by(clearance_m)` without
        computing a distance."""
        if not len(q_rad):
            return np.zeros(0, dtype=bool)
        coal_obstacles = [coal_obstacle(o) for o in obstacles]
        return ~self.robot.within_m(q_rad, self.disabled, coal_obstacles, margin_m)


def coal_obstacle(obstacle: ServiceObstacle) -> Obstacle:
    """The reference's obstacle of a service obstacle: the same primitive and pose."""
    return Obstacle(
        shape=obstacle.shape,
        dimensions_m=obstacle.dimensions_m,
        position_m=np.asarray(obstacle.position_m),
        rotation=np.asarray(obstacle.rotation),
    )


def free_by(clearance_m: FloatArray, margin_m: float) -> BoolArray:
    """Which clearances are free by the margin: at least it, and apart (above 0)."""
    return np.asarray((clearance_m >= margin_m) & (clearance_m > 0.0))
