"""Random box scenes around the arm, each seeded and reproducible.

A target is the forward kinematics of a configuration q_target uniform in the joint
limits (as the report's targets), drawn again until coal finds it free of
self-collision by the margin. Its scene holds 1 to `max_obstacles` boxes (or exactly a
given count): each side 0.05 to 0.4 m, a uniformly random orientation, the centre
uniform in the ball of the arm's reach around its base, above the base's floor (z > 0);
a box is kept only when coal finds q_target clear of it by the margin, so the target has
at least one free configuration. Every draw comes from the target's own generator, so a
scene is replayed from (seed, index) alone, and is recorded as the obstacles of a POST
/smm body (`request_body`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.arrays import FloatArray
from service.pipeline.collision.scene import Obstacle
from service.pipeline.targets import TargetFields, fields_reached
from training.evaluate.scenes.coal_model import CoalModel

MIN_SIDE_M, MAX_SIDE_M = 0.05, 0.4
# Boxes drawn per box asked for before a scene settles for fewer (q_target fills space).
DRAWS_PER_BOX = 50
MAX_TARGET_DRAWS = 1000


@dataclass(frozen=True)
class SceneTarget:
    """One target and its scene."""

    index: int
    q_target_rad: FloatArray  # (n,) free of self-collision by coal
    obstacles: tuple[Obstacle, ...]  # boxes clear of q_target by coal
    boxes_asked: int  # how many boxes the scene drew for (some may not have fitted)
    bodies: tuple[dict[str, object], ...]  # each obstacle as a POST /smm body lists it


def free_target(
    model: ServedModel, coal: CoalModel, rng: np.random.Generator, margin_m: float
) -> FloatArray:
    """A configuration uniform in the limits that coal finds free of self-collision."""
    limits = model.limits
    for _ in range(MAX_TARGET_DRAWS):
        q = rng.uniform(limits.lower_rad, limits.upper_rad)
        if coal.free(q[None], (), margin_m)[0]:
            return np.asarray(q)
    raise RuntimeError(f"no self-collision-free configuration in {MAX_TARGET_DRAWS} draws")


def random_box(
    index: int, reach_m: float, rng: np.random.Generator
) -> tuple[Obstacle, dict[str, object]]:
    """A box (module docstring): sides, orientation and a centre in the upper half ball,
    and its POST /smm body (the very numbers it was made from, so a replay is exact)."""
    sides = rng.uniform(MIN_SIDE_M, MAX_SIDE_M, 3)
    quaternion = rng.normal(size=4)
    quaternion /= np.linalg.norm(quaternion)
    while True:
        centre = rng.uniform(-reach_m, reach_m, 3)
        if np.linalg.norm(centre) <= reach_m and centre[2] > 0.0:
            break
    w, x, y, z = (float(c) for c in quaternion)
    body: dict[str, object] = {
        "shape": "box",
        "dimensions": sides.tolist(),
        "position": centre.tolist(),
        "orientation": {"w": w, "x": x, "y": y, "z": z},
    }
    return Obstacle.of(index, "box", sides.tolist(), centre.tolist(), (w, x, y, z)), body


def box_scene(
    model: ServedModel,
    coal: CoalModel,
    q_target_rad: FloatArray,
    count: int,
    margin_m: float,
    rng: np.random.Generator,
) -> tuple[tuple[Obstacle, ...], tuple[dict[str, object], ...]]:
    """Up to `count` random boxes, each clear of q_target by the margin by coal, and
    their POST bodies."""
    kept: list[tuple[Obstacle, dict[str, object]]] = []
    for _ in range(DRAWS_PER_BOX * count):
        if len(kept) == count:
            break
        box, body = random_box(len(kept), model.manifest.reach_m, rng)
        if coal.free(q_target_rad[None], [box], margin_m)[0]:
            kept.append((box, body))
    return tuple(box for box, _ in kept), tuple(body for _, body in kept)


def scene_target(
    model: ServedModel,
    coal: CoalModel,
    seed: int,
    index: int,
    max_obstacles: int,
    margin_m: float,
    exact_count: int | None = None,
) -> SceneTarget:
    """Target `index` of `seed` and its scene of 1 to `max_obstacles` boxes (exactly
    `exact_count` asked for when given, drawn from a generator of its own)."""
    rng = np.random.default_rng([seed, index])
    q_target = free_target(model, coal, rng, margin_m)
    if exact_count is None:
        count = int(rng.integers(1, max_obstacles + 1))
    else:
        count, rng = exact_count, np.random.default_rng([seed, index, exact_count])
    obstacles, bodies = box_scene(model, coal, q_target, count, margin_m, rng)
    return SceneTarget(index, q_target, obstacles, count, bodies)


def target_fields(model: ServedModel, q_target_rad: FloatArray) -> TargetFields:
    """The target a configuration (n,) reaches, as a client sends it for the model's task:
    the position, and the orientation (pose) or the tool axis (axis)."""
    fk = model.kinematics(q_target_rad[None])
    return fields_reached(model.manifest.task, fk.position_m[0], fk.rotation[0])


def request_body(model: ServedModel, scene: SceneTarget, margin_m: float) -> dict[str, object]:
    """The POST /smm body that asks the service this target in this scene, with the seed
    and number of samples the evaluation asked with (the target's index, the model's
    default), so that it replays the evaluated answer."""
    manifest = model.manifest
    return {
        "robot": manifest.robot,
        "task": manifest.task.name,
        "target": target_fields(model, scene.q_target_rad).wire(),
        "num_samples": manifest.defaults.num_samples,
        "seed": scene.index,
        "obstacles": list(scene.bodies),
        "collision": {"self": True, "margin_m": margin_m},
    }
